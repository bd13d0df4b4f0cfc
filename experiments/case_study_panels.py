"""The drawing pieces of the case-study figures (:mod:`experiments.case_studies`): titled render
panels with grasps, U colour maps with log and obstacle outlines, grids, headings and stacks."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from experiments.case_studies import CaseStudyConfig

GREEN, RED, WHITE = (80, 220, 80), (80, 80, 255), (255, 255, 255)


def panel_scale(obs, cfg: CaseStudyConfig) -> int:
    return max(1, round(cfg.panel_px / obs.depth.shape[0]))


def titled(img: np.ndarray, lines: list[str], colour=WHITE) -> np.ndarray:
    import cv2

    w = img.shape[1]
    fs = 0.45 if w >= 200 else 0.3
    lh = int(round(40 * fs))
    strip = np.zeros((lh * len(lines) + 6, w, 3), np.uint8)
    for k, line in enumerate(lines):
        cv2.putText(strip, line, (4, lh * (k + 1)), cv2.FONT_HERSHEY_SIMPLEX, fs, colour, 1, cv2.LINE_AA)
    return np.concatenate([strip, img], axis=0)


def render_panel(obs, grasps, cfg: CaseStudyConfig) -> np.ndarray:
    """The render (left half of :func:`synth.render.preview.draw_grasps`) with the grasps drawn."""
    from synth.render.preview import draw_grasps

    s = panel_scale(obs, cfg)
    return draw_grasps(obs, grasps, scale=s)[:, : obs.depth.shape[0] * s]


def u_panel(u: np.ndarray, obs, cfg: CaseStudyConfig, u_max: float = 1.0) -> np.ndarray:
    """U as a colour map, 0 .. ``u_max`` (share it between panels that are compared)."""
    import cv2

    s = panel_scale(obs, cfg)
    n = u.shape[0] * s
    img = cv2.applyColorMap(cv2.resize((np.clip(u / max(u_max, 1e-6), 0, 1) * 255).astype(np.uint8), (n, n),
                                       interpolation=cv2.INTER_NEAREST), cv2.COLORMAP_INFERNO)
    inst = cv2.resize(obs.instance.astype(np.int32), (n, n), interpolation=cv2.INTER_NEAREST)
    for code, colour in (((inst > 0) & (inst < 1000), (200, 200, 200)), (inst >= 1000, (80, 80, 255))):
        contours, _ = cv2.findContours(code.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(img, contours, -1, colour, 1)
    return img


def outcome_colour(outcome: str):
    return GREEN if outcome == "success" else RED


def fmt_targets(t) -> str:
    return "{" + ",".join(str(i) for i in t) + "}"


def describe_trial(rec: dict) -> str:
    return f"{rec['outcome']} {len(rec['grasped'])}/{len(rec['targets'])}"


def grid_image(panels: list[np.ndarray], columns: int) -> np.ndarray:
    """Panels (any sizes) on a white grid, ``columns`` per row, 4 px apart."""
    if not panels:
        raise ValueError("nothing to draw: no panels")
    h = max(p.shape[0] for p in panels)
    w = max(p.shape[1] for p in panels)
    rows = []
    for k in range(0, len(panels), columns):
        row = []
        for p in panels[k : k + columns] + [np.full((h, w, 3), 255, np.uint8)] * (columns - len(panels[k : k + columns])):
            cell = np.full((h, w, 3), 255, np.uint8)
            cell[: p.shape[0], : p.shape[1]] = p
            row.append(cell)
            row.append(np.full((h, 4, 3), 255, np.uint8))
        rows.append(np.concatenate(row[:-1], axis=1))
        rows.append(np.full((4, rows[-1].shape[1], 3), 255, np.uint8))
    return np.concatenate(rows[:-1], axis=0)


def with_heading(img: np.ndarray, text: str) -> np.ndarray:
    import cv2

    strip = np.full((30, img.shape[1], 3), 40, np.uint8)
    cv2.putText(strip, text, (6, 21), cv2.FONT_HERSHEY_SIMPLEX, 0.6, WHITE, 1, cv2.LINE_AA)
    return np.concatenate([strip, img], axis=0)


def stack_blocks(blocks: list[np.ndarray]) -> np.ndarray:
    w = max(b.shape[1] for b in blocks)
    out = []
    for b in blocks:
        pad = np.full((b.shape[0], w - b.shape[1], 3), 255, np.uint8)
        out += [np.concatenate([b, pad], axis=1), np.full((8, w, 3), 255, np.uint8)]
    return np.concatenate(out[:-1], axis=0)
