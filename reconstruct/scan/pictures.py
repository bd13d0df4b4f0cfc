"""Pictures of a scan a person reads: its top view, and the top view beside the orthographic re-render."""

from __future__ import annotations

from typing import Any

import numpy as np


def scan_top_view(points: np.ndarray, colours: np.ndarray, extent_m: float, size_px: int) -> np.ndarray:
    """BGR uint8 top view of a coloured cloud (pile frame) on the ortho grid: the highest point
    per pixel; grey where nothing was seen."""
    from synth.geometry.frames import OrthoGrid

    g = OrthoGrid(size_px, extent_m)
    r, c = g.pile_to_pixel(points[:, 0], points[:, 1])
    r, c = np.rint(r).astype(np.int64), np.rint(c).astype(np.int64)
    ok = (r >= 0) & (r < size_px) & (c >= 0) & (c < size_px)
    r, c, z, col = r[ok], c[ok], points[ok, 2], colours[ok]
    order = np.argsort(z)  # later (higher) points overwrite lower ones
    img = np.full((size_px, size_px, 3), 128, np.uint8)
    img[r[order], c[order]] = (np.clip(col[order][:, ::-1], 0, 1) * 255).astype(np.uint8)
    return img


def comparison_image(points: np.ndarray, colours: np.ndarray, obs: Any, scale: int = 4) -> np.ndarray:
    """The scan from above (left) beside the re-render with log outlines (right), BGR uint8."""
    import cv2

    from synth.render.preview import log_colour_bgr

    n = obs.depth.shape[0]
    size = n * scale
    left = scan_top_view(points, colours, obs.extent_m, size)
    grey = (np.clip(obs.intensity[0], 0, 1) * 255).astype(np.uint8)
    right = cv2.cvtColor(cv2.resize(grey, (size, size), interpolation=cv2.INTER_NEAREST), cv2.COLOR_GRAY2BGR)
    inst = cv2.resize(obs.instance.astype(np.int32), (size, size), interpolation=cv2.INTER_NEAREST)
    for i in range(obs.n_logs):
        mask = (inst == i + 1).astype(np.uint8)
        if mask.any():
            contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            cv2.drawContours(left, contours, -1, log_colour_bgr(i), 1)  # thin: the scan stays visible
            cv2.drawContours(right, contours, -1, log_colour_bgr(i), 2)
    cv2.putText(left, "scan (top view) + fitted logs", (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1)
    cv2.putText(right, "re-render (training format)", (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1)
    return np.concatenate([left, np.full((size, 4, 3), 255, np.uint8), right], axis=1)
