"""Procedural textures for the stereo renders: bark, soil, rock — deterministic in a seed.

Stereo matching needs high-frequency content that does not look periodic within the disparity
search range, so every texture mixes several scales of spectrally shaped noise (generated through
the FFT, hence seamlessly tileable) with drawn detail (fissures, gravel, needles).

Texture coordinates of the bodies built by :class:`synth.world.World`:

* logs: metric UVs from :func:`synth.meshes.frustum` with ``uv_m = 0.5`` — ``u`` along the axis,
  ``v`` around the circumference, one texture repeat per 0.5 m. Bark streaks therefore run along
  the texture's ``u`` (column) direction.
* stumps: the same, with ``uv_m = 0.3``, axis along local z.
* rocks: planar projection of local x, y with ``uv_m = 0.5``.
* terrain: the visual grid mesh from :func:`synth.meshes.grid_mesh` has metric UVs with
  ``uv_m = 0.5`` (pile x, y divided by 0.5 m; checked in ``tests/synth/test_stereo.py``), so the
  soil texture is a seamless 0.5 m tile. The tile repeats on the ground, which stereo tolerates:
  at 3 m a repeat spans far more pixels than the disparity search range.

Files are PNGs (``cv2.imwrite``) in a per-user temporary cache, named by the SHA-1 of the recipe
(kind, seed, size, :data:`TEXTURE_VERSION`) and written atomically; generation is deterministic, so
the recipe determines the content. Arrays are RGB ``uint8`` ``(rows, cols, 3)``.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from synth.world import World

#: Bump when any generator changes its output (part of every cache key).
TEXTURE_VERSION = "2"

_CACHE = Path(tempfile.gettempdir()) / f"loggrasp-textures-{os.getuid() if hasattr(os, 'getuid') else 0}"

KINDS = ("bark", "ground", "rock", "stump")


@dataclass(frozen=True)
class TextureConfig:
    """How the bodies of a world are textured."""

    seed: int = 0  # base seed; textures are deterministic in it [-]
    variants: int = 4  # distinct bark / rock textures in use (logs cycle through them) [-]
    bark_px: int = 512  # side of a bark texture = one 0.5 m repeat (~1 mm / px) [px]
    rock_px: int = 512  # side of a rock / stump texture [px]
    ground_px: int = 512  # side of the soil tile [px]
    ground_uv_m: float = 0.5  # ground repeat length: the terrain mesh's UV scale (synth.meshes.grid_mesh) [m]
    specular: float = 0.0  # specular colour of textured bodies (view-dependent highlights hurt stereo) [-]

    def __post_init__(self) -> None:
        if not 1 <= self.variants <= 64:
            raise ValueError(f"texture variants must be in [1, 64], got {self.variants}")
        for name in ("bark_px", "rock_px", "ground_px"):
            v = getattr(self, name)
            if not 32 <= v <= 8192:
                raise ValueError(f"{name} must be in [32, 8192] px, got {v}")
        if not 0.05 <= self.ground_uv_m <= 100.0:
            raise ValueError(f"ground_uv_m must be in [0.05, 100] m, got {self.ground_uv_m}")
        if not 0.0 <= self.specular <= 1.0:
            raise ValueError(f"specular must be in [0, 1], got {self.specular}")


# -- noise primitives ------------------------------------------------------------------------
def _rng(kind: str, seed: int) -> np.random.Generator:
    tag = int.from_bytes(hashlib.sha1(kind.encode()).digest()[:4], "little")
    return np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, tag]))


def spectral_noise(rng: np.random.Generator, rows: int, cols: int, beta: float,
                   stretch_u: float = 1.0, k_min: float = 1.0, k_max: float | None = None) -> np.ndarray:
    """Zero-mean, unit-std, tileable noise with power spectrum ~ 1/k^beta (float32).

    ``stretch_u`` > 1 elongates features along the column (u) direction by that factor.
    ``k_min``/``k_max`` band-limit the spectrum in cycles per texture.
    """
    white = rng.standard_normal((rows, cols)).astype(np.float32)
    spec = np.fft.rfft2(white)
    ky = np.fft.fftfreq(rows)[:, None] * rows
    kx = np.fft.rfftfreq(cols)[None, :] * cols
    k = np.sqrt((kx * stretch_u) ** 2 + ky**2)
    with np.errstate(divide="ignore"):
        amp = np.where(k >= k_min, k ** (-beta / 2.0), 0.0)
    if k_max is not None:
        amp = np.where(k <= k_max, amp, 0.0)
    out = np.fft.irfft2(spec * amp, s=(rows, cols)).astype(np.float32)
    out -= out.mean()
    std = float(out.std())
    return out / std if std > 0 else out


def _to_uint8(rgb: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8)


def _colourise(lum: np.ndarray, base_rgb: tuple[float, float, float], tint: np.ndarray | None = None) -> np.ndarray:
    """Luminance field (around 1) times a base colour, optionally tinted per pixel (rows, cols, 3)."""
    rgb = lum[..., None] * np.asarray(base_rgb, dtype=np.float32)[None, None, :]
    if tint is not None:
        rgb = rgb * tint
    return rgb


def _stamp_wrapped(draw, size: tuple[int, int], x: float, y: float, reach: float) -> None:
    """Call ``draw(x, y)`` at (x, y) and at its wrapped copies near the borders (tileable stamps)."""
    rows, cols = size
    xs = [x] + ([x + cols] if x < reach else []) + ([x - cols] if x > cols - reach else [])
    ys = [y] + ([y + rows] if y < reach else []) + ([y - rows] if y > rows - reach else [])
    for xx in xs:
        for yy in ys:
            draw(xx, yy)


# -- generators ------------------------------------------------------------------------------
def bark_texture(seed: int, size_px: int = 512) -> np.ndarray:
    """Bark: fissures and plates streaked along u (columns), fine grain, slow colour drift.

    One texture side is one 0.5 m repeat on a log (see the module docstring).
    """
    rng = _rng("bark", seed)
    n = size_px
    ridges = spectral_noise(rng, n, n, beta=1.6, stretch_u=5.0, k_min=4.0)
    plates = spectral_noise(rng, n, n, beta=2.4, stretch_u=2.0, k_min=2.0)
    grain = spectral_noise(rng, n, n, beta=0.6, k_min=8.0)
    drift = spectral_noise(rng, n, n, beta=3.0, k_min=1.0)
    fissure = np.clip((ridges - 0.6) / 0.9, 0.0, 1.0)  # 1 inside a fissure
    lum = 1.0 + 0.18 * plates + 0.10 * grain - 0.55 * fissure
    lum = np.clip(lum, 0.15, 1.8)
    base = (0.46, 0.37, 0.27)
    d = drift[..., None]
    tint = 1.0 + 0.08 * np.concatenate([d, 0.5 * d, -0.4 * d], axis=-1)
    return _to_uint8(_colourise(lum, base, tint))


def rock_texture(seed: int, size_px: int = 512) -> np.ndarray:
    """Rock: granite-like speckle, mottling and a few lichen patches."""
    rng = _rng("rock", seed)
    n = size_px
    mottle = spectral_noise(rng, n, n, beta=2.2, k_min=1.0)
    speckle = spectral_noise(rng, n, n, beta=0.3, k_min=16.0)
    dots = rng.random((n, n)).astype(np.float32)
    lum = 1.0 + 0.15 * mottle + 0.12 * speckle - 0.35 * (dots > 0.985) + 0.3 * (dots < 0.01)
    rgb = _colourise(np.clip(lum, 0.2, 1.8), (0.52, 0.52, 0.50))
    lichen = np.clip((spectral_noise(rng, n, n, beta=2.6, k_min=2.0) - 1.2) * 2.0, 0.0, 1.0)[..., None]
    rgb = rgb * (1 - lichen) + lichen * np.array([0.62, 0.66, 0.48], dtype=np.float32) * (1 + 0.1 * speckle[..., None])
    return _to_uint8(rgb)


def stump_texture(seed: int, size_px: int = 512) -> np.ndarray:
    """Stump: darker, weathered bark (streaks along u, as on logs)."""
    rgb = bark_texture(seed ^ 0x5A5A, size_px).astype(np.float32) / 255.0
    rng = _rng("stump", seed)
    weather = spectral_noise(rng, size_px, size_px, beta=2.0, k_min=2.0)[..., None]
    rgb = rgb * (0.82 + 0.06 * weather) * np.array([0.95, 0.95, 1.0], dtype=np.float32)
    return _to_uint8(rgb)


def ground_texture(seed: int, size_px: int = 512, m_per_px: float = 0.5 / 512) -> np.ndarray:
    """Forest-floor soil: multi-scale noise, moss/litter patches, gravel and conifer needles.

    Seamlessly tileable. ``m_per_px`` sets the physical size of gravel and needles.
    """
    import cv2

    rng = _rng("ground", seed)
    n = size_px
    coarse = spectral_noise(rng, n, n, beta=2.6, k_min=1.0)
    mid = spectral_noise(rng, n, n, beta=1.8, k_min=4.0)
    fine = spectral_noise(rng, n, n, beta=0.5, k_min=max(8.0, n / 64))
    # weak tile-scale structure: the tile repeats every ground_uv_m on the terrain
    lum = 1.0 + 0.05 * coarse + 0.12 * mid + 0.10 * fine
    soil = _colourise(np.clip(lum, 0.3, 1.8), (0.40, 0.33, 0.24))
    litter = np.clip(spectral_noise(rng, n, n, beta=2.0, k_min=3.0) * 0.8 - 0.2, 0.0, 1.0)[..., None]
    litter_rgb = np.array([0.50, 0.40, 0.25], dtype=np.float32) * (1.0 + 0.15 * mid[..., None])
    moss = np.clip(spectral_noise(rng, n, n, beta=2.0, k_min=3.0) - 1.8, 0.0, 1.0)[..., None]
    moss_rgb = np.array([0.30, 0.38, 0.18], dtype=np.float32) * (1.0 + 0.2 * fine[..., None])
    rgb = soil * (1 - litter) + litter_rgb * litter
    rgb = rgb * (1 - moss) + moss_rgb * moss
    img = np.ascontiguousarray(_to_uint8(rgb)[..., ::-1])  # BGR for cv2 drawing

    px = 1.0 / m_per_px  # pixels per metre
    area_m2 = (n * m_per_px) ** 2
    # gravel: small irregular grey-brown stones with a lit and a shaded side
    for _ in range(int(rng.poisson(120 * area_m2))):
        r = max(1.0, rng.uniform(0.004, 0.02) * px)
        g = rng.uniform(0.35, 0.75)
        col = tuple(int(255 * min(1.0, g * f)) for f in (1.0, 1.02, 1.05))
        dark = tuple(int(c * 0.6) for c in col)
        ax = (max(1, int(r)), max(1, int(r * rng.uniform(0.55, 1.0))))
        ang = float(rng.uniform(0, 180))

        def stone(x, y, ax=ax, ang=ang, col=col, dark=dark, r=r):
            c = (int(round(x * 16)), int(round(y * 16)))
            cv2.ellipse(img, c, (ax[0] * 16, ax[1] * 16), ang, 0, 360, dark, -1, cv2.LINE_AA, 4)
            c2 = (int(round((x - 0.25 * r) * 16)), int(round((y - 0.25 * r) * 16)))
            cv2.ellipse(img, c2, (int(ax[0] * 12), int(ax[1] * 12)), ang, 0, 360, col, -1, cv2.LINE_AA, 4)

        _stamp_wrapped(stone, (n, n), float(rng.uniform(0, n)), float(rng.uniform(0, n)), 2 * r + 2)
    # needles: thin short segments, fresh (green-brown) and old (rust)
    for _ in range(int(rng.poisson(900 * area_m2))):
        length = rng.uniform(0.02, 0.05) * px
        th = float(rng.uniform(0, np.pi))
        dx, dy = 0.5 * length * np.cos(th), 0.5 * length * np.sin(th)
        old = rng.random() < 0.7
        base = (0.25, 0.40, 0.62) if old else (0.20, 0.35, 0.35)  # BGR
        f = rng.uniform(0.7, 1.2)
        col = tuple(int(255 * min(1.0, b * f)) for b in base)
        w = max(1, int(round(0.0012 * px)))

        def needle(x, y, dx=dx, dy=dy, col=col, w=w):
            p0 = (int(round((x - dx) * 16)), int(round((y - dy) * 16)))
            p1 = (int(round((x + dx) * 16)), int(round((y + dy) * 16)))
            cv2.line(img, p0, p1, col, w, cv2.LINE_AA, 4)

        _stamp_wrapped(needle, (n, n), float(rng.uniform(0, n)), float(rng.uniform(0, n)), length + 2)
    return np.ascontiguousarray(img[..., ::-1])


_GENERATORS = {"bark": bark_texture, "rock": rock_texture, "stump": stump_texture}


def make_texture(kind: str, seed: int, size_px: int, m_per_px: float | None = None) -> np.ndarray:
    """RGB uint8 texture of ``kind`` (one of :data:`KINDS`)."""
    if kind not in KINDS:
        raise ValueError(f"unknown texture kind {kind!r}; use one of {KINDS}")
    if not 32 <= size_px <= 8192:
        raise ValueError(f"texture size must be in [32, 8192] px, got {size_px}")
    if kind == "ground":
        return ground_texture(seed, size_px, 0.5 / size_px if m_per_px is None else m_per_px)
    return _GENERATORS[kind](seed, size_px)


@lru_cache(maxsize=256)
def texture_file(kind: str, seed: int, size_px: int, m_per_px: float | None = None) -> str:
    """Path of the PNG of a texture, generated on first use and cached on disk (atomic write)."""
    import cv2

    recipe = json.dumps({"v": TEXTURE_VERSION, "kind": kind, "seed": int(seed), "size": int(size_px),
                         "m_per_px": m_per_px}, sort_keys=True)
    digest = hashlib.sha1(recipe.encode()).hexdigest()[:16]
    path = _CACHE / f"{kind}-{digest}.png"
    if path.exists():
        return str(path)
    rgb = make_texture(kind, seed, size_px, m_per_px)
    ok, buf = cv2.imencode(".png", rgb[..., ::-1])
    if not ok:  # pragma: no cover - cv2 failure
        from synth.errors import RenderError

        raise RenderError(f"OpenCV could not encode the {kind} texture as PNG")
    from synth.pile import atomic_write_bytes

    atomic_write_bytes(path, buf.tobytes())
    return str(path)


def texture_set(config: TextureConfig) -> list[str]:
    """Every texture file a world can use under ``config``, in a fixed order (generated if needed)."""
    cfg = config
    paths = []
    for k in range(cfg.variants):
        s = cfg.seed * cfg.variants + k
        paths.append(texture_file("ground", s, cfg.ground_px, cfg.ground_uv_m / cfg.ground_px))
        paths.append(texture_file("bark", s, cfg.bark_px))
        paths.append(texture_file("stump", s, cfg.rock_px))
        paths.append(texture_file("rock", s, cfg.rock_px))
    return paths


def apply_textures(world: "World", config: TextureConfig | None = None) -> dict[int, int]:
    """Texture every body of ``world`` (terrain, logs, stumps, rocks) in its own client.

    The body colour is set to white so the texture shows unmodified, and the specular colour to
    ``config.specular``. Log ``i`` gets bark variant ``(seed + i) % variants``, obstacle ``j``
    stump/rock variant ``(seed + j) % variants``; the soil is variant ``terrain.seed % variants``.
    Returns ``{body_id: texture_id}``.

    The whole :func:`texture_set` is loaded, always in the same order: after
    ``resetSimulation`` pybullet restarts texture ids while the EGL plugin keeps its old
    textures, so a rebuilt scene only gets the right images if id k always names the same file
    (measured; ``tests/synth/test_stereo.py`` checks rebuilt scenes against fresh ones).
    pybullet never frees texture memory either (see ``StereoRenderer``'s ``max_scenes``).
    """
    cfg = config or TextureConfig()
    c = world.client
    ids: dict[str, int] = {}
    for path in texture_set(cfg):
        tid = c.loadTexture(path)
        if tid < 0:
            from synth.errors import RenderError

            raise RenderError(f"pybullet could not load the texture {path}; delete the file to regenerate it")
        ids[path] = tid

    def tex(kind: str, variant: int, size: int, m_per_px: float | None = None) -> int:
        return ids[texture_file(kind, cfg.seed * cfg.variants + variant % cfg.variants, size, m_per_px)]

    out: dict[int, int] = {}
    spec = [cfg.specular] * 3

    def put(body: int, tid: int) -> None:
        c.changeVisualShape(body, -1, textureUniqueId=tid, rgbaColor=[1, 1, 1, 1], specularColor=spec)
        out[body] = tid

    t = world.pile.terrain
    put(world.terrain_id, tex("ground", t.seed, cfg.ground_px, cfg.ground_uv_m / cfg.ground_px))
    for i, body in enumerate(world.log_ids):
        put(body, tex("bark", cfg.seed + i, cfg.bark_px))
    n_stumps = len(world.pile.stumps)
    for j, body in enumerate(world.obstacle_ids):
        put(body, tex("stump" if j < n_stumps else "rock", cfg.seed + j, cfg.rock_px))
    return out
