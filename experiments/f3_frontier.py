"""What stands between f3 and "90 % with at least 4 logs": the scorer, or the candidates?

On a folder of tried grasps (``experiments.ranking run``: on each pile the union of the best subsets by f1
and by f3 tried in the twin, the union the product's ranker re-scores), with the shipped ranker's ``p``
beside each grasp's U (``experiments.ranking rescore ... --out FILE``), this prints

* **the frontier**: f3's choice among the tried grasps (success and logs per success) when U is replaced
  by ``sigmoid(w logit U + (1 - w) logit p + c)`` for a grid of the blend's U weight ``w`` and an offset
  ``c`` (``c`` < 0 makes the score a probability rather than a rank: f3's ``tau^(1/3)`` then buys fewer
  logs with it), beside **the oracle**: on each pile the successful tried grasp with the most targets;
* **the targets' span across the closing axis**: the extent, along the claws' closing axis, of the
  target pixels that lie under the claws' plates (within half a plate width of the grasp line), as the
  planner sees them (:func:`target_span_m`); per span bin the tried grasps' success, their NOT_CLOSED
  share and the ranker's mean p. Wide bundles are the claws' NOT_CLOSED; the question is whether p
  already knows it.

::

    .venv/bin/python -m experiments.ranking rescore docs/results/ranking-v3model-rev4 \\
        --ranker planner/weights/ranker.safetensors --out runs/rescored-r3.json
    .venv/bin/python -m experiments.f3_frontier runs/rescored-r3.json --records docs/results/ranking-v3model-rev4
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from experiments.ranking import _by_pile

#: edges of the span bins [m] (the twin's grapple opens 0.30-1.55 m)
SPAN_EDGES_M = (0.0, 0.6, 0.8, 1.0, 1.15, 1.3, 1.45, 2.0)
#: the frontier's grid: the blend's U weight [-] and the offset of its logit [-]
U_WEIGHTS = (1.0, 0.75, 0.5, 0.25, 0.0)
OFFSETS = (0.0, -2.0, -4.0)


def target_span_m(target_crop: np.ndarray, pixel_m: float, plate_width_m: float) -> float:
    """Extent [m] along the closing axis of the target pixels within ``plate_width_m / 2`` of the grasp
    line, in a grasp-aligned crop (rows across the closing axis, columns along it, the grasp line through
    the crop's centre row; :func:`planner.ranker.grasp_crops`' ``M_T`` channel); 0 when none lies there."""
    s = target_crop.shape[0]
    v = (np.arange(s) - (s - 1) / 2) * pixel_m
    cols = np.flatnonzero(target_crop[np.abs(v) <= plate_width_m / 2 + 1e-9].any(axis=0))
    return float((cols.max() - cols.min() + 1) * pixel_m) if len(cols) else 0.0


def _logit(x) -> np.ndarray:
    x = np.clip(np.asarray(x, dtype=np.float64), 1e-6, 1 - 1e-6)
    return np.log(x / (1 - x))


def f3_choice(records: list[dict], score: np.ndarray) -> dict:
    """f3's choice on each pile with U replaced by ``score``: piles, successes, logs per success."""
    from planner.inference import Objective

    f3 = Objective("f3")
    scored = [dict(r, score=float(s)) for r, s in zip(records, score)]
    chosen = [max(rs, key=lambda r: float(f3.quality(r["score"], r["tau"], r["b"]))) for rs in _by_pile(scored).values()]
    won = [r for r in chosen if r["success"]]
    return {"piles": len(chosen), "successes": len(won),
            "logs_per_success": float(np.mean([r["tau"] for r in won])) if won else float("nan")}


def oracle(records: list[dict]) -> dict:
    """On each pile, the successful tried grasp with the most targets (none where every one failed)."""
    piles = _by_pile(records)
    best = [max((r for r in rs if r["success"]), key=lambda r: r["tau"]) for rs in piles.values()
            if any(r["success"] for r in rs)]
    return {"piles": len(piles), "successes": len(best),
            "logs_per_success": float(np.mean([r["tau"] for r in best])) if best else float("nan")}


