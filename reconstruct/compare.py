"""A reconstructed pile measured against the ground truth, and twin scans to measure it on.

:func:`compare_piles` matches the logs of two piles (order-independent: Hungarian assignment on
the distance between their axes; a log's two ends may be swapped), and reports per matched log

* ``endpoint_err_m``: mean distance of the two ends (ends paired the better way round),
  ``endpoint_max_err_m``, ``length_err_m``, ``axis_angle_err_deg``;
* ``diameter_err_m``: reconstructed minus true MEAN diameter (butt and top averaged), and
  ``butt_diameter_err_m``;
* ``mask_iou``: the log's mask in a 128 px orthographic render (:func:`synth.render.ortho.render_ortho`)
  of a pile made of the TRUE terrain and obstacles with the RECONSTRUCTED logs, against its mask in
  the render of the true pile — the same occluders in both, so only the logs' geometry differs;

plus obstacle matching (:func:`match_obstacles`: one-to-one, centres within ``obstacle_match_m`` + half the
true obstacle's size) and a
summary (medians, 95th percentiles, worst cases, counts). The reconstructed pile is brought into
the true pile's frame through both georeferences (:mod:`synth.geometry.geodesy`) when both have one,
otherwise the two frames are taken to be the same. Everything returned is JSON-serialisable.

:func:`simulate_scan` makes the inputs of :func:`reconstruct.pipeline.reconstruct` from a pile:
stereo pairs rendered by the twin (:mod:`synth.render.stereo`), the scan pose and a simulated RTK survey.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from synth.scene.pile import Georeference, LogSpec, PileSpec


#: an obstacle gate [m]: a reconstructed obstacle is a true one's when its centre lies within this much plus half
#: the true one's size of the true centre (horizontally). Half the size: a rock seen in part (half under a log,
#: cut by the scan's edge) is centred on the part the scan shows, anywhere over its footprint. 0.3 m beyond the
#: footprint is the smallest generated rock's diameter (``GenerationConfig.rock_size_m``): registration (1-2 cm)
#: and stereo smear are far less, and a centre a whole smallest obstacle outside the footprint is another thing
OBSTACLE_GATE_M = 0.3


def T_truth_recon(truth: PileSpec, recon: PileSpec) -> tuple[np.ndarray | None, str]:
    """Transform taking recon-pile points to truth-pile points (None: identity) and how."""
    if truth.georef is None or recon.georef is None:
        return None, "same frame assumed (a pile has no georeference)"
    g_t, g_r = truth.georef, recon.georef
    same_origin = (abs(g_t.origin_lat_deg - g_r.origin_lat_deg) < 1e-12
                   and abs(g_t.origin_lon_deg - g_r.origin_lon_deg) < 1e-12
                   and abs(g_t.origin_h_m - g_r.origin_h_m) < 1e-9)
    if same_origin:
        return np.linalg.inv(g_t.matrix()) @ g_r.matrix(), "through the common site frame"
    return None, "through geodetic coordinates"


def _to_truth(points: np.ndarray, truth: PileSpec, recon: PileSpec) -> np.ndarray:
    from synth.geometry import geodesy

    T, how = T_truth_recon(truth, recon)
    p = np.atleast_2d(np.asarray(points, dtype=np.float64))
    if T is not None:
        return p @ T[:3, :3].T + T[:3, 3]
    if how.startswith("through geodetic"):
        lat, lon, h = geodesy.pile_to_geodetic(recon.georef, p)
        return geodesy.geodetic_to_pile(truth.georef, lat, lon, h)
    return p


def _logs_in_truth_frame(truth: PileSpec, recon: PileSpec) -> list[LogSpec]:
    out = []
    for log in recon.logs:
        butt, top = log.endpoints_m()
        b, t = _to_truth(np.stack([butt, top]), truth, recon)
        out.append(LogSpec.from_endpoints(b, t, log.diameter_m, log.top_diameter_m, log.colour))
    return out


def _end_errors(t: LogSpec, r: LogSpec) -> tuple[float, float, bool]:
    """(mean, max) end distance with the ends paired the better way round, and whether swapped."""
    a0, a1 = t.endpoints_m()
    b0, b1 = r.endpoints_m()
    straight = (np.linalg.norm(a0 - b0), np.linalg.norm(a1 - b1))
    swapped = (np.linalg.norm(a0 - b1), np.linalg.norm(a1 - b0))
    if sum(swapped) < sum(straight):
        return float(np.mean(swapped)), float(max(swapped)), True
    return float(np.mean(straight)), float(max(straight)), False


def _render_instances(pile: PileSpec, size_px: int) -> np.ndarray:
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.physics.world import World

    with World(pile) as world:
        return render_ortho(world, OrthoRenderConfig(size_px=size_px, n_renders=1)).instance


def _obstacles(pile: PileSpec) -> list[dict]:
    out = []
    for s in pile.stumps:
        out.append({"kind": "stump", "xy": np.array(s.position_m, float), "size_m": 2 * s.bottom_radius_m})
    for r in pile.rocks:
        out.append({"kind": "rock", "xy": np.array(r.position_m[:2], float), "size_m": r.size_m()})
    return out


def _stats(values: list[float]) -> dict[str, float | None]:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    if v.size == 0:
        return {"median": None, "p95": None, "max": None, "mean": None}
    return {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(v.max()),
            "mean": float(v.mean())}


def compare_piles(truth: PileSpec, recon: PileSpec, size_px: int = 128, render: bool = True,
                  obstacle_match_m: float = OBSTACLE_GATE_M) -> dict:
    """Measure ``recon`` against ``truth`` (see the module docstring). Returns a JSON-serialisable
    dict: ``logs`` (one entry per matched log: ``truth_index``, ``recon_index``,
    ``endpoint_err_m``, ``endpoint_max_err_m``, ``length_err_m``, ``axis_angle_err_deg``,
    ``diameter_err_m``, ``butt_diameter_err_m``, ``mask_iou``, ``ends_swapped``),
    ``unmatched_truth``, ``unmatched_recon``, ``obstacles`` (matches, detection rate, false
    positives), ``frame`` (how the frames were related) and ``summary``.
    ``render=False`` skips the mask IoU (no pybullet)."""
    if not 16 <= size_px <= 2048:
        raise ValueError(f"size_px must be in [16, 2048], got {size_px}")
    _, how = T_truth_recon(truth, recon)
    rlogs = _logs_in_truth_frame(truth, recon)
    n_t, n_r = truth.n_logs, len(rlogs)
    pairs = _match_logs(truth, rlogs)
    inst_t, inst_r, iou_note = _instance_masks(truth, rlogs, size_px) if render else (None, None, "not rendered")
    logs = [_log_errors(truth.logs[i], rlogs[j], i, j, inst_t, inst_r) for i, j in pairs]
    obs_t, obs_r = _obstacles(truth), _obstacles(recon)
    for o in obs_r:
        o["xy"] = _to_truth(np.array([[o["xy"][0], o["xy"][1], 0.0]]), truth, recon)[0, :2]
    obstacle_matches = match_obstacles(obs_t, obs_r, obstacle_match_m)
    matched_t = {i for i, _ in pairs}
    matched_r = {j for _, j in pairs}
    return {
        "frame": how, "mask_iou_method": iou_note, "logs": logs,
        "unmatched_truth": [i for i in range(n_t) if i not in matched_t],
        "unmatched_recon": [j for j in range(n_r) if j not in matched_r],
        "obstacles": obstacle_matches, "summary": _summary(logs, obstacle_matches, n_t, n_r, len(obs_t), len(obs_r)),
    }


def _match_logs(truth: PileSpec, rlogs: list) -> list[tuple[int, int]]:
    """(truth index, recon index) pairs by the least total end error; a "match" farther than half
    a log length is no match."""
    from scipy.optimize import linear_sum_assignment

    cost = np.zeros((truth.n_logs, len(rlogs)))
    for i, t in enumerate(truth.logs):
        for j, r in enumerate(rlogs):
            cost[i, j] = _end_errors(t, r)[0]
    rows, cols = linear_sum_assignment(cost)
    return [(int(i), int(j)) for i, j in zip(rows, cols) if cost[i, j] < 0.5 * max(truth.logs[i].length_m, 0.5)]


def _instance_masks(truth: PileSpec, rlogs: list, size_px: int):
    """Instance renders of the true pile and of the reconstructed logs on the true terrain and
    obstacles, and how they were made (None, None and why when they could not be)."""
    try:
        inst_t = _render_instances(truth, size_px)
        inst_r = _render_instances(replace(truth, logs=tuple(rlogs)), size_px)
    except ValueError as exc:  # a reconstructed log off the true terrain patch
        return None, None, f"not rendered: {exc}"
    return inst_t, inst_r, f"{size_px} px orthographic renders, true terrain and obstacles in both"


def _log_errors(t, r, i: int, j: int, inst_t, inst_r) -> dict:
    """One matched log's errors (recon ``r`` against truth ``t``) and, with the renders, its mask IoU."""
    mean_e, max_e, swapped = _end_errors(t, r)
    cosang = abs(float(t.axis() @ r.axis()))
    entry = {
        "truth_index": i, "recon_index": j, "ends_swapped": swapped,
        "endpoint_err_m": mean_e, "endpoint_max_err_m": max_e,
        "length_err_m": float(r.length_m - t.length_m),
        "axis_angle_err_deg": float(math.degrees(math.acos(min(1.0, cosang)))),
        "diameter_err_m": float(r.mean_diameter_m - t.mean_diameter_m),
        "butt_diameter_err_m": float(r.diameter_m - t.diameter_m),
        "true_diameter_m": t.mean_diameter_m, "recon_diameter_m": r.mean_diameter_m,
        "mask_iou": None,
    }
    if inst_t is not None:
        mt, mr = inst_t == i + 1, inst_r == j + 1
        union = int((mt | mr).sum())
        entry["mask_iou"] = float((mt & mr).sum() / union) if union else None
        entry["true_mask_px"] = int(mt.sum())
    return entry


