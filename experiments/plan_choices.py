"""The planner's choices on a fixed set of piles, recorded and compared: does a change meant only to
make planning faster (kernels, batch size, vectorised post-processing) leave every plan as it was?

:func:`record_choices` plans each pile of a fixed list (``EvalConfig``-style tasks: the evaluation's
own pile and render code) with each objective and keeps, per subset, its best grasp (pixel, pose,
width, q, u, b); :func:`compare_choices` pairs two such records and reports the chosen subset and
grasp of each (pile, objective) and the largest differences over all subsets. Written with
:class:`synth.common.formats.VersionedJson` (``loggrasp.plan-choices``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from synth.common.formats import VersionedJson

CHOICES_FORMAT = VersionedJson("loggrasp.plan-choices", "1.0", "plan-choices record", ValueError,
                               fix="record it again with this loggrasp")
PIXEL_TOL_PX = 1.0  # a chosen grasp "the same" within this distance [px] ...
ANGLE_TOL_RAD = 0.01  # ... and this angle [rad]
WIDTH_TOL_M = 0.01  # ... and this opening width [m]


def choice_tasks(logs=(3, 4, 5, 6, 7), per_cell: int = 2, seed_base: int = 950_000_000) -> list[tuple]:
    """(n_logs, obstacles, k, seed) of the fixed piles: ``per_cell`` per pile size, with and
    without obstacles (20 piles by default)."""
    from planner.evaluate import EvalConfig

    return EvalConfig(logs=tuple(logs), obstacles=(False, True), per_cell=per_cell, seed_base=seed_base).tasks()


def _observation(task, cache_dir: Path | None):
    """The task's observation (the evaluation's :func:`planner.evaluate.eval_scene`), kept as an npz
    in ``cache_dir`` so that two code versions plan on identical arrays."""
    from types import SimpleNamespace

    from planner.evaluate import EvalConfig, eval_scene

    path = None if cache_dir is None else Path(cache_dir) / f"pile-{task[3]}.npz"
    if path is not None and path.exists():
        z = np.load(path)
        return SimpleNamespace(intensity=z["intensity"], depth=z["depth"], instance=z["instance"],
                               extent_m=float(z["extent_m"]), camera_height_m=float(z["camera_height_m"]))
    _, obs = eval_scene(task, EvalConfig())
    if path is not None:
        import io

        from synth.common.files import atomic_write_bytes

        buf = io.BytesIO()
        np.savez_compressed(buf, intensity=np.asarray(obs.intensity), depth=np.asarray(obs.depth),
                            instance=np.asarray(obs.instance), extent_m=obs.extent_m,
                            camera_height_m=obs.camera_height_m)
        atomic_write_bytes(path, buf.getvalue())
    return obs


def record_choices(planner, tasks, objectives=("f1", "f3"), cache_dir: str | Path | None = None) -> dict:
    """Every subset's best grasp of every (pile, objective), best first, as plain data."""
    from planner.inference import Objective, plan

    piles = []
    for task in tasks:
        obs = _observation(task, None if cache_dir is None else Path(cache_dir))
        for obj in objectives:
            p = plan(obs, planner, Objective(obj))
            piles.append({"seed": int(task[3]), "logs": int(task[0]), "obstacles": bool(task[1]), "objective": obj,
                          "subsets": p.subsets_evaluated,
                          "grasps": [{"targets": list(g.targets), "pixel": list(g.pixel), "x_m": g.grasp.x_m,
                                      "y_m": g.grasp.y_m, "phi_rad": g.grasp.phi_rad, "width_m": g.grasp.width_m,
                                      "q": g.quality, "u": g.graspability, "b": g.balance} for g in p.grasps]})
    from planner.runtime import masks_per_pass

    return {"precision": planner.precision, "batch_size": masks_per_pass(planner.batch_size), "piles": piles}


def write_choices(path: str | Path, rec: dict) -> None:
    CHOICES_FORMAT.write(path, rec, indent=None)


def read_choices(path: str | Path) -> dict:
    return CHOICES_FORMAT.read(path)


