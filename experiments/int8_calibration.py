"""The int8 calibration of a planner checkpoint (:mod:`planner.int8`), written beside it.

Inputs are real training inputs: piles drawn (fixed seed) from the committed stores
``data/paper-v4`` and ``data/mixed-v4``, each rendered as the store renders it (its pile seed, one of
its renders drawn per subset) with the target masks of the subsets the store labelled.

    .venv/bin/python -m experiments.int8_calibration [--model planner/weights/default.safetensors]
        [--stores data/paper-v4 data/mixed-v4] [--piles-per-store 16] [--seed 0] [--out PATH]
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_STORES = (ROOT / "data" / "paper-v4", ROOT / "data" / "mixed-v4")


def store_inputs(stores=DEFAULT_STORES, piles_per_store: int = 16, seed: int = 0,
                 in_channels: int = 3) -> Iterator[tuple[str, np.ndarray]]:
    """(pile name, network inputs (N, C, H, W) of its labelled subsets) for ``piles_per_store``
    piles of each store, drawn without replacement with ``seed``."""
    from planner.data import make_inputs
    from synth.data.datastore import open_store, read_chunk
    from synth.physics.world import World
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.scene.pile import PileSpec

    rng = np.random.default_rng(seed)
    for store_dir in stores:
        store_dir = Path(store_dir)
        job, chunks, store = open_store(store_dir)
        keys = sorted(chunks)
        for c in sorted(rng.choice(keys, size=min(piles_per_store, len(keys)), replace=False)):
            rec = read_chunk(store_dir / chunks[int(c)]["file"], store["params_sha256"])
            for p in rec["piles"]:
                if not p["subsets"]:
                    continue
                with World(PileSpec.from_dict(p["pile"])) as world:
                    obs = render_ortho(world, OrthoRenderConfig(size_px=job.size_px, n_renders=job.n_renders),
                                       seed=int(p["pile_seed"]))
                renders = rng.integers(0, job.n_renders, size=len(p["subsets"]))
                x = np.concatenate([make_inputs(obs.intensity[r], obs.depth, obs.target_mask(s["targets"]),
                                                in_channels, obs.camera_height_m)
                                    for s, r in zip(p["subsets"], renders)])
                yield f"{store_dir.name}/{p['pile_id']}", x


def calibrate_checkpoint(model_path: str | Path, stores=DEFAULT_STORES, piles_per_store: int = 16, seed: int = 0,
                         out: str | Path | None = None) -> Path:
    """Calibrate ``model_path`` on the stores' inputs and write the calibration (default: beside it)."""
    from planner.checkpoint import load_checkpoint
    from planner.int8 import calibrate, calibration_path, write_calibration

    model, config, _ = load_checkpoint(model_path)
    names: list[str] = []

    def batches():
        for name, x in store_inputs(stores, piles_per_store, seed, config.in_channels):
            names.append(name)
            yield x

    meta = {"checkpoint": Path(model_path).name, "stores": [Path(s).name for s in stores],
            "piles_per_store": piles_per_store, "pile_seed": seed}
    cal = calibrate(model, batches(), meta)
    cal.meta["piles"] = names
    return write_calibration(out or calibration_path(model_path), cal)


if __name__ == "__main__":
    import argparse

    import torch

    from planner.checkpoint import DEFAULT_MODEL

    ap = argparse.ArgumentParser(description="Write a planner checkpoint's int8 calibration beside it.")
    ap.add_argument("--model", default=str(DEFAULT_MODEL), help="checkpoint (default: the shipped model)")
    ap.add_argument("--stores", nargs="+", default=[str(s) for s in DEFAULT_STORES], help="committed stores")
    ap.add_argument("--piles-per-store", type=int, default=16, help="piles drawn from each store")
    ap.add_argument("--seed", type=int, default=0, help="seed of the pile and render draw")
    ap.add_argument("--out", default=None, help="where to write it (default: beside the checkpoint)")
    a = ap.parse_args()
    torch.set_num_threads(1)
    path = calibrate_checkpoint(a.model, a.stores, a.piles_per_store, a.seed, a.out)
    print(f"wrote {path}")