def frontier(records: list[dict]) -> list[dict]:
    """f3's choice for every (U weight, offset) of the grid (module doc)."""
    lu, lp = _logit([r["u"] for r in records]), _logit([r["p"] for r in records])
    return [{"u_weight": w, "offset": c, **f3_choice(records, 1 / (1 + np.exp(-(w * lu + (1 - w) * lp + c))))}
            for w in U_WEIGHTS for c in OFFSETS]


def spans(records: list[dict], seed_base: int) -> list[float]:
    """Each tried grasp's :func:`target_span_m` on its pile's observation (the scene made again from the seed)."""
    from planner.data import normalise_depth
    from planner.evaluate import EvalConfig, eval_scene
    from planner.inference import observation_arrays
    from planner.ranker import RankerConfig, grasp_crops
    from synth.geometry.frames import OrthoGrid
    from synth.geometry.grasp import Grasp

    cfg, out = RankerConfig(), {}
    piles: dict[int, list[int]] = {}
    for i, r in enumerate(records):
        piles.setdefault(int(r["seed"]), []).append(i)
    for seed, idx in piles.items():
        r0 = records[idx[0]]
        _, obs = eval_scene((r0["n_logs"], bool(r0["obstacles"]), 0, seed), EvalConfig(seed_base=seed_base))
        inten, depth, inst, extent_m, cam_h = observation_arrays(obs)
        grasps = [Grasp(**{k: records[i]["grasp"][k] for k in ("x_m", "y_m", "phi_rad", "width_m")}) for i in idx]
        masks = np.stack([np.isin(inst, [t + 1 for t in records[i]["targets"]]) for i in idx])
        crops = grasp_crops(inten, normalise_depth(depth, cam_h), masks, OrthoGrid(depth.shape[0], extent_m), grasps, cfg,
                            inst)
        for i, crop in zip(idx, crops):
            out[i] = target_span_m(crop[2], cfg.pixel_m, cfg.claw_width_m)
    return [out[i] for i in range(len(records))]


def span_table(records: list[dict], span_m: list[float]) -> list[dict]:
    """Per span bin: tried grasps, success, NOT_CLOSED share, mean p and mean number of targets."""
    rows = []
    for lo, hi in zip(SPAN_EDGES_M, SPAN_EDGES_M[1:]):
        rs = [r for r, s in zip(records, span_m) if lo <= s < hi]
        if rs:
            rows.append({"span_m": (lo, hi), "grasps": len(rs), "success": float(np.mean([r["success"] for r in rs])),
                         "not_closed": float(np.mean([r["outcome"] == "not_closed" for r in rs])),
                         "p": float(np.mean([r["p"] for r in rs])), "targets": float(np.mean([r["tau"] for r in rs]))})
    return rows


def markdown(front: list[dict], orc: dict, table: list[dict]) -> str:
    lines = ["| U weight w | offset c | f3 success | logs / success |", "|---|---|---|---|"]
    lines += [f"| {f['u_weight']:.2f} | {f['offset']:+.0f} | {f['successes']} / {f['piles']} | "
              f"{f['logs_per_success']:.2f} |" for f in front]
    lines += [f"| oracle | | {orc['successes']} / {orc['piles']} | {orc['logs_per_success']:.2f} |", "",
              "| span [m] | tried grasps | success | NOT_CLOSED | ranker p (mean) | targets (mean) |",
              "|---|---|---|---|---|---|"]
    lines += [f"| {t['span_m'][0]:.2f}-{t['span_m'][1]:.2f} | {t['grasps']} | {100 * t['success']:.0f} % | "
              f"{100 * t['not_closed']:.0f} % | {t['p']:.2f} | {t['targets']:.1f} |" for t in table]
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rescored", help="tried grasps with the ranker's p (experiments.ranking rescore --out)")
    ap.add_argument("--records", required=True, help="the ranking folder they come from (its collect.json: the seeds)")
    a = ap.parse_args(argv)
    records = json.loads(Path(a.rescored).read_text())
    if not records or "p" not in records[0]:
        ap.error(f"{a.rescored} holds no rescored grasps (make it with experiments.ranking rescore --out)")
    collect = Path(a.records) / "collect.json"
    if not collect.is_file():
        ap.error(f"{a.records} has no collect.json: give the folder experiments.ranking run --out wrote")
    seed_base = json.loads(collect.read_text())["seed_base"]
    print(markdown(frontier(records), oracle(records), span_table(records, spans(records, seed_base))))


if __name__ == "__main__":
    main()