def _angle_diff(a: float, b: float) -> float:
    """|a - b| for grasp angles, which repeat every pi [rad]."""
    d = (a - b) % math.pi
    return min(d, math.pi - d)


def compare_choices(before: dict, after: dict) -> dict:
    """Per (pile, objective): the same chosen subset? the chosen grasps' pixel, angle and width
    differences; over every subset's best grasp: the largest |du|, |dq| and the subsets whose best
    pixel moved by more than :data:`PIXEL_TOL_PX`."""
    key = lambda p: (p["seed"], p["objective"])  # noqa: E731
    b_of = {key(p): p for p in before["piles"]}
    rows, all_du = [], []
    for pa in after["piles"]:
        pb = b_of.get(key(pa))
        if pb is None:
            raise ValueError(f"pile {pa['seed']} / {pa['objective']} is not in the earlier record")
        gb, ga = pb["grasps"][0], pa["grasps"][0]
        sub_b = {tuple(g["targets"]): g for g in pb["grasps"]}
        du = dq = 0.0
        moved = 0
        for g in pa["grasps"]:
            o = sub_b[tuple(g["targets"])]
            all_du.append(abs(g["u"] - o["u"]))
            du, dq = max(du, abs(g["u"] - o["u"])), max(dq, abs(g["q"] - o["q"]))
            moved += math.dist(g["pixel"], o["pixel"]) > PIXEL_TOL_PX
        d_px = math.dist(ga["pixel"], gb["pixel"])
        d_phi = _angle_diff(ga["phi_rad"], gb["phi_rad"])
        d_w = abs(ga["width_m"] - gb["width_m"])
        rows.append({"seed": pa["seed"], "logs": pa["logs"], "obstacles": pa["obstacles"],
                     "objective": pa["objective"], "subsets": pa["subsets"],
                     "same_targets": ga["targets"] == gb["targets"], "d_px": d_px, "d_phi_rad": d_phi, "d_width_m": d_w,
                     "same_grasp": (ga["targets"] == gb["targets"] and d_px <= PIXEL_TOL_PX and d_phi <= ANGLE_TOL_RAD
                                    and d_w <= WIDTH_TOL_M),
                     "max_du": du, "max_dq": dq, "subsets_moved": moved})
    return {"rows": rows, "same": sum(r["same_grasp"] for r in rows), "n": len(rows),
            "same_targets": sum(r["same_targets"] for r in rows),
            "max_du": max((r["max_du"] for r in rows), default=0.0),
            "median_du": float(np.median(all_du)) if all_du else 0.0,
            "subsets_moved": sum(r["subsets_moved"] for r in rows),
            "subsets": sum(r["subsets"] for r in rows)}


def choices_markdown(cmp: dict, before: dict, after: dict) -> list[str]:
    lines = [f"Chosen grasps before ({before['precision']}, batch {before['batch_size']}) and after "
             f"({after['precision']}, batch {after['batch_size']}): {cmp['same']}/{cmp['n']} (pile, objective) "
             f"pairs choose the same subset and grasp (within {PIXEL_TOL_PX:g} px, {ANGLE_TOL_RAD:g} rad, "
             f"{WIDTH_TOL_M:g} m) and {cmp['same_targets']}/{cmp['n']} the same subset; over all {cmp['subsets']} "
             f"subsets' best grasps, {cmp['subsets_moved']} moved by more than {PIXEL_TOL_PX:g} px and |du| is "
             f"{cmp['median_du']:.2g} at the median, {cmp['max_du']:.2g} at most.", "",
             "| seed | logs | obstacles | objective | subsets | same subset | d pixel | d phi rad | max abs du |",
             "|---|---|---|---|---|---|---|---|---|"]
    return lines + [f"| {r['seed']} | {r['logs']} | {'yes' if r['obstacles'] else 'no'} | {r['objective']} | "
                    f"{r['subsets']} | {'yes' if r['same_targets'] else 'NO'} | {r['d_px']:.1f} | "
                    f"{r['d_phi_rad']:.2g} | {r['max_du']:.2g} |" for r in cmp["rows"]]
