"""Where the product's chosen grasps stand against two physical limits, with their twin outcomes.

On the records of a ``loggrasp eval`` folder (each pile regenerated from its seed, as the evaluation made it),
two measures of every chosen grasp:

* **clearance** [m]: the distance from the opening's rectangle (the opening x
  :data:`planner.inference.RECT_WIDTH_M`, what ``Constraints.clear_obstacles`` tested before the claws' own
  footprint became the default, docs/results/README.md "obstacle-footprint") to the nearest obstacle
  pixel of the observation, for the exact and the field execution (the grasp moved by the crane's positioning
  error). If failures gathered within a few centimetres of a visible obstacle, a margin of the positioning
  error around the rectangle would be the principled next step; this measures whether they do;
* **fill** [-]: the targets' total cross-section (each log the mean section of its frustum) over the area the
  closed claws enclose (:data:`GRAPPLE_CLOSED_AREA_M2`, :class:`synth.physics.grapple.GrappleConfig`). A bundle
  the bowl cannot hold cannot be closed on: if NOT_CLOSED rose sharply at some fill, a capacity limit would
  be a constraint with a physical reason rather than something the ranker must learn.

Prints success and failure kinds per bin of each measure, per objective::

    .venv/bin/python -m experiments.choice_geometry docs/results/eval-product-1200 --out runs/choice-geometry.json
"""

from __future__ import annotations

import argparse
import collections
import json
import math
from pathlib import Path

import numpy as np

#: the twin grapple's enclosed area when closed [m^2] (GrappleConfig's docstring: a 0.35 m^2 forwarder grapple)
GRAPPLE_CLOSED_AREA_M2 = 0.35
CLEARANCE_EDGES_M = (0.0, 0.05, 0.10, 0.20, 0.40, math.inf)
FILL_EDGES = (0.0, 0.2, 0.3, 0.4, 0.5, math.inf)


def mean_section_m2(diameter_m: float, top_diameter_m: float | None) -> float:
    """Mean cross-section [m^2] of a frustum with end diameters ``diameter_m`` and ``top_diameter_m``."""
    d0, d1 = diameter_m, top_diameter_m or diameter_m
    return math.pi / 4 * (d0 * d0 + d0 * d1 + d1 * d1) / 3


def bundle_fill(pile, targets, closed_area_m2: float = GRAPPLE_CLOSED_AREA_M2) -> float:
    """The targets' total mean cross-section over the closed grapple's area [-]."""
    return sum(mean_section_m2(pile.logs[i].diameter_m, pile.logs[i].top_diameter_m) for i in targets) / closed_area_m2


def clearance_m(observation, grasp: dict) -> float | None:
    """Distance [m] from ``grasp``'s swept rectangle to the nearest obstacle pixel (None when the observation
    shows no obstacle or the rectangle lies outside it)."""
    from scipy.ndimage import distance_transform_edt

    from planner.constraints import polygon_raster
    from planner.inference import OBSTACLE_CODE_BASE, RECT_WIDTH_M, observation_arrays
    from synth.geometry.frames import OrthoGrid
    from synth.geometry.grasp import Grasp

    _, depth, inst, extent_m, _ = observation_arrays(observation)
    obstacle = inst >= OBSTACLE_CODE_BASE
    if not obstacle.any():
        return None
    grid = OrthoGrid(depth.shape[0], extent_m)
    g = Grasp(**{k: grasp[k] for k in ("x_m", "y_m", "phi_rad", "width_m")})
    rect = polygon_raster(grid, g.rectangle(RECT_WIDTH_M)).astype(bool)
    if not rect.any():
        return None
    return float((distance_transform_edt(~obstacle) * grid.pixel_m)[rect].min())


def measure(folder: Path, seed_base: int, limit: int | None = None, progress=None) -> list[dict]:
    """One row per chosen grasp of the folder's records: planner, targets, fill, clearance and outcomes."""
    from planner.evaluate import EvalConfig, eval_scene

    piles: dict[tuple, list[dict]] = {}
    for f in sorted(Path(folder, "records").glob("*.json")):
        for r in json.loads(f.read_text()):
            if r.get("grasp") is not None:
                piles.setdefault((int(r["n_logs"]), bool(r["obstacles"]), int(r["k"]), int(r["seed"])), []).append(r)
    rows = []
    for n, (task, records) in enumerate(sorted(piles.items())[:limit]):
        pile, obs = eval_scene(task, EvalConfig(seed_base=seed_base))
        for r in records:
            field = r.get("field") or {}
            rows.append(dict(seed=task[3], planner=r["planner"], obstacles=task[1], tau=len(r["targets"]),
                             fill=bundle_fill(pile, r["targets"]), clearance_m=clearance_m(obs, r["grasp"]),
                             outcome=r["outcome"], field_clearance_m=(clearance_m(obs, field["grasp"])
                                                                       if field.get("grasp") else None),
                             field_outcome=field.get("outcome")))
        if progress:
            progress(n + 1, min(len(piles), limit or len(piles)))
    return rows


def binned(rows: list[dict], key: str, edges, outcome: str = "outcome") -> list[dict]:
    """Per bin [edges[i], edges[i+1]) of ``key``: count, success share and the failure kinds."""
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        x = [r for r in rows if r[key] is not None and lo <= r[key] < hi and r[outcome] is not None]
        if x:
            out.append(dict(lo=lo, hi=hi, n=len(x), success=float(np.mean([r[outcome] == "success" for r in x])),
                            failures=dict(collections.Counter(r[outcome] for r in x if r[outcome] != "success"))))
    return out


def report(rows: list[dict]) -> str:
    lines = []
    for objective in sorted({r["planner"] for r in rows}):
        mine = [r for r in rows if r["planner"] == objective]
        lines.append(f"{objective}: {len(mine)} choices")
        for title, key, edges, outcome, sel in (
                ("clearance [m], obstacle piles", "clearance_m", CLEARANCE_EDGES_M, "outcome", lambda r: r["obstacles"]),
                ("clearance [m], field execution", "field_clearance_m", CLEARANCE_EDGES_M, "field_outcome",
                 lambda r: r["obstacles"]),
                ("fill, three or more targets", "fill", FILL_EDGES, "outcome", lambda r: r["tau"] >= 3)):
            lines.append(f"  {title}")
            for b in binned([r for r in mine if sel(r)], key, edges, outcome):
                lines.append(f"    [{b['lo']:.2f}, {b['hi']:.2f}): n {b['n']:4d}, success {100 * b['success']:5.1f} %, "
                             f"{b['failures']}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path, help="a loggrasp eval results folder (with records/)")
    ap.add_argument("--seed-base", type=int, default=970_000_000, help="the evaluation's --seed-base")
    ap.add_argument("--limit", type=int, default=None, help="only the first N piles (sorted by cell and seed)")
    ap.add_argument("--out", type=Path, default=None, help="write every row as JSON here")
    a = ap.parse_args(argv)
    if not Path(a.folder, "records").is_dir():
        raise SystemExit(f"error: {a.folder} has no records/ folder; give a loggrasp eval results folder")
    rows = measure(a.folder, a.seed_base, a.limit,
                   progress=lambda i, n: print(f"piles: {i}/{n}", flush=True) if i % 50 == 0 or i == n else None)
    print(report(rows))
    if a.out:
        a.out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
