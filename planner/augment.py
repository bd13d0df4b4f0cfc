"""Training augmentation applied consistently to inputs and target maps.

Geometry (the picture is north-up: columns grow with pile +x, rows with pile -y, see
:mod:`synth.geometry.frames`):

* horizontal flip (columns reversed, x -> -x): a grasp at (x, y, phi) becomes (-x, y, -phi), so
  ``C`` = cos 2phi stays and ``S`` = sin 2phi changes sign;
* rotation by ``theta`` counter-clockwise about the image centre (the pile-frame origin) as seen
  from above: (x, y) rotates by theta and phi -> phi + theta, so (C, S) rotate by 2 theta:
  C' = C cos 2theta - S sin 2theta, S' = S cos 2theta + C sin 2theta.
  Quarter turns use exact array rotations; arbitrary angles use ``cv2.warpAffine`` (bilinear with
  replicated borders for intensity and depth, nearest-neighbour for the mask and the maps, U = 0
  where the rotated frame has no data). A vertical flip is a horizontal flip plus a half turn.

Photometry ("randomised colours and lighting"): intensity ``gain * I**gamma + offset`` then
Gaussian noise, clipped to [0, 1]; Gaussian noise on depth [m].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.model import OUTPUT_NAMES

_C, _S, _W, _U, _B = (OUTPUT_NAMES.index(k) for k in OUTPUT_NAMES)


@dataclass(frozen=True)
class AugmentConfig:
    flip_prob: float = 0.5  # probability of a horizontal flip [-]
    rotation: str = "arbitrary"  # "none", "quarter" (multiples of 90 deg) or "arbitrary"
    gain_range: tuple[float, float] = (0.7, 1.3)  # intensity gain [-]
    gamma_log_range: tuple[float, float] = (-0.3, 0.3)  # log of the intensity gamma [-]
    offset_range: tuple[float, float] = (-0.1, 0.1)  # intensity offset [-]
    intensity_noise_std: float = 0.02  # Gaussian noise on intensity [-]
    depth_noise_std_m: float = 0.01  # Gaussian noise on depth [m]

    def __post_init__(self) -> None:
        if not 0.0 <= self.flip_prob <= 1.0:
            raise ValueError(f"flip_prob must be in [0, 1], got {self.flip_prob}")
        if self.rotation not in ("none", "quarter", "arbitrary"):
            raise ValueError(f"rotation must be 'none', 'quarter' or 'arbitrary', got {self.rotation!r}")
        for name in ("gain_range", "gamma_log_range", "offset_range"):
            lo, hi = getattr(self, name)
            if not lo <= hi:
                raise ValueError(f"{name} must be (low, high) with low <= high, got {(lo, hi)}")
        if self.intensity_noise_std < 0 or self.depth_noise_std_m < 0:
            raise ValueError("noise standard deviations must be >= 0")

    @staticmethod
    def off() -> "AugmentConfig":
        """No augmentation at all (validation)."""
        return AugmentConfig(flip_prob=0.0, rotation="none", gain_range=(1.0, 1.0), gamma_log_range=(0.0, 0.0),
                             offset_range=(0.0, 0.0), intensity_noise_std=0.0, depth_noise_std_m=0.0)


def _rotate_angle_maps(maps: np.ndarray, theta_rad: float) -> None:
    c2, s2 = math.cos(2 * theta_rad), math.sin(2 * theta_rad)
    c, s = maps[_C].copy(), maps[_S].copy()
    maps[_C] = c * c2 - s * s2
    maps[_S] = s * c2 + c * s2


def flip_lr(intensity, depth, mask, maps):
    """Horizontal flip (x -> -x, phi -> -phi). Returns new arrays."""
    maps = maps[..., ::-1].copy()
    maps[_S] = -maps[_S]
    return intensity[..., ::-1].copy(), depth[..., ::-1].copy(), mask[..., ::-1].copy(), maps


def rotate(intensity, depth, mask, maps, theta_rad: float):
    """Rotate by ``theta_rad`` counter-clockwise (seen from above) about the image centre."""
    k = theta_rad / (math.pi / 2)
    if abs(k - round(k)) < 1e-9:
        k = int(round(k)) % 4
        rot = lambda a: np.ascontiguousarray(np.rot90(a, k, axes=(-2, -1)))  # noqa: E731  (CCW on screen)
        maps = rot(maps)
        _rotate_angle_maps(maps, theta_rad)
        return rot(intensity), rot(depth), rot(mask), maps
    import cv2

    h, w = depth.shape[-2:]
    M = cv2.getRotationMatrix2D(((w - 1) / 2.0, (h - 1) / 2.0), math.degrees(theta_rad), 1.0)  # + = CCW on screen

    def warp(a, interp, border, value=0.0):
        return cv2.warpAffine(np.ascontiguousarray(a, dtype=np.float32), M, (w, h), flags=interp,
                              borderMode=border, borderValue=value)

    lin = (cv2.INTER_LINEAR, cv2.BORDER_REPLICATE)
    near = (cv2.INTER_NEAREST, cv2.BORDER_CONSTANT)
    intensity = warp(intensity, *lin)
    depth = warp(depth, *lin)
    mask = warp(mask.astype(np.float32), *near) > 0.5
    maps = np.stack([warp(m, *near) for m in maps])
    _rotate_angle_maps(maps, theta_rad)
    return intensity, depth, mask, maps


def photometric(intensity, depth, rng: np.random.Generator, cfg: AugmentConfig):
    gain = rng.uniform(*cfg.gain_range)
    gamma = math.exp(rng.uniform(*cfg.gamma_log_range))
    offset = rng.uniform(*cfg.offset_range)
    i = gain * np.clip(intensity, 0.0, 1.0) ** gamma + offset
    if cfg.intensity_noise_std > 0:
        i = i + rng.normal(0.0, cfg.intensity_noise_std, size=i.shape)
    d = depth
    if cfg.depth_noise_std_m > 0:
        d = depth + rng.normal(0.0, cfg.depth_noise_std_m, size=depth.shape)
    return np.clip(i, 0.0, 1.0).astype(np.float32), d.astype(np.float32)


def augment(intensity, depth, mask, maps, rng: np.random.Generator, cfg: AugmentConfig = AugmentConfig()):
    """Randomly flip, rotate and re-light one sample.

    ``intensity`` (H, W) in [0, 1], ``depth`` (H, W) [m], ``mask`` (H, W) bool, ``maps`` (5, H, W)
    (C, S, W, U, B), or (6, H, W) with the outcome recipe's U weight last (a scalar map, moved like U).
    Returns new ``(intensity, depth, mask, maps)``; the inputs are not modified."""
    if maps.shape[0] not in (5, 6) or maps.shape[1:] != depth.shape or intensity.shape != depth.shape or mask.shape != depth.shape:
        raise ValueError(f"augment needs (H, W) inputs and (5, H, W) maps (6 with a U weight), got {intensity.shape}, {depth.shape}, "
                         f"{mask.shape}, {maps.shape}")
    maps = np.asarray(maps, dtype=np.float32)
    if rng.random() < cfg.flip_prob:
        intensity, depth, mask, maps = flip_lr(intensity, depth, mask, maps)
    if cfg.rotation == "quarter":
        intensity, depth, mask, maps = rotate(intensity, depth, mask, maps, int(rng.integers(4)) * math.pi / 2)
    elif cfg.rotation == "arbitrary":
        intensity, depth, mask, maps = rotate(intensity, depth, mask, maps, rng.uniform(-math.pi, math.pi))
    intensity, depth = photometric(intensity, depth, rng, cfg)
    return intensity, depth, np.asarray(mask, dtype=bool), maps.astype(np.float32)
