"""Fit and check planner.balance.HangModel on the twin's tilt of successful grasps.

Each successful grasp with a measured tilt gives a sample: ``d``, the grasp centre's offset from the
centroid of its targets' mask in the top-down render (along the mask's principal axis, or the whole
distance with ``--offset radial``: ``HangModel.offsets_m``); ``m``, the targets' mass (the pile's
log volumes at ``Constraints.wood_density_kg_m3``); ``beta``, the twin's tilt. The model's two
parameters are the least-squares fit of ``beta = atan(d / (h + M / m))``; the check reports the
mean absolute error and the rank correlation on other piles, beside the network's own B map where
the records carry it (``b``)::

    .venv/bin/python -m experiments.hang_fit --fit docs/results/ranking-v3model-rev4 \\
        --check docs/results/eval-aft4-970

A folder is either a ranking folder (``collect.json`` and its records) or an evaluation folder
(``eval.json`` and ``records/*.json``); the piles are made again from their seeds.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from planner.balance import HangModel, tilt_deg


def read_successes(folder: str | Path) -> tuple[list[dict], int]:
    """The successful records with a measured tilt of a ranking or evaluation folder, and its seed base."""
    folder = Path(folder)
    if (folder / "collect.json").is_file():
        from experiments.subset_outcomes import read_records

        recs, base = read_records(folder), json.loads((folder / "collect.json").read_text())["seed_base"]
    elif (folder / "eval.json").is_file():
        recs = [r for f in sorted((folder / "records").glob("*.json")) for r in json.loads(f.read_text())]
        base = json.loads((folder / "eval.json").read_text())["config"]["seed_base"]
    else:
        raise ValueError(f"{folder} has neither collect.json (a ranking folder) nor eval.json (an evaluation folder)")
    return [r for r in recs if r.get("outcome") == "success" and r.get("cos_beta") is not None], int(base)


def samples(records: list[dict], seed_base: int, offset: str = "along_axis") -> np.ndarray:
    """(n, 4): offset d [m], load mass [kg], the twin's beta [deg], the network's beta [deg] (NaN if absent)."""
    from planner.constraints import Constraints
    from planner.evaluate import EvalConfig, eval_scene
    from planner.inference import observation_arrays
    from synth.geometry.frames import OrthoGrid

    density = Constraints().wood_density_kg_m3
    by_seed: dict[int, list[dict]] = {}
    for r in records:
        by_seed.setdefault(int(r["seed"]), []).append(r)
    rows = []
    for seed, rs in sorted(by_seed.items()):
        pile, obs = eval_scene((rs[0]["n_logs"], bool(rs[0]["obstacles"]), 0, seed), EvalConfig(seed_base=seed_base))
        _, depth, inst, extent_m, _ = observation_arrays(obs)
        grid = OrthoGrid(depth.shape[0], extent_m)
        for r in rs:
            mask = np.isin(inst, [i + 1 for i in r["targets"]])
            if not mask.any():
                continue
            gr, gc = grid.pile_to_pixel(r["grasp"]["x_m"], r["grasp"]["y_m"])
            d = float(HangModel(offset=offset).offsets_m(mask, grid.pixel_m, gr, gc))
            mass = sum(pile.logs[i].volume_m3() for i in r["targets"]) * density
            net = tilt_deg(r["b"]) if r.get("b") is not None else math.nan
            rows.append((d, mass, tilt_deg(r["cos_beta"]), net))
    return np.array(rows, float).reshape(-1, 4)


def predict_deg(model: HangModel, s: np.ndarray) -> np.ndarray:
    return np.degrees(np.arctan(s[:, 0] / (model.load_drop_m + model.grapple_moment_kg_m / s[:, 1])))


def fit(s: np.ndarray, offset: str = "along_axis") -> HangModel:
    """The least-squares HangModel of samples ``s`` (beta in degrees) made with ``offset``."""
    from scipy.optimize import minimize

    def loss(p):
        return float(np.mean((s[:, 2] - predict_deg(HangModel(abs(p[0]) + 1e-6, abs(p[1])), s)) ** 2))

    p = minimize(loss, [1.0, 100.0], method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-8}).x
    return HangModel(abs(p[0]) + 1e-6, abs(p[1]), offset=offset)


def agreement(pred_deg: np.ndarray, true_deg: np.ndarray) -> dict:
    from scipy.stats import spearmanr

    ok = np.isfinite(pred_deg)
    if ok.sum() < 3:
        return {"n": int(ok.sum()), "mae_deg": math.nan, "spearman": math.nan}
    return {"n": int(ok.sum()), "mae_deg": float(np.mean(np.abs(pred_deg[ok] - true_deg[ok]))),
            "spearman": float(spearmanr(pred_deg[ok], true_deg[ok])[0])}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fit", required=True, help="the folder whose successes fit the model")
    ap.add_argument("--check", action="append", default=[], help="a folder of other piles to check it on")
    ap.add_argument("--offset", choices=("along_axis", "radial"), default="along_axis",
                    help="which part of the grasp's offset tilts the load (planner.balance.HangModel.offset)")
    a = ap.parse_args(argv)
    s_fit = samples(*read_successes(a.fit), offset=a.offset)
    model = fit(s_fit, a.offset)
    print(f"fitted on {len(s_fit)} successes of {a.fit}: load_drop_m {model.load_drop_m:.3f} m, "
          f"grapple_moment_kg_m {model.grapple_moment_kg_m:.1f} kg m (shipped: {HangModel()})")
    for name, folder in [("fit", a.fit)] + [("check", c) for c in a.check]:
        s = s_fit if name == "fit" else samples(*read_successes(folder), offset=a.offset)
        for who, pred in (("hang model (fitted)", predict_deg(model, s)), ("hang model (shipped)",
                                                                          predict_deg(HangModel(), s)),
                          ("network B", s[:, 3])):
            g = agreement(pred, s[:, 2])
            print(f"- {name} {folder}: {who}: n {g['n']}, MAE {g['mae_deg']:.1f} deg, Spearman {g['spearman']:.3f}"
                  f" (the twin's mean beta {s[:, 2].mean():.1f} deg)")


if __name__ == "__main__":
    main()
