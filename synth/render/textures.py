"""Procedural textures for the stereo renders: bark, soil, rock — deterministic in a seed.

Stereo matching needs high-frequency content that does not look periodic within the disparity
search range, so every texture mixes several scales of spectrally shaped noise (generated through
the FFT, hence seamlessly tileable) with drawn detail (fissures, gravel, needles).

Texture coordinates of the bodies built by :class:`synth.physics.world.World`:

* logs: metric UVs from :func:`synth.physics.meshes.frustum` with ``uv_m = 0.5`` — ``u`` along the axis,
  ``v`` around the circumference, one texture repeat per 0.5 m. Bark streaks therefore run along
  the texture's ``u`` (column) direction.
* stumps: the same, with ``uv_m = 0.3``, axis along local z.
* rocks: planar projection of local x, y with ``uv_m = 0.5``.
* terrain: the visual grid mesh from :func:`synth.physics.meshes.grid_mesh` has metric UVs with
  ``uv_m = TextureConfig.ground_uv_m`` (pile x, y divided by it; checked in
  ``tests/synth/render/test_stereo.py``): one 4096 px soil texture spans the default 5 m patch, so
  nothing on the ground repeats inside a scan. (A 0.5 m tile was harmless to stereo, whose search
  range is far shorter, but pycolmap SfM matched features one tile over and joined handheld pairs
  metres apart.)

Every pile gets its own textures (:func:`pile_texture_files`). Files are PNGs in a per-user
temporary cache, named by the SHA-1 of the recipe (kind, seed, size, :data:`TEXTURE_VERSION`) and
written atomically; generation is deterministic, so the recipe determines the content. The cache
keeps at most :data:`CACHE_MAX_BYTES`, dropping the least recently used files. Arrays are RGB
``uint8`` ``(rows, cols, 3)``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from synth.scene.pile import PileSpec
    from synth.physics.world import World

#: Bump when any generator changes its output (part of every cache key).
TEXTURE_VERSION = "3"

_CACHE = Path(tempfile.gettempdir()) / f"loggrasp-textures-{os.getuid() if hasattr(os, 'getuid') else 0}"

#: Bound of the texture cache on disk; a 4096 px soil texture is ~35 MB as PNG [bytes].
CACHE_MAX_BYTES = 2 * 1024**3
#: Files younger than this are never pruned: another process may be about to load them [s].
_PRUNE_MIN_AGE_S = 600.0

KINDS = ("bark", "ground", "rock", "stump")


@dataclass(frozen=True)
class TextureConfig:
    """How the bodies of a world are textured."""

    seed: int = 0  # base seed; with each pile's own digest it fixes every texture [-]
    bark_px: int = 512  # side of a bark texture = one 0.5 m repeat (~1 mm / px) [px]
    rock_px: int = 512  # side of a rock / stump texture [px]
    ground_px: int = 4096  # side of the soil texture [px] (1.2 mm / px over 5 m; 2048 px lost stereo detail)
    ground_uv_m: float = 5.0  # terrain per soil-texture repeat (the terrain mesh's UVs) [m]: the default 5 m
    #                           patch holds one copy, so nothing on the ground repeats inside a scan
    specular: float = 0.0  # specular colour of textured bodies (view-dependent highlights hurt stereo) [-]

    def __post_init__(self) -> None:
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


def _smooth_noise(rng: np.random.Generator, n: int, beta: float, k_min: float, res: int) -> np.ndarray:
    """:func:`spectral_noise` for a red spectrum, made at ``res`` px and upsampled to ``n`` px.

    A spectrum falling as 1/k^beta (beta >= 1.8) holds almost nothing above ``res / 2`` cycles
    (about 1 % of the amplitude at ``k_min``), so the small FFT loses nothing visible; the upsampling
    pads by wrapping, which keeps the result tileable.
    """
    import cv2

    if res >= n:
        return spectral_noise(rng, n, n, beta=beta, k_min=k_min)
    small = spectral_noise(rng, res, res, beta=beta, k_min=k_min)
    pad = 4
    f = n / res
    big = cv2.resize(np.pad(small, pad, mode="wrap"), None, fx=f, fy=f, interpolation=cv2.INTER_CUBIC)
    o = int(round(pad * f))
    out = np.ascontiguousarray(big[o:o + n, o:o + n])
    out -= out.mean()
    return out / max(float(out.std()), 1e-12)


def ground_texture(seed: int, size_px: int = 512, m_per_px: float = 0.5 / 512) -> np.ndarray:
    """Forest-floor soil: multi-scale noise, moss/litter patches, gravel and conifer needles.

    Seamlessly tileable. ``m_per_px`` sets the physical size of gravel and needles. The smooth
    fields are made at 1/4 (mid-scale: 1/2) resolution and upsampled (:func:`_smooth_noise`): a
    4096 px texture then takes ~5 s instead of ~9 s here (2-core CPU).
    """
    import cv2

    rng = _rng("ground", seed)
    n = size_px
    low, mid_res = max(64, n // 4), max(64, n // 2)
    coarse = _smooth_noise(rng, n, beta=2.6, k_min=1.0, res=low)
    mid = _smooth_noise(rng, n, beta=1.8, k_min=4.0, res=mid_res)
    fine = spectral_noise(rng, n, n, beta=0.5, k_min=max(8.0, n / 64))
    lum = 1.0 + 0.05 * coarse + 0.12 * mid + 0.10 * fine
    soil = _colourise(np.clip(lum, 0.3, 1.8), (0.40, 0.33, 0.24))
    litter = np.clip(_smooth_noise(rng, n, beta=2.0, k_min=3.0, res=low) * 0.8 - 0.2, 0.0, 1.0)[..., None]
    litter_rgb = np.array([0.50, 0.40, 0.25], dtype=np.float32) * (1.0 + 0.15 * mid[..., None])
    moss = np.clip(_smooth_noise(rng, n, beta=2.0, k_min=3.0, res=low) - 1.8, 0.0, 1.0)[..., None]
    moss_rgb = np.array([0.30, 0.38, 0.18], dtype=np.float32) * (1.0 + 0.2 * fine[..., None])
    rgb = soil * (1 - litter) + litter_rgb * litter
    rgb = rgb * (1 - moss) + moss_rgb * moss
    img = np.ascontiguousarray(_to_uint8(rgb)[..., ::-1])  # BGR for cv2 drawing
    del coarse, mid, fine, soil, litter, litter_rgb, moss, moss_rgb, rgb

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


def texture_file(kind: str, seed: int, size_px: int, m_per_px: float | None = None) -> str:
    """Path of the PNG of a texture, generated on first use and cached on disk (atomic write)."""
    import cv2

    recipe = json.dumps({"v": TEXTURE_VERSION, "kind": kind, "seed": int(seed), "size": int(size_px),
                         "m_per_px": m_per_px}, sort_keys=True)
    digest = hashlib.sha1(recipe.encode()).hexdigest()[:16]
    path = _CACHE / f"{kind}-{digest}.png"
    if path.exists():
        try:
            os.utime(path)  # recently used: pruned last
        except OSError:  # pragma: no cover - pruned by another process just now
            pass
        else:
            return str(path)
    rgb = make_texture(kind, seed, size_px, m_per_px)
    ok, buf = cv2.imencode(".png", rgb[..., ::-1])
    if not ok:  # pragma: no cover - cv2 failure
        from synth.errors import RenderError

        raise RenderError(f"OpenCV could not encode the {kind} texture as PNG")
    from synth.common.files import atomic_write_bytes

    atomic_write_bytes(path, buf.tobytes())
    prune_cache(CACHE_MAX_BYTES)
    return str(path)


def prune_cache(max_bytes: int, min_age_s: float | None = None) -> int:
    """Delete the least recently used cached textures until the cache holds at most ``max_bytes``.

    Files used in the last ``min_age_s`` seconds (default :data:`_PRUNE_MIN_AGE_S`) are kept
    whatever the size. Returns the number of files deleted.
    """
    import time

    age = _PRUNE_MIN_AGE_S if min_age_s is None else min_age_s
    try:
        entries = [(st.st_mtime, st.st_size, e.path) for e in os.scandir(_CACHE)
                   if e.is_file() and e.name.endswith(".png") for st in (e.stat(),)]
    except OSError:
        return 0
    total = sum(size for _, size, _ in entries)
    now, gone = time.time(), 0
    for mtime, size, path in sorted(entries):
        if total <= max_bytes or now - mtime < age:
            break
        try:
            os.unlink(path)
        except OSError:
            continue
        total -= size
        gone += 1
    return gone


def _digest_seed(*parts: object) -> int:
    """A 32-bit seed from a stable digest of ``parts`` (JSON; never Python's salted ``hash``)."""
    blob = json.dumps(parts, sort_keys=True, default=str).encode()
    return int.from_bytes(hashlib.sha1(blob).digest()[:4], "little")


def pile_texture_files(pile: "PileSpec", config: TextureConfig | None = None) -> dict[str, Any]:
    """The texture files of one pile: ``{"ground": path, "logs": [path, ...], "obstacles": [path, ...]}``.

    Every place gets its own textures: the soil from a digest of the terrain, each log's bark and
    each stump's or rock's surface from a digest of the whole pile and its index, all mixed with
    ``config.seed``. Two piles therefore never share a surface (what a field site is like), which
    matters to SfM: with textures shared between piles, or a soil tile repeating every 0.5 m, pycolmap
    matched features one repeat over and joined handheld pairs metres apart. Generated if needed.
    """
    cfg = config or TextureConfig()
    ground = texture_file("ground", _digest_seed(cfg.seed, "ground", dataclasses.asdict(pile.terrain)),
                          cfg.ground_px, cfg.ground_uv_m / cfg.ground_px)
    whole = pile.to_dict()
    logs = [texture_file("bark", _digest_seed(cfg.seed, "log", i, whole), cfg.bark_px) for i in range(len(pile.logs))]
    n_stumps = len(pile.stumps)
    obstacles = [texture_file("stump" if j < n_stumps else "rock", _digest_seed(cfg.seed, "obstacle", j, whole),
                              cfg.rock_px) for j in range(n_stumps + len(pile.rocks))]
    return {"ground": ground, "logs": logs, "obstacles": obstacles}


def apply_textures(world: "World", config: TextureConfig | None = None) -> dict[int, int]:
    """Texture every body of ``world`` (terrain, logs, stumps, rocks) in its own client.

    The textures are the pile's own (:func:`pile_texture_files`). The body colour is set to white
    so the texture shows unmodified, and the specular colour to ``config.specular``.
    Returns ``{body_id: texture_id}``.

    Load textures into a fresh client only: after ``resetSimulation`` pybullet restarts texture
    ids while the EGL plugin keeps its old textures (measured), and pybullet never frees texture
    memory; :class:`synth.render.stereo.StereoRenderer` therefore builds a new client for every pile.
    """
    cfg = config or TextureConfig()
    c = world.client
    files = pile_texture_files(world.pile, cfg)
    ids: dict[str, int] = {}
    for path in [files["ground"], *files["logs"], *files["obstacles"]]:
        if path in ids:
            continue
        tid = c.loadTexture(path)
        if tid < 0:
            from synth.errors import RenderError

            raise RenderError(f"pybullet could not load the texture {path}; delete the file to regenerate it")
        ids[path] = tid

    out: dict[int, int] = {}
    spec = [cfg.specular] * 3

    def put(body: int, path: str) -> None:
        tid = ids[path]
        c.changeVisualShape(body, -1, textureUniqueId=tid, rgbaColor=[1, 1, 1, 1], specularColor=spec)
        out[body] = tid

    put(world.terrain_id, files["ground"])
    for body, path in zip(world.log_ids, files["logs"]):
        put(body, path)
    for body, path in zip(world.obstacle_ids, files["obstacles"]):
        put(body, path)
    return out