def match_obstacles(obs_t: list[dict], obs_r: list[dict], gate_m: float = OBSTACLE_GATE_M) -> list[dict]:
    """True obstacles paired one-to-one with reconstructed ones (dicts with ``xy`` in the same frame, ``kind``
    and ``size_m``): a pair is allowed when the horizontal centre distance is under ``gate_m`` plus half the
    true obstacle's size (:data:`OBSTACLE_GATE_M`); of the allowed pairings the one with the most pairs, then
    the least total distance (an assignment, so a reconstructed obstacle serves one true one at most and a
    near one is not taken from the true obstacle that has no other). One entry per true obstacle, in order;
    ``recon_index`` None: missed."""
    from scipy.optimize import linear_sum_assignment

    if gate_m < 0:
        raise ValueError(f"the obstacle gate must be >= 0 m, got {gate_m}")
    pair: dict[int, tuple[int, float]] = {}
    if obs_t and obs_r:
        d = np.array([[float(np.linalg.norm(o["xy"] - q["xy"])) for q in obs_r] for o in obs_t])
        allowed = d < gate_m + np.array([o["size_m"] / 2 for o in obs_t])[:, None]
        # a forbidden pair costs more than every allowed pair together: the most pairs first, then the least distance
        rows, cols = linear_sum_assignment(np.where(allowed, d, 1.0 + d.sum()))
        pair = {int(i): (int(j), float(d[i, j])) for i, j in zip(rows, cols) if allowed[i, j]}
    out = []
    for k, o in enumerate(obs_t):
        j, dist = pair.get(k, (None, None))
        out.append({"truth_index": k, "recon_index": j, "kind": o["kind"],
                    "recon_kind": None if j is None else obs_r[j]["kind"], "distance_m": dist})
    return out


