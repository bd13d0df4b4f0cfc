"""Draw docs/img/architecture.png: the packages, their stages and the data flow of `loggrasp demo`.

    .venv/bin/python scripts/architecture_figure.py
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "architecture.png"

# package lanes: (name, y, colour, stages as (label, modules))
LANES = [
    ("field/", 3.0, "#f4d6c6", [("laptop: trial", "trial.py, geo.py, cli.py"),
                                 ("crane link", "link/ (CAN, Zenoh, twin)"),
                                 ("controller twin", "controller/, executor.py"),
                                 ("record + replay", "trial.py, cli.py")]),
    ("reconstruct/", 2.0, "#d6e4f0", [("scan/", "stereo.py, calibration.py, sfm.py"),
                                       ("survey/ + registration", "gnss.py, registration.py"),
                                       ("fitting/", "fuse.py, fit.py"),
                                       ("pile", "pipeline.py")]),
    ("planner/", 1.0, "#dcefd6", [("inputs", "data.py, augment.py"),
                                   ("U-Net", "model.py, train.py"),
                                   ("plan: Q = f(U, tau, B)", "inference.py, subsets.py"),
                                   ("verify in the twin", "verify.py, evaluate.py")]),
    ("synth/", 0.0, "#ece3f4", [("scene/", "pile.py, generate.py, terrain.py"),
                                 ("physics/", "world.py, grapple.py, trial.py"),
                                 ("render/", "ortho.py, stereo.py, textures.py"),
                                 ("data/", "candidates, maps, dataset, datastore, jobs")]),
]


def box(ax, x, y, w, h, text, sub, colour):
    ax.add_patch(FancyBboxPatch((x, y), w, h, boxstyle="round,pad=0.02,rounding_size=0.06",
                                fc=colour, ec="#555555", lw=1))
    ax.text(x + w / 2, y + h * 0.63, text, ha="center", va="center", fontsize=9, weight="bold")
    ax.text(x + w / 2, y + h * 0.27, sub, ha="center", va="center", fontsize=6.5, color="#333333")


def arrow(ax, a, b, text="", colour="#b03a2e", rad=0.0):
    ax.add_patch(FancyArrowPatch(a, b, arrowstyle="-|>", mutation_scale=12, lw=1.6, color=colour,
                                 connectionstyle=f"arc3,rad={rad}"))
    if text:
        ax.text((a[0] + b[0]) / 2, (a[1] + b[1]) / 2 + 0.08, text, fontsize=6.5, color=colour, ha="center")


def main() -> None:
    fig, ax = plt.subplots(figsize=(12, 6.4))
    w, h, x0, dx = 2.1, 0.62, 1.3, 2.45
    centres = {}
    for name, y, colour, stages in LANES:
        ax.add_patch(FancyBboxPatch((0.05, y - 0.12), 11.3, 0.86, boxstyle="round,pad=0.0,rounding_size=0.05",
                                    fc=colour, ec="none", alpha=0.35))
        ax.text(0.15, y + 0.31, name, fontsize=11, weight="bold", va="center")
        for i, (label, mods) in enumerate(stages):
            x = x0 + i * dx
            box(ax, x, y, w, h, label, mods, colour)
            centres[(name, i)] = (x + w / 2, y + h / 2)
    ax.add_patch(FancyBboxPatch((0.05, -0.75), 11.3, 0.5, boxstyle="round,pad=0.0,rounding_size=0.05",
                                fc="#eeeeee", ec="#999999"))
    ax.text(5.7, -0.5, "synth/common/: atomic writes, hashing, one versioned-JSON reader, one job runner, ranges, "
            "error root (LoggraspError), the CLI helpers\nsynth/geometry/: frames, the grasp, geodesy (SWEREF 99 TM, RH 2000), "
            "stereo calibration formats — no simulator behind them; used by every package", ha="center",
            va="center", fontsize=8)
    # the demo's data flow: numbered badges on the stages, in order, and the sequence written out
    flow = [("reconstruct/", 0), ("reconstruct/", 1), ("reconstruct/", 2), ("reconstruct/", 3), ("synth/", 2),
            ("planner/", 0), ("planner/", 1), ("planner/", 2), ("planner/", 3), ("synth/", 1), ("field/", 0),
            ("field/", 1), ("field/", 2), ("synth/", 1), ("field/", 3)]
    seen: dict = {}
    for n, key in enumerate(flow, 1):
        x, y = centres[key]
        k = seen.get(key, 0)
        seen[key] = k + 1
        bx, by = x - w / 2 + 0.12 + 0.3 * k, y + h / 2 - 0.02
        ax.add_patch(plt.Circle((bx, by), 0.12, color="#b03a2e", zorder=5))
        ax.text(bx, by, str(n), color="white", fontsize=7, ha="center", va="center", weight="bold", zorder=6)
    for lane in LANES:
        for i in range(len(lane[3]) - 1):
            (xa, ya), (xb, yb) = centres[(lane[0], i)], centres[(lane[0], i + 1)]
            if lane[0] != "synth/":
                arrow(ax, (xa + w / 2, ya), (xb - w / 2, yb))
    steps = ("`loggrasp demo`: 1 stereo pairs  2 RTK log ends  3 survey and scan fused by their accuracies  "
             "4 the reconstructed pile  5 re-rendered top-down\n6 intensity, depth, target masks  7 U-Net maps "
             "(cos 2phi, sin 2phi, W, U, B)  8 every subset scored, Q = f(U, tau, B)  9-10 the K best tried in the "
             "twin on the reconstruction\n11 the best that succeeded, in SWEREF 99 TM  12 authenticated CAN / Zenoh "
             "frames  13-14 the controller twin runs it on the true pile  15 trial record; replay repeats it")
    ax.text(0.1, 4.05, steps, fontsize=7.5, color="#b03a2e", va="top")
    ax.text(11.3, -0.95, "packages depend only downwards; planner/ and reconstruct/ never on each other "
            "(tests/test_architecture.py)", fontsize=7, ha="right", color="#555555")
    ax.set_xlim(0, 11.4)
    ax.set_ylim(-1.05, 4.1)
    ax.axis("off")
    fig.tight_layout()
    OUT.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(OUT, dpi=110)
    print(OUT)


if __name__ == "__main__":
    main()
