"""eval's planner rows from its flags: the U-Net per objective (verified, with views, in another
number format), each --extra-model and the baselines, every model file checked."""

from __future__ import annotations

from pathlib import Path

from planner.evaluate import PlannerSpec
from synth.common.cli import CliError, check_input


def view_specs(model: str, objectives: str, views: int | None, view_spread: float) -> list[PlannerSpec]:
    """eval's rows with test-time views (``--views``): the U-Net per objective, named ``unet-f1-views8``
    (``...k2`` with ``--view-spread 2``)."""
    if views is None:
        if view_spread:
            raise CliError("--view-spread needs --views V")
        return []
    if views == 1:
        raise CliError("--views 1 is the plain row that --objectives gives already: add 2, 4 or 8 views")
    from planner.inference import check_views

    check_views(views, view_spread)  # a ValueError naming views / view_spread_k, reported with the flags
    return [PlannerSpec("unet", model=model, objective=x, views=views, view_spread_k=view_spread)
            for x in csv_list(objectives)]


def csv_list(text: str) -> list[str]:
    return [x.strip() for x in text.split(",") if x.strip()]


def base_specs(model: str, objectives: str, baselines: str, extra_model: list[str], verify: int | None,
                verify_copies: int) -> list[PlannerSpec]:
    """eval's planner rows: the U-Net per objective (and verified, with --verify), each --extra-model
    (f1), then the baselines; every model file checked."""
    objs = csv_list(objectives)
    if any(x not in ("f1", "f2", "f3") for x in objs):
        raise CliError(f"--objectives must be a comma-separated list of f1, f2, f3, got {objectives!r}")
    specs = [PlannerSpec("unet", model=model, objective=x) for x in objs]
    from planner.cli import check_verify_flags  # the flags' check shared with plan and trial

    check_verify_flags(verify, None)
    if verify is not None:
        specs += [PlannerSpec("unet", model=model, objective=x, verify_k=verify, verify_copies=verify_copies)
                  for x in objs]
    elif verify_copies:
        raise CliError("--verify-copies needs --verify K")
    for item in extra_model:
        label, _, p = item.partition("=")
        if not p or not label:
            raise CliError(f"--extra-model must be LABEL=PATH, got {item!r}")
        specs.append(PlannerSpec("unet", model=p, objective="f1", label=label))
    names = csv_list(baselines)
    if any(b not in ("random", "geometric", "oracle") for b in names):
        raise CliError(f"--baselines must be a comma-separated list of random, geometric, oracle, got {baselines!r}")
    specs += [PlannerSpec(b) for b in names]
    if not specs:
        raise CliError("nothing to evaluate: give --objectives, --baselines or --extra-model")
    for s in specs:
        if s.kind == "unet":
            check_input(s.model, "--model" if s.label == "" else "--extra-model", "file")
    return specs


def with_precision(specs: list[PlannerSpec], precision: str) -> list[PlannerSpec]:
    """The U-Net rows in ``precision`` (``--precision``; "auto" leaves them as they are, their names and
    records too); a precision this machine cannot run is a :class:`CliError` now, not in a worker."""
    if precision == "auto":
        return specs
    from dataclasses import replace

    from planner.int8 import calibration_path
    from planner.runtime import INT8_PRECISIONS, resolve_precision

    try:
        resolve_precision(precision, "cpu")
    except ValueError as exc:
        raise CliError(f"--precision {precision}: {exc}") from exc
    out = [replace(s, precision=precision) if s.kind == "unet" else s for s in specs]
    for s in out:
        if s.kind == "unet" and precision in INT8_PRECISIONS and not calibration_path(s.model).is_file():
            raise CliError(f"--precision {precision}: {s.model} has no int8 calibration beside it "
                           f"({Path(calibration_path(s.model)).name}; python -m experiments.int8_calibration)")
    return out


def with_ranker(specs: list[PlannerSpec], ranker: Path | None, rerank_k: int, u_weight: float,
                ranked_only: bool) -> list[PlannerSpec]:
    """``specs`` and, with a ``ranker`` (``--ranker``), a re-ranked copy of each plain U-Net row (not the
    --extra-model ones, nor those with views); ``ranked_only`` (``--ranked-only``): the copies in place of
    the rows they re-rank."""
    from dataclasses import replace

    if ranker is None:
        if ranked_only:
            raise CliError("--ranked-only needs --ranker PATH")
        return specs
    check_input(ranker, "--ranker", "file")
    plain = [s for s in specs if s.kind == "unet" and not s.label and s.views == 1]
    ranked = [replace(s, ranker=str(ranker), rerank_k=rerank_k, ranker_u_weight=u_weight) for s in plain]
    return [s for s in specs if not (ranked_only and s in plain)] + ranked