def _summary(logs: list[dict], obstacle_matches: list[dict], n_t: int, n_r: int, n_obs_t: int, n_obs_r: int) -> dict:
    detected = sum(m["recon_index"] is not None for m in obstacle_matches)
    iou = [e["mask_iou"] for e in logs]
    return {
        "n_truth_logs": n_t, "n_recon_logs": n_r, "n_matched": len(logs),
        "endpoint_err_m": _stats([e["endpoint_err_m"] for e in logs]),
        "abs_diameter_err_m": _stats([abs(e["diameter_err_m"]) for e in logs]),
        "mask_iou": {**_stats(iou), "min": (min(v for v in iou if v is not None)
                                            if any(v is not None for v in iou) else None)},
        "n_truth_obstacles": n_obs_t, "n_recon_obstacles": n_obs_r,
        "obstacles_detected": detected,
        "obstacle_detection_rate": (detected / n_obs_t) if n_obs_t else None,
        "obstacle_false_positives": n_obs_r - detected,
        "obstacle_kind_agreement": (sum(m["kind"] == m["recon_kind"] for m in obstacle_matches if m["recon_index"] is not None)
                                    / detected) if detected else None,
    }


# -- twin scans ------------------------------------------------------------------------------
DEFAULT_ORIGIN = (64.1, 20.0, 250.0)  # SWEREF 99 lat [deg], lon [deg], ellipsoidal h [m]


