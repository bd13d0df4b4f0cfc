"""Pictures of the twin's grip before and after trial revision 4 (docs/trials.md, "Why the twin dropped").

Left: the closing plane — both claws at the end of their stroke, the largest loose log the bowl
holds (dashed) and a 0.16 m log, for the old stroke (bowl 0.34 m) and the new one (0.19 m).
Right: side views of one trial, a single 0.16 m log gripped 0.6 m from its middle with the crane
1 cm / 1° off, after closing and after the lift, with each stroke.

    .venv/bin/python bench/twin_grip_pictures.py --out docs/img/grip_before_after.png
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from synth.geometry.grasp import Grasp
from synth.physics.grapple import GrappleConfig
from synth.physics.trial import TrialConfig, render_view, run_trial
from synth.scene.pile import LogSpec, PileSpec, TerrainSpec, quat_from_x_axis

OLD_BOWL_M = 0.342  # trial revisions 2-3: the stroke ended with the tips 0.60 m past each other


def _pile() -> PileSpec:
    n = 32
    flat = tuple(tuple(0.0 for _ in range(n)) for _ in range(n))
    log = LogSpec(centre_m=(0.0, 0.0, 0.41 * 0.16), orientation=quat_from_x_axis((0, 1, 0)), length_m=2.5, diameter_m=0.16)
    return PileSpec(terrain=TerrainSpec(resolution=n, heights_m=flat), logs=(log,))


def side_views(bowl_m: float) -> tuple[list[np.ndarray], str]:
    cfg = TrialConfig.fast()
    cfg = replace(cfg, grapple=replace(cfg.grapple, closed_bowl_diameter_m=bowl_m))
    shots: dict[str, np.ndarray] = {}

    def look(phase, world, grapple):
        if phase in ("closed", "end"):
            o, _ = grapple.head_pose()
            shots[phase] = render_view(world, (0.0, 0.3, float(o[2]) - 0.6), distance_m=3.4, yaw_deg=90.0,
                                       pitch_deg=-8.0, size_px=(480, 360))

    r = run_trial(_pile(), Grasp(0.01, 0.6, math.radians(1.0), 0.6), [0], cfg, on_phase=look)
    return [shots["closed"], shots["end"]], r.outcome.value.upper()


def closing_plane(ax, g: GrappleConfig, title: str) -> None:
    from matplotlib.patches import Circle, Rectangle

    q = g.close_angle_rad()
    for sign in (1.0, -1.0):
        P = g.claw_polyline_m(q) * [sign, 1.0]
        ax.plot(P[:, 0], P[:, 1], "-", color="#d9731a", lw=6 * g.claw_thickness_m / 0.05, solid_capstyle="round")
    hu = g.head_size_m[0] / 2
    ax.add_patch(Rectangle((-hu, g.head_bottom_z_m()), 2 * hu, g.head_size_m[2], color="#d9731a", alpha=0.5))
    d = g.bowl_diameter_m(q)
    ax.add_patch(Circle((0.0, g.head_bottom_z_m() - d / 2), d / 2, fill=False, ls="--", color="k"))
    ax.add_patch(Circle((0.0, g.head_bottom_z_m() - d + 0.08), 0.08, color="#8b5a2b", alpha=0.8))
    ax.set_title(f"{title}\nstroke end {math.degrees(q):.0f}°: loose bowl {d * 100:.0f} cm", fontsize=9)
    ax.set_aspect("equal")
    ax.set_xlim(-0.7, 0.7)
    ax.set_ylim(-1.35, -0.1)
    ax.set_xticks([])
    ax.set_yticks([])


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img" / "grip_before_after.png")
    a = ap.parse_args()
    fig, axes = plt.subplots(2, 3, figsize=(12, 7.2), gridspec_kw={"width_ratios": [0.8, 1, 1]})
    for row, (bowl, name) in enumerate(((OLD_BOWL_M, "trial revision 3"), (GrappleConfig().closed_bowl_diameter_m,
                                                                             "trial revision 4"))):
        closing_plane(axes[row, 0], replace(GrappleConfig(), closed_bowl_diameter_m=bowl), name)
        (closed, end), outcome = side_views(bowl)
        axes[row, 1].imshow(closed)
        axes[row, 1].set_title(f"{name}: claws closed", fontsize=9)
        axes[row, 2].imshow(end)
        axes[row, 2].set_title(f"{name}: after the lift and hold — {outcome}", fontsize=9)
        for ax in axes[row, 1:]:
            ax.axis("off")
    fig.suptitle("One 0.16 m log gripped 0.6 m from its middle, the crane 1 cm / 1° off", fontsize=11)
    fig.tight_layout()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out, dpi=90)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
