"""Orthographic top-down renders in the paper's training format, and their file ``ortho.npz``.

A render is seen by a virtual orthographic camera ``camera_height_m`` above the pile-frame datum,
looking straight down, over the whole terrain patch (pixel grid: :class:`synth.geometry.frames.OrthoGrid`).
It yields

* ``intensity``: colour channels summed and normalised to [0, 1], one image per render
  (several renders per scene, each with its own random colours and light — the paper used three);
* ``depth``: metric distance [m] from the camera plane down to the first surface (the same for
  every render); ``height = camera_height_m - depth``;
* ``instance``: which body each pixel sees: 0 ground, ``i + 1`` log ``i``, ``1000 + j`` obstacle ``j``
  (stumps first, then rocks). Any target mask M_T is built from it with :func:`target_mask`.

TinyRenderer takes a custom projection matrix but derives near/far planes from it as if it were
perspective; with an orthographic matrix whose z row is ``clip_z = k * z_eye + b`` (w = 1) and
``k < 0 < b`` every fragment passes, and pybullet returns ``buf = (0.5 - k/2) + (b/2) / d`` for a
surface at distance ``d`` — inverted exactly below. TinyRenderer samples integer pixel positions, so
the window is shifted by half a pixel to sample pixel centres.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np

from synth.common.files import atomic_write_bytes
from synth.common.formats import VersionedJson
from synth.errors import PileFormatError, RenderError
from synth.geometry.frames import OrthoGrid
from synth.physics.world import GROUND_CODE, OBSTACLE_BASE, World

ORTHO_FORMAT_VERSION = "1.0"
ORTHO_FORMAT_NAME = "loggrasp.ortho"
ORTHO = VersionedJson(ORTHO_FORMAT_NAME, ORTHO_FORMAT_VERSION, "orthographic render", PileFormatError,
                      fix="re-render the pile")

# z row of the orthographic projection (see module docstring)
_K = -0.1
_B = 10.0


@dataclass(frozen=True)
class OrthoRenderConfig:
    size_px: int = 128  # image side [px]
    camera_height_m: float = 5.0  # camera plane above the pile-frame datum [m]
    n_renders: int = 3  # renders per scene with randomised colours/light [-]
    colour_min: float = 0.2  # lowest random colour intensity [-]
    colour_max: float = 0.8  # highest random colour intensity [-]
    keep_first_colours: bool = True  # render 0 uses the pile's own colours and light

    def __post_init__(self) -> None:
        OrthoGrid(self.size_px)  # validates the size
        if not 1.0 <= self.camera_height_m <= 100.0:
            raise ValueError(f"camera_height_m must be in [1, 100] m, got {self.camera_height_m}")
        if not 1 <= self.n_renders <= 32:
            raise ValueError(f"n_renders must be in [1, 32], got {self.n_renders}")
        if not 0.0 <= self.colour_min <= self.colour_max <= 1.0:
            raise ValueError("need 0 <= colour_min <= colour_max <= 1")


@dataclass
class OrthoObservation:
    """What the planner sees of a pile: intensity renders, depth and the instance map."""

    intensity: np.ndarray  # (R, H, W) float32 in [0, 1]
    depth: np.ndarray  # (H, W) float32 [m] from the camera plane
    instance: np.ndarray  # (H, W) int16 codes
    extent_m: float = 5.0
    camera_height_m: float = 5.0
    n_logs: int = 0
    n_obstacles: int = 0
    meta: dict = field(default_factory=dict)

    @property
    def grid(self) -> OrthoGrid:
        return OrthoGrid(self.depth.shape[0], self.extent_m)

    def height(self) -> np.ndarray:
        """Height map [m] above the pile-frame datum."""
        return (self.camera_height_m - self.depth).astype(np.float32)

    def log_mask(self, i: int) -> np.ndarray:
        return self.instance == i + 1

    def target_mask(self, targets: Iterable[int]) -> np.ndarray:
        return target_mask(self.instance, targets)

    # -- file ----------------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        path = Path(path)
        if path.is_dir():
            path = path / "ortho.npz"
        meta = {
            "format": ORTHO_FORMAT_NAME, "format_version": ORTHO_FORMAT_VERSION,
            "extent_m": self.extent_m, "camera_height_m": self.camera_height_m,
            "n_logs": self.n_logs, "n_obstacles": self.n_obstacles,
            "instance_codes": {"ground": GROUND_CODE, "log_i": "i + 1", "obstacle_j": f"{OBSTACLE_BASE} + j"},
            "pixel_to_pile": "x = -extent/2 + (col + 0.5) * extent/size; y = extent/2 - (row + 0.5) * extent/size",
            **self.meta,
        }
        import io

        buf = io.BytesIO()
        np.savez_compressed(
            buf, intensity=self.intensity.astype(np.float32), depth=self.depth.astype(np.float32),
            instance=self.instance.astype(np.int16), meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8),
        )
        atomic_write_bytes(path, buf.getvalue())
        return path

    @staticmethod
    def load(path: str | Path) -> "OrthoObservation":
        path = Path(path)
        if path.is_dir():
            path = path / "ortho.npz"
        try:
            with np.load(path) as z:
                meta = json.loads(bytes(z["meta"]).decode())
                arrays = {k: z[k] for k in ("intensity", "depth", "instance")}
        except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise PileFormatError(f"cannot read orthographic render {path} ({exc or type(exc).__name__}): "
                                  "it is truncated or not an ortho.npz; delete it and render the pile again") from exc
        ORTHO.check(meta, path)
        known = {"format", "format_version", "extent_m", "camera_height_m", "n_logs", "n_obstacles",
                 "instance_codes", "pixel_to_pile"}
        return OrthoObservation(
            intensity=arrays["intensity"], depth=arrays["depth"], instance=arrays["instance"],
            extent_m=float(meta["extent_m"]), camera_height_m=float(meta["camera_height_m"]),
            n_logs=int(meta["n_logs"]), n_obstacles=int(meta["n_obstacles"]),
            meta={k: v for k, v in meta.items() if k not in known},
        )


def target_mask(instance: np.ndarray, targets: Iterable[int]) -> np.ndarray:
    """M_T: the union of the masks of logs ``targets`` (log indices, 0-based)."""
    codes = np.asarray([int(t) + 1 for t in targets], dtype=np.int16)
    return np.isin(instance, codes)


def _projection(grid: OrthoGrid) -> list[float]:
    e, n = grid.extent_m, grid.size_px
    # half-pixel shift so that integer sample positions are pixel centres (x and y)
    M = np.array([
        [2 / e, 0, 0, -1.0 / n],
        [0, 2 / e, 0, -1.0 / n],
        [0, 0, _K, _B],
        [0, 0, 0, 1.0],
    ])
    return M.T.ravel().tolist()  # column-major


def _depth_from_buffer(buf: np.ndarray) -> np.ndarray:
    return (_B / 2) / (buf - (0.5 - _K / 2))


def _random_colour(rng: np.random.Generator, lo: float, hi: float) -> list[float]:
    v = rng.uniform(lo, hi)
    tint = rng.normal(0.0, 0.06, size=3)
    rgb = np.clip(v + tint - tint.mean(), 0.0, 1.0)
    return [float(c) for c in rgb] + [1.0]


def render_ortho(world: World, config: OrthoRenderConfig | None = None, seed: int = 0) -> OrthoObservation:
    """Render ``world`` top-down: ``config.n_renders`` intensity images, depth and instances.

    Colours and light of renders ``1..n-1`` (and render 0 unless ``keep_first_colours``) are drawn
    from ``seed``; the world's visual colours are restored afterwards.
    """
    config = config or OrthoRenderConfig()
    c, p = world.client, world.p
    pile = world.pile
    grid = OrthoGrid(config.size_px, pile.terrain.extent_m)
    h = config.camera_height_m
    view = c.computeViewMatrix([0, 0, h], [0, 0, 0], [0, 1, 0])
    proj = _projection(grid)
    n = grid.size_px
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x0A7F0]))

    bodies = [world.terrain_id, *world.log_ids, *world.obstacle_ids]
    own = [pile.terrain.colour, *(log.colour for log in pile.logs),
           *(s.colour for s in pile.stumps), *(r.colour for r in pile.rocks)]
    light0 = pile.lighting

    intensities = []
    depth = instance = None
    try:
        for r in range(config.n_renders):
            if r == 0 and config.keep_first_colours:
                colours = [[*col, 1.0] for col in own]
                ldir, amb, dif, spec = list(light0.direction), light0.ambient, light0.diffuse, light0.specular
            else:
                colours = [_random_colour(rng, config.colour_min, config.colour_max) for _ in bodies]
                elev = rng.uniform(np.radians(35), np.radians(90))
                azim = rng.uniform(0, 2 * np.pi)
                ldir = [np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)]
                amb, dif, spec = rng.uniform(0.45, 0.75), rng.uniform(0.2, 0.45), rng.uniform(0.0, 0.1)
            for b, col in zip(bodies, colours):
                c.changeVisualShape(b, -1, rgbaColor=col)
            flags = 0 if r == 0 else p.ER_NO_SEGMENTATION_MASK
            _, _, rgb, dep, seg = c.getCameraImage(
                n, n, view, proj, renderer=p.ER_TINY_RENDERER, lightDirection=ldir,
                lightAmbientCoeff=amb, lightDiffuseCoeff=dif, lightSpecularCoeff=spec,
                shadow=0, flags=flags,
            )
            rgb = np.reshape(np.asarray(rgb, dtype=np.uint8), (n, n, 4))[:, :, :3]
            intensities.append(rgb.astype(np.float32).sum(axis=2) / (3 * 255.0))
            if r == 0:
                buf = np.reshape(np.asarray(dep, dtype=np.float64), (n, n))
                depth = _depth_from_buffer(buf).astype(np.float32)
                seg = np.reshape(np.asarray(seg, dtype=np.int64), (n, n))
                lut = np.full(max(bodies) + 2, -1, dtype=np.int16)
                for b, code in world.instance_of_body.items():
                    lut[b] = code
                instance = np.where(seg >= 0, lut[np.clip(seg, 0, None)], -1).astype(np.int16)
    finally:
        for b, col in zip(bodies, own):
            c.changeVisualShape(b, -1, rgbaColor=[*col, 1.0])
    if depth is None or not np.all(np.isfinite(depth)) or (instance < 0).any():
        raise RenderError(
            "the orthographic render has holes (pixels that see nothing); "
            "the terrain must cover the whole imaged square"
        )
    return OrthoObservation(
        intensity=np.stack(intensities).astype(np.float32), depth=depth, instance=instance,
        extent_m=grid.extent_m, camera_height_m=h, n_logs=pile.n_logs, n_obstacles=pile.n_obstacles,
    )