def simulate_scan(pile: PileSpec, out_dir: str | Path, *, grid: tuple[int, int] = (1, 1),
                  spacing_m: tuple[float, float] = (1.4, 1.0), height_m: float = 3.0,
                  hfov_deg: float = 50.0, image_size: tuple[int, int] = (1280, 720),
                  seed: int = 0, origin: tuple[float, float, float] = DEFAULT_ORIGIN,
                  yaw_site_deg: float = 30.0, offset_site_m: tuple[float, float, float] = (12.0, -4.0, 0.5),
                  pose_error: tuple[float, float] = (0.0, 0.0), sigma_h_m: float = 0.015,
                  sigma_v_m: float = 0.025, renderer: str = "auto") -> tuple[Path, Path, PileSpec]:
    """Twin inputs for :func:`reconstruct.pipeline.reconstruct` from ``pile``.

    Gives the pile a georeference (site origin ``origin``; pile frame turned ``yaw_site_deg`` and
    shifted ``offset_site_m`` in the site frame) unless it has one, renders a ``grid`` of
    straight-down stereo pairs ``height_m`` above the pile frame origin, ``spacing_m`` apart
    (``out_dir/scan/pair_XY``; one pair: ``out_dir/scan`` itself), writes ``scan_pose.json``
    (the scan frame is the pile frame; ``pose_error`` = (metres, degrees) of error added to it, a
    random horizontal shift and yaw) and an RTK survey of the log end centres
    (``out_dir/survey.csv``, noise ``sigma_h_m``/``sigma_v_m``). Returns (scan folder, survey
    path, the georeferenced true pile)."""
    from reconstruct.survey.gnss import pile_endpoints_site, simulate_survey, write_gnss_csv
    from reconstruct.registration import ScanPose, write_scan_pose
    from synth.geometry.frames import make_T, rot_z
    from synth.render.stereo import StereoRenderer, StereoRigConfig

    out_dir = Path(out_dir)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5CA7]))
    if pile.georef is None:
        T = make_T(rot_z(math.radians(yaw_site_deg)), offset_site_m)
        pile = replace(pile, georef=Georeference(*origin, T_site_pile=tuple(tuple(float(v) for v in r) for r in T)))
    scan = out_dir / "scan"
    nx, ny = grid
    positions = [((ix - (nx - 1) / 2) * spacing_m[0], (iy - (ny - 1) / 2) * spacing_m[1])
                 for iy in range(ny) for ix in range(nx)]
    with StereoRenderer(renderer) as r:
        for k, (x, y) in enumerate(positions):
            rig = StereoRigConfig(width_px=image_size[0], height_px=image_size[1], hfov_deg=hfov_deg,
                                  height_m=height_m, target_m=(x, y, 0.0), renderer=renderer)
            pair = r.render(pile, rig)
            pair.save(scan if len(positions) == 1 else scan / f"pair_{k:02d}")
    T_site_scan = pile.georef.matrix()
    if pose_error[0] > 0 or pose_error[1] > 0:
        ang = rng.uniform(-1, 1) * math.radians(pose_error[1])
        d = rng.normal(size=2)
        d = d / np.linalg.norm(d) * pose_error[0]
        T_site_scan = make_T(rot_z(ang), (d[0], d[1], 0.0)) @ T_site_scan
    g = pile.georef
    write_scan_pose(ScanPose(g.origin_lat_deg, g.origin_lon_deg, g.origin_h_m,
                             T_site_scan=tuple(tuple(float(v) for v in row) for row in T_site_scan)), scan)
    survey = simulate_survey(pile_endpoints_site(pile), pile.georef, rng, sigma_h_m=sigma_h_m, sigma_v_m=sigma_v_m)
    gnss_path = write_gnss_csv(survey, out_dir / "survey.csv")
    return scan, gnss_path, pile
