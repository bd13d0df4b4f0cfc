"""Radius states as the rescue of a refused pile (``JointConfig.radius_rescue``, joint revision 20).

The pile check's refusal (:class:`reconstruct.errors.SeparationError`) says that a log would have to move farther
than what holds it allows: *its fit or its GNSS end points are wrong*. Each log's radius as a state of the estimate
(:mod:`reconstruct.fitting.joint_radius`) is the first of the two explanations - the scan fitted a log too thick -
and in packed piles it is often the right one. It is the second explanation of the pile, not the first: the pile is
settled with its fitted radii, and only a refusal is settled again with the radii as states (:func:`settle_or_rescue`).

The rescue stands only when the pile it makes is one the report would not warn about (:func:`rescue_doubts`):
every end of every log, where the pile check leaves it (:func:`reconstruct.fitting.joint_ends.joint_after_check`),
surer than ``weak_sigma_m`` and no survey point called wrong (its outlier probability over ``outlier_flag_prob``).
A pile that clears only with logs thinned *and* doubts its survey has both of the refusal's causes in play, and
nothing in the estimate says which one acted: it is refused as the fitted radii refused it, so the crew
re-measures (the refusal's message says which points), rather than handed on with a thinned log in it."""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Sequence

import numpy as np

from reconstruct.errors import SeparationError
from reconstruct.fitting.clearance import Cleared
from reconstruct.fitting.joint_config import JointConfig
from reconstruct.fitting.joint_ends import joint_after_check


def rescue_doubts(cleared: Cleared, fits: Sequence, survey_ends: dict, cfg: JointConfig) -> list[str]:
    """What the report would warn about in the settled pile ``cleared`` (its ``at_survey`` ends as the settler
    leaves them, ``fits``: each log's fit report, ``survey_ends``: per log id, its survey points): one line per
    end less certain than ``weak_sigma_m`` or whose survey point is called wrong, where the pile check leaves it."""
    out = []
    for k, lf in enumerate(fits):
        if not lf.ends:
            continue
        ends = [cleared.at_survey.get((k, j), e) for j, e in enumerate(lf.ends)]
        endpoints = tuple(np.asarray(p, dtype=float) for p in cleared.pile.logs[k].endpoints_m())
        after = joint_after_check(ends, endpoints, survey_ends.get(lf.log_id, (None, None)), cfg)
        for name, e in zip("ab", after):
            if e.get("contradicted"):
                out.append(f"{lf.log_id} end {name}'s survey point called wrong")
            elif e["sigma_m"] > cfg.weak_sigma_m:
                out.append(f"{lf.log_id} end {name} +-{e['sigma_m'] * 100:.0f} cm")
    return out


def settle_or_rescue(settle: Callable[[JointConfig], Cleared], fits: Sequence, survey_ends: dict,
                     cfg: JointConfig) -> Cleared:
    """``settle`` (the pile settled under the config it is given) with the fitted radii, and, where that is
    refused and ``cfg.radius_states`` and ``cfg.radius_rescue`` are on, with each radius a state, kept only if
    :func:`rescue_doubts` finds nothing (else the first refusal, with what the rescue doubted). With
    ``radius_rescue`` off, ``settle(cfg)`` as it is (radius states everywhere, or nowhere)."""
    if not (cfg.radius_states and cfg.radius_rescue):
        return settle(cfg)
    try:
        return settle(replace(cfg, radius_states=False))
    except SeparationError as exc:
        refused = exc
    cleared = settle(cfg)
    doubts = rescue_doubts(cleared, fits, survey_ends, cfg)
    if doubts:
        raise SeparationError(f"{refused}. With each log's radius a state it clears, but that pile doubts its own "
                              f"evidence ({'; '.join(doubts)}), so the refusal stands", logs=refused.logs) from refused
    cleared.notes.insert(0, f"the fitted radii could not be met ({refused}); with each log's radius a state of the "
                            f"estimate the pile clears, every end surer than {cfg.weak_sigma_m * 100:.0f} cm and no "
                            f"survey point called wrong")
    return cleared
