"""Pictures a person can look at: a render with log outlines and indices, depth beside it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from synth.common.files import atomic_write_bytes
from synth.render.ortho import OrthoObservation
from synth.physics.world import OBSTACLE_BASE

_PALETTE = [(255, 99, 71), (50, 205, 50), (30, 144, 255), (255, 215, 0), (238, 130, 238), (0, 206, 209),
            (255, 140, 0), (173, 255, 47), (219, 112, 147), (135, 206, 250), (244, 164, 96), (152, 251, 152)]


def log_colour_bgr(i: int) -> tuple[int, int, int]:
    r, g, b = _PALETTE[i % len(_PALETTE)]
    return (b, g, r)


def preview_image(obs: OrthoObservation, scale: int = 4, render: int = 0) -> np.ndarray:
    """BGR uint8 picture: intensity render with coloured log outlines + indices, and the height map."""
    import cv2

    n = obs.depth.shape[0]
    size = n * scale
    grey = (np.clip(obs.intensity[render], 0, 1) * 255).astype(np.uint8)
    img = cv2.cvtColor(cv2.resize(grey, (size, size), interpolation=cv2.INTER_NEAREST), cv2.COLOR_GRAY2BGR)
    inst = cv2.resize(obs.instance.astype(np.int32), (size, size), interpolation=cv2.INTER_NEAREST)
    for i in range(obs.n_logs):
        mask = (inst == i + 1).astype(np.uint8)
        if not mask.any():
            continue
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(img, contours, -1, log_colour_bgr(i), 2)
        m = cv2.moments(mask)
        cx, cy = int(m["m10"] / m["m00"]), int(m["m01"] / m["m00"])
        cv2.putText(img, str(i), (cx - 6, cy + 6), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 0), 3)
        cv2.putText(img, str(i), (cx - 6, cy + 6), cv2.FONT_HERSHEY_SIMPLEX, 0.7, log_colour_bgr(i), 2)
    obstacles = (inst >= OBSTACLE_BASE).astype(np.uint8)
    contours, _ = cv2.findContours(obstacles, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(img, contours, -1, (0, 0, 255), 1)
    h = obs.height()
    hn = ((h - h.min()) / max(float(h.max() - h.min()), 1e-6) * 255).astype(np.uint8)
    depth_img = cv2.applyColorMap(cv2.resize(hn, (size, size), interpolation=cv2.INTER_NEAREST), cv2.COLORMAP_VIRIDIS)
    cv2.putText(img, "intensity + logs", (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1)
    cv2.putText(depth_img, f"height {h.min():.2f}..{h.max():.2f} m", (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55,
                (255, 255, 255), 1)
    return np.concatenate([img, np.full((size, 4, 3), 255, np.uint8), depth_img], axis=1)


def write_png(path: str | Path, bgr: np.ndarray) -> Path:
    import cv2

    ok, data = cv2.imencode(".png", bgr)
    if not ok:
        raise OSError(f"could not encode {path}")
    atomic_write_bytes(Path(path), data.tobytes())
    return Path(path)


def draw_grasps(obs: OrthoObservation, grasps, scale: int = 4, render: int = 0, labels=None) -> np.ndarray:
    """BGR picture of the render with the target logs brightened and grasp rectangles drawn.

    ``grasps``: sequence of ``(Grasp, targets)``; the first is drawn thick (the chosen one).
    ``labels``: optional text per grasp (e.g. its quality)."""
    import cv2

    from synth.geometry.grasp import RECT_WIDTH_M

    img = preview_image(obs, scale=scale, render=render)
    n = obs.depth.shape[0]
    size = n * scale
    left = img[:, :size].copy()
    inst = cv2.resize(obs.instance.astype(np.int32), (size, size), interpolation=cv2.INTER_NEAREST)
    grid = obs.grid
    for k, (grasp, targets) in reversed(list(enumerate(grasps))):
        if k == 0 and targets:
            m = np.isin(inst, [t + 1 for t in targets])
            left[m] = (0.5 * left[m] + 0.5 * 255).astype(np.uint8)
        corners = grasp.rectangle(RECT_WIDTH_M)
        r, c = grid.pile_to_pixel(corners[:, 0], corners[:, 1])
        pts = np.stack([(c + 0.5) * scale, (r + 0.5) * scale], axis=1).astype(np.int32)
        colour = (0, 255, 255) if k == 0 else (200, 200, 0)
        cv2.polylines(left, [pts], True, (0, 0, 0), 5 if k == 0 else 3)
        cv2.polylines(left, [pts], True, colour, 3 if k == 0 else 1)
        # claw tips: the two short sides
        for a, b in ((0, 3), (1, 2)):
            cv2.line(left, tuple(pts[a]), tuple(pts[b]), (0, 0, 255) if k == 0 else colour, 4 if k == 0 else 2)
        if labels is not None:
            cx, cy = pts.mean(axis=0).astype(int)
            cv2.putText(left, str(labels[k]), (cx + 8, cy - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3)
            cv2.putText(left, str(labels[k]), (cx + 8, cy - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.5, colour, 1)
    img[:, :size] = left
    return img
