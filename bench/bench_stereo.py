"""Benchmark of the ZED 2-like stereo render: time per pair (EGL vs TinyRenderer) and the depth
error of OpenCV SGBM on log pixels for a few rig settings. Prints a Markdown block.

    .venv/bin/python bench/bench_stereo.py --piles 3 --repeats 5

Piles come from :func:`synth.scene.generate.generate_pile` (seeds 0..N-1, 6 logs, settled). The depth
error is |SGBM depth - ground truth| on the left image's log pixels (:func:`synth.render.stereo.sgbm_depth`,
3-way SGBM, block 5, depth search range height - 1.5 m .. height + 0.5 m).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np


from synth.render.stereo import (
    SGBMConfig,
    StereoRenderer,
    StereoRigConfig,
    egl_plugin_path,
    render_stereo,
    sgbm_depth,
)

RIGS = [  # (width, height, hfov_deg, height_m)
    (1280, 720, 50.0, 3.0),
    (1280, 720, 70.0, 3.5),
    (640, 360, 50.0, 3.0),
]


def _backends() -> list[str]:
    out = ["tiny"]
    if egl_plugin_path() is not None:
        out.insert(0, "egl")
    return out


def _piles(n: int):
    from synth.scene.generate import GenerationConfig, generate_pile

    return [generate_pile(seed, GenerationConfig(n_logs=6))[0] for seed in range(n)]


def timing(pile, backend: str, repeats: int) -> dict[str, float]:
    rig = StereoRigConfig(renderer=backend)
    t0 = time.perf_counter()
    render_stereo(pile, rig)  # fresh renderer: client, scene, textures, (EGL context)
    one_shot = time.perf_counter() - t0
    times = []
    with StereoRenderer(backend) as r:
        r.render(pile, rig)
        for _ in range(repeats):
            t = time.perf_counter()
            r.render(pile, rig)
            times.append(time.perf_counter() - t)
    return {"one_shot_s": one_shot, "pair_s": statistics.median(times), "pair_max_s": max(times)}


def accuracy(piles, backend: str) -> list[tuple[tuple, dict[str, float], float]]:
    rows = []
    with StereoRenderer(backend) as r:
        for w, h, fov, height in RIGS:
            rig = StereoRigConfig(width_px=w, height_px=h, hfov_deg=fov, height_m=height, renderer=backend)
            errs, sg = [], []
            for pile in piles:
                pair = r.render(pile, rig)
                t = time.perf_counter()
                depth = sgbm_depth(pair.left, pair.right, pair.calibration,
                                   SGBMConfig(z_min_m=height - 1.5, z_max_m=height + 0.5))
                sg.append(time.perf_counter() - t)
                inst = pair.instance_left
                mask = (inst >= 1) & (inst < 1000)
                ok = mask & np.isfinite(depth)
                errs.append((np.abs(depth[ok] - pair.depth_left[ok]), ok.sum() / max(1, mask.sum())))
            all_err = np.concatenate([e[0] for e in errs])
            stats = {"median_m": float(np.median(all_err)), "p90_m": float(np.percentile(all_err, 90)),
                     "coverage": float(np.mean([e[1] for e in errs]))}
            rows.append(((w, h, fov, height), stats, statistics.median(sg)))
    return rows


def markdown(n_piles: int = 3, repeats: int = 5) -> str:
    piles = _piles(n_piles)
    lines = ["### Stereo pair render (ZED 2-like, 0.12 m baseline, straight down)", ""]
    lines += ["Time per stereo pair at 1280x720 (both cameras; left with depth + segmentation), "
              f"pile with {piles[0].n_logs} logs:", "",
              "| renderer | pair, warm renderer (median) | max | first pair incl. client + scene + textures |",
              "|---|---|---|---|"]
    for b in _backends():
        try:
            t = timing(piles[0], b, repeats)
        except Exception as exc:  # EGL missing at run time
            lines.append(f"| {b} | failed: {exc} | | |")
            continue
        lines.append(f"| {b} | {t['pair_s']:.3f} s | {t['pair_max_s']:.3f} s | {t['one_shot_s']:.2f} s |")
    lines += ["", f"SGBM depth error on log pixels ({n_piles} generated piles, all log pixels pooled):", "",
              "| renderer | image | HFOV | height | median | p90 | coverage | SGBM time |",
              "|---|---|---|---|---|---|---|---|"]
    for b in _backends():
        try:
            rows = accuracy(piles, b)
        except Exception as exc:
            lines.append(f"| {b} | failed: {exc} | | | | | | |")
            continue
        for (w, h, fov, height), s, sg in rows:
            lines.append(f"| {b} | {w}x{h} | {fov:.0f}° | {height:.1f} m | {s['median_m'] * 100:.2f} cm | "
                         f"{s['p90_m'] * 100:.2f} cm | {s['coverage'] * 100:.0f} % | {sg:.2f} s |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--piles", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    print(markdown(args.piles, args.repeats))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
