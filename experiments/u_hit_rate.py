"""Where a network's grasp map peaks, against the labels: on validation samples with a grasp, the
share whose U argmax lies inside a labelled grasp region, and the median U maximum.

A low validation loss can hide a network that never commits (U flat and low everywhere: the argmax
is then noise and the planner's grasps land anywhere); this measures the thing planning uses.

    .venv/bin/python -m experiments.u_hit_rate data/paper-v3/.cache planner/weights/default.safetensors \\
        docs/results/learning-curve/share_0.125/model.safetensors
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from planner.model import INPUT_NAMES, OUTPUT_NAMES

U = OUTPUT_NAMES.index("U")  # the U channel of the network output and of the label maps


def validation_samples(data_dir: str | Path, every: int = 12) -> Iterable:
    """Render 0 of every validation sample with a grasp, from every ``every``-th shard."""
    from planner.data import is_validation_pile, list_shards, load_samples, sample_pile_id

    shards, _ = list_shards(data_dir)
    for shard in shards[::every]:
        for s in load_samples(shard):
            if s.render == 0 and not s.negative and is_validation_pile(sample_pile_id(s)):
                yield s


def hit_rates(samples: Iterable, predictors: dict[str, Callable[[np.ndarray], np.ndarray]],
              camera_height_m: float = 5.0) -> dict[str, dict]:
    """``predictors``: name -> predict(inputs (1, 3, H, W): I, D, M_T) -> outputs (1, 5, H, W), U as a logit.
    Returns per name: samples, hit rate, median of the U maximum (after the sigmoid)."""
    from planner.data import make_inputs, sample_arrays

    hits: dict[str, list[bool]] = {n: [] for n in predictors}
    peaks: dict[str, list[float]] = {n: [] for n in predictors}
    for s in samples:
        inten, depth, mask, maps = sample_arrays(s)
        x = make_inputs(inten, depth, mask[None], 3, camera_height_m)
        for name, predict in predictors.items():
            u = 1.0 / (1.0 + np.exp(-predict(x)[0, U].astype(np.float64)))
            r, c = np.unravel_index(np.argmax(u), u.shape)
            hits[name].append(bool(maps[U, r, c] > 0.5))
            peaks[name].append(float(u.max()))
    return {n: {"samples": len(hits[n]), "hit_rate": float(np.mean(hits[n])) if hits[n] else float("nan"),
                "u_max_median": float(np.median(peaks[n])) if peaks[n] else float("nan")} for n in predictors}


def _three_inputs(planner) -> Callable[[np.ndarray], np.ndarray]:
    """``planner.predict`` on (I, D, M_T) inputs, the depth left out for a model without it."""
    keep = [INPUT_NAMES[3].index(n) for n in INPUT_NAMES[planner.config.in_channels]]
    return lambda x: planner.predict(x[:, keep])


def main(argv=None) -> int:
    from planner.inference import load_planner

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", help="a materialised data set (e.g. data/paper-v3/.cache)")
    ap.add_argument("models", nargs="+", help="checkpoints (.safetensors)")
    ap.add_argument("--every", type=int, default=12, help="every N-th shard")
    a = ap.parse_args(argv)
    nets = {m: _three_inputs(load_planner(m)) for m in a.models}
    for name, r in hit_rates(validation_samples(a.data, a.every), nets).items():
        print(f"{name}: {r['samples']} samples, argmax in a labelled region {100 * r['hit_rate']:.1f} %, "
              f"median U max {r['u_max_median']:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
