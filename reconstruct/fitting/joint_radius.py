"""Each log's radius as a state of the joint pile estimate (``JointConfig.radius_states``): a log the scan
fitted a few centimetres too thick in a packed pile presses into its neighbour or the terrain; with its radius
a state, held by a Gaussian of its own scan radius sigma (:func:`reconstruct.fitting.joint_scan_sigma.scan_sigma`'s
``radius_m``), the non-interpenetration penalty can thin it within that uncertainty instead of moving it
farther than its evidence allows and refusing it.

A log's state is one number, the change of its radius (the same at the butt and the top, so its taper is
kept), in units of its sigma. The log is thinned (or thickened) with its top kept: the scan sees a log's top
arc best, so a thinner log has its axis raised by what its radius lost (:func:`radius_segment`), as revision
22's thinning does (:mod:`reconstruct.fitting.separation`), and never below ``radius_min_share`` of its
fitted radius (:func:`changed_radius`): a log that clears only thinner is moved or refused. The settled pile
carries the changed diameters (:func:`resized_log`), so the twin checks what the estimate says, and a note
names each log thinned, saying where that is more than its sigma (:func:`radius_notes`)."""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from reconstruct.fitting.joint_contact import Segment
from synth.scene.pile import LogSpec

UP = np.array([0.0, 0.0, 1.0])
#: the thinnest a log's radius is taken to (half LogSpec's least butt diameter, 3 cm) [m]
MIN_RADIUS_M = 0.015
#: a radius changed less than this is not reported [m]
REPORT_RADIUS_M = 1e-3


def changed_radius(r_m: float, dr_m: float, min_share: float) -> float:
    """A radius ``r_m`` changed by ``dr_m``, no thinner than ``min_share`` of itself nor ``MIN_RADIUS_M`` [m]:
    past that floor a contact gains nothing from thinning the log, so it moves it (or refuses it) as before."""
    return max(r_m + dr_m, min_share * r_m, MIN_RADIUS_M)


def radius_segment(s: Segment, dr_m: float, min_share: float) -> Segment:
    """Segment ``s`` with its radius changed by ``dr_m`` at both ends (:func:`changed_radius`), its top kept:
    its axis raised by what the radius lost."""
    if dr_m == 0.0:
        return s
    ra, rb = changed_radius(s.ra, dr_m, min_share), changed_radius(s.rb, dr_m, min_share)
    return Segment(s.a + (s.ra - ra) * UP, s.b + (s.rb - rb) * UP, ra, rb)


def resized_log(log: LogSpec, dr_m: float, min_share: float) -> LogSpec:
    """``log`` (already at its settled axis) with its radii changed by ``dr_m`` as :func:`radius_segment`
    changes them (a cylinder stays one)."""
    if dr_m == 0.0:
        return log
    butt = 2 * changed_radius(log.diameter_m / 2, dr_m, min_share)
    top = (None if log.top_diameter_m is None else
           min(2 * changed_radius(log.top_diameter_m / 2, dr_m, min_share), butt))
    return replace(log, diameter_m=butt, top_diameter_m=top)


def radius_notes(dr_m: np.ndarray, sigmas_m: Sequence[float], logs: Sequence[LogSpec]) -> list[str]:
    """A note per log whose radius the estimate changed by ``REPORT_RADIUS_M`` or more (``logs``: as found,
    ``dr_m``: each one's radius change as the settled pile carries it [m], ``sigmas_m``: each one's radius
    sigma [m]); a log thinned by more than its sigma is said to be."""
    notes = []
    for k, (dr, sig, log) in enumerate(zip(dr_m, sigmas_m, logs)):
        if abs(dr) < REPORT_RADIUS_M:
            continue
        word = "thinned" if dr < 0 else "thickened"
        beyond = ", more than its sigma: its scan fit is too thick" if dr < -sig else ""
        notes.append(f"log {k} {word} {abs(dr) * 2000:.1f} mm to {(log.mean_diameter_m + 2 * dr) * 100:.1f} cm "
                     f"thick, its top kept ({abs(dr) / sig:.1f} sigma of its scan radius, +-{sig * 100:.1f} cm"
                     f"{beyond})")
    return notes
