"""A grasp-centred success ranker: the U-Net proposes, a small crop network re-scores.

The U-Net's U marks where grasps were accepted; it orders a pile's grasps only a little better than
chance (docs/results/ranking-v3). Its top few subsets, though, usually hold a grasp that works. The
ranker is a GQ-CNN-like network (Mahler et al. 2017) that looks at one grasp at a time: a crop of
the observation centred on the grasp and turned so that its closing axis runs along the crop's
columns, with the claws drawn where they will come down, and predicts the probability that the grasp
lifts exactly its targets when the crane stands off by the field's positioning error (its training
label: the robust labels' success fraction, :func:`synth.data.outcomes.trial_success`).

Crop channels (``RankerConfig.crop_channels``, from ``CROP_CHANNELS``), ``crop_px`` square at the
observation's pixel pitch:

* ``I``: intensity of the render, in [0, 1];
* ``H``: height [m] relative to the highest target pixel in the crop (the top the claws meet);
* ``M_T``: the target mask, {0, 1};
* ``claws``: 1 on the two claw plates' footprints (``claw_width_m`` along the log, ``claw_plate_m``
  across, just outside the opening ``width_m``), 0 elsewhere;
* ``M_L``: the logs that are not targets, {0, 1} (from the instance map): a log the claws would take
  along, or one lying on a target;
* ``M_O``: the obstacles (stumps, rocks), {0, 1} (from the instance map): a target lying against one
  is held by it (measured: such f3 choices succeed 62 %, the others 87 %, docs/results/README.md).

Checkpoints made before the instance channels (no ``crop_channels`` stored) read as
``LEGACY_CROP_CHANNELS``.

The head also sees the opening width [m] and the number of targets / 7. Re-ranking (:func:`rerank`)
takes the union of the best ``k`` grasps by f1 and by f3 of a :class:`planner.inference.Plan`, scores
them and orders them by the objective with U replaced by a blend of the ranker's probability p and the
network's U, ``sigmoid(w logit U + (1 - w) logit p)`` with ``w`` = ``u_weight`` (0: p alone). The two
err differently (U knows the pile around the grasp, p the claws' footprint and the number of targets), so
the blend ranks better than either: :data:`U_WEIGHT` below. Checkpoints are
safetensors files of format ``loggrasp.planner.ranker`` (:func:`save_ranker`, :func:`load_ranker`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from planner.errors import CheckpointError
from synth.geometry.frames import OrthoGrid
from synth.geometry.grasp import Grasp
from synth.physics.world import OBSTACLE_BASE

RANKER_FORMAT_NAME = "loggrasp.planner.ranker"
CROP_CHANNELS = ("I", "H", "M_T", "claws", "M_L", "M_O")  # every channel a crop can have, in this order
LEGACY_CROP_CHANNELS = CROP_CHANNELS[:4]  # a checkpoint that stores no crop_channels (before the instance channels)
INSTANCE_CHANNELS = ("M_L", "M_O")  # the channels made from the instance map
MAX_TARGETS = 7  # the number of targets is fed to the head divided by this [-]
# rerank's default weight of U's logit in the blend with the ranker's p [-]: chosen on the first 48 of the
# 96 held-out piles of docs/results/ranking-v3model-rev4 (weights 0-1 in steps of 0.05-0.25; within-pile AUC
# 0.807 at 0.75, against 0.750 for U and 0.726 for p) and checked on the other 48 (0.782 against 0.726 and
# 0.671; f1's choice 89.6 against 83.3 %, f3's 91.7 against 87.5 %): docs/results/README.md, ranker-r0
U_WEIGHT = 0.75


@dataclass(frozen=True)
class RankerConfig:
    """The ranker's crop and network."""

    crop_px: int = 48  # crop side [px] (at the observation's pitch: 48 x 3.9 cm = 1.88 m, the widest opening + claws)
    pixel_m: float = 5.0 / 128  # the pixel pitch crops are taken at [m] (the U-Net's training images)
    claw_width_m: float = 0.22  # claw plate extent along the logs [m] (the twin's grapple)
    claw_plate_m: float = 0.05  # claw plate thickness across the logs [m] (the twin's grapple)
    channels: int = 32  # channels of the first convolution (doubled once) [-]
    hidden: int = 128  # units of the fully connected layer [-]
    crop_channels: tuple[str, ...] = CROP_CHANNELS  # the crop's channels, a sub-sequence of CROP_CHANNELS [-]

    def __post_init__(self) -> None:
        object.__setattr__(self, "crop_channels", tuple(self.crop_channels))
        if not self.crop_channels or tuple(c for c in CROP_CHANNELS if c in self.crop_channels) != self.crop_channels:
            raise ValueError(f"crop_channels must be a non-empty sub-sequence of {list(CROP_CHANNELS)} in that order, "
                             f"got {list(self.crop_channels)}")
        if not 16 <= self.crop_px <= 128 or self.crop_px % 8:
            raise ValueError(f"crop_px must be a multiple of 8 in [16, 128], got {self.crop_px}")
        for k in ("pixel_m", "claw_width_m", "claw_plate_m"):
            if not (math.isfinite(getattr(self, k)) and getattr(self, k) > 0):
                raise ValueError(f"{k} must be > 0, got {getattr(self, k)}")
        if self.channels < 4 or self.hidden < 8:
            raise ValueError(f"channels must be >= 4 and hidden >= 8, got {self.channels}, {self.hidden}")

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def needs_instance(self) -> bool:
        """True when a crop has a channel made from the instance map."""
        return any(c in INSTANCE_CHANNELS for c in self.crop_channels)

    @classmethod
    def from_dict(cls, d: dict) -> "RankerConfig":
        return cls(**{"crop_channels": LEGACY_CROP_CHANNELS, **d})


def grasp_crops(intensity: np.ndarray, height_m: np.ndarray, masks: Sequence[np.ndarray] | np.ndarray,
                grid: OrthoGrid, grasps: Sequence[Grasp], config: RankerConfig = RankerConfig(),
                instance: np.ndarray | None = None) -> np.ndarray:
    """The ranker's input crops (N, C, S, S) float32 for ``grasps``, each with its own target mask; C =
    ``len(config.crop_channels)``.

    ``height_m`` is the height image (:func:`planner.data.normalise_depth`); ``masks`` one target mask
    per grasp (or one for all); ``instance`` the instance map (0 ground, i + 1 log i, from 1000
    obstacles), needed when ``config`` has ``M_L`` or ``M_O`` (``ValueError`` without it). Crop row 0 is
    on the left of the closing axis; column 0 at its negative end; pixels outside the image repeat its
    border."""
    if config.needs_instance and instance is None:
        raise ValueError(f"the crop channels {list(config.crop_channels)} need the instance map")
    s = config.crop_px
    c = (np.arange(s) - (s - 1) / 2) * config.pixel_m
    u, v = np.meshgrid(c, -c)  # u along the closing axis (columns), v to its left (rows, up)
    masks = np.asarray(masks)
    logs = obstacles = None
    if instance is not None:
        inst = np.asarray(instance)
        logs, obstacles = (inst > 0) & (inst < OBSTACLE_BASE), inst >= OBSTACLE_BASE
    out = np.empty((len(grasps), len(config.crop_channels), s, s), dtype=np.float32)
    for n, g in enumerate(grasps):
        a = np.array([math.cos(g.phi_rad), math.sin(g.phi_rad)])
        rc = np.stack(grid.pile_to_pixel(g.x_m + u * a[0] - v * a[1], g.y_m + u * a[1] + v * a[0]))
        mask = np.asarray(masks if masks.ndim == 2 else masks[n], dtype=bool)
        claws = claw_footprint(u, v, g.width_m, config)
        out[n] = _crop_layers(rc, intensity, height_m, mask, logs, obstacles, claws, config.crop_channels)
    return out


def _crop_layers(rc: np.ndarray, intensity, height_m, mask, logs, obstacles, claws: np.ndarray,
                 want: tuple[str, ...]) -> list[np.ndarray]:
    """One crop's channels in ``want``'s order: the images sampled at pixel coordinates ``rc`` (2, S, S),
    and ``claws``, the grasp's claw footprint in the crop."""
    from scipy.ndimage import map_coordinates

    def sample(img) -> np.ndarray:
        return map_coordinates(np.asarray(img, np.float32), rc, order=1, mode="nearest")

    h = sample(height_m)
    m = sample(mask) > 0.5
    top = float(h[m].max()) if m.any() else float(h[h.shape[0] // 2, h.shape[1] // 2])
    made = {"H": lambda: h - top, "M_T": lambda: m, "I": lambda: sample(intensity), "claws": lambda: claws,
            "M_L": lambda: sample(logs & ~mask) > 0.5, "M_O": lambda: sample(obstacles) > 0.5}
    return [made[name]() for name in want]


def claw_footprint(u: np.ndarray, v: np.ndarray, width_m: float, config: RankerConfig) -> np.ndarray:
    """1 where the claw plates of an opening ``width_m`` come down in crop coordinates (u, v) [m]."""
    across = (np.abs(u) >= width_m / 2) & (np.abs(u) <= width_m / 2 + config.claw_plate_m)
    return (across & (np.abs(v) <= config.claw_width_m / 2)).astype(np.float32)


def grasp_scalars(grasps: Sequence[Grasp], taus: Sequence[int]) -> np.ndarray:
    """The head's scalar inputs (N, 2): opening width [m] and number of targets / 7."""
    return np.array([[g.width_m, t / MAX_TARGETS] for g, t in zip(grasps, taus)], dtype=np.float32).reshape(-1, 2)


def build_ranker(config: RankerConfig = RankerConfig()):
    """The crop network: three conv + max-pool stages, a fully connected layer with the scalars, a logit."""
    import torch
    from torch import nn

    k = config.channels
    flat = 2 * k * (config.crop_px // 8) ** 2

    class RankerNet(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.features = nn.Sequential(
                nn.Conv2d(len(config.crop_channels), k, 5, padding=2), nn.ReLU(), nn.MaxPool2d(2),
                nn.Conv2d(k, 2 * k, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
                nn.Conv2d(2 * k, 2 * k, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2))
            self.head = nn.Sequential(nn.Linear(flat + 2, config.hidden), nn.ReLU(), nn.Linear(config.hidden, 1))

        def forward(self, crops, scalars):
            f = self.features(crops).flatten(1)
            return self.head(torch.cat([f, scalars], dim=1)).squeeze(1)

    return RankerNet()


def save_ranker(path: str | Path, model, config: RankerConfig, meta: dict[str, Any] | None = None) -> Path:
    from planner.checkpoint import CHECKPOINT_FORMAT_VERSION, save_tensors

    header = {"format": RANKER_FORMAT_NAME, "format_version": CHECKPOINT_FORMAT_VERSION,
              "ranker_config": config.to_dict(), "meta": dict(meta or {})}
    return save_tensors(path, model.state_dict(), header)


def load_ranker(path: str | Path) -> "Ranker":
    """A ranker checkpoint, ready to score; :class:`CheckpointError` for a missing, foreign or broken file."""
    from planner.checkpoint import load_tensors

    tensors, header = load_tensors(path, RANKER_FORMAT_NAME)
    try:
        config = RankerConfig.from_dict(header["ranker_config"])
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{path}: the stored ranker configuration is invalid ({exc})") from exc
    model = build_ranker(config)
    try:
        model.load_state_dict(tensors, strict=True)
    except RuntimeError as exc:
        raise CheckpointError(f"{path}: the weights do not fit the stored ranker ({exc}); retrain it") from exc
    model.eval()
    return Ranker(model, config, header.get("meta", {}))


@dataclass
class Ranker:
    model: Any
    config: RankerConfig
    meta: dict

    def probabilities(self, crops: np.ndarray, scalars: np.ndarray) -> np.ndarray:
        """Success probabilities of crops (N, C, S, S) with their scalars (N, 2)."""
        import torch

        if not len(crops):
            return np.zeros(0)
        with torch.inference_mode():
            logits = self.model(torch.from_numpy(np.ascontiguousarray(crops, dtype=np.float32)),
                                torch.from_numpy(np.ascontiguousarray(scalars, dtype=np.float32)))
        return torch.sigmoid(logits.float()).numpy().astype(np.float64)

    def score(self, observation, grasps: Sequence[Grasp], targets: Sequence[Sequence[int]]) -> np.ndarray:
        """Success probability of each grasp on its targets (log indices) in ``observation``."""
        from planner.data import normalise_depth
        from planner.inference import observation_arrays

        inten, depth, inst, extent_m, cam_h = observation_arrays(observation)
        grid = OrthoGrid(depth.shape[0], extent_m)
        if abs(grid.pixel_m / self.config.pixel_m - 1.0) > 0.005:
            raise CheckpointError(f"the ranker was trained on {100 * self.config.pixel_m:.2f} cm pixels but the "
                                  f"observation has {100 * grid.pixel_m:.2f} cm; render at the ranker's pitch or "
                                  "plan without it (--no-ranker)")
        masks = np.stack([np.isin(inst, [i + 1 for i in t]) for t in targets]) if len(targets) else np.zeros((0,) + inst.shape)
        crops = grasp_crops(inten, normalise_depth(depth, cam_h), masks, grid, grasps, self.config, inst)
        return self.probabilities(crops, grasp_scalars(grasps, [len(t) for t in targets]))


def check_u_weight(u_weight: float) -> None:
    """Raise ValueError unless ``u_weight`` (U's share of the blend's logit) lies in [0, 1]."""
    if not 0.0 <= u_weight <= 1.0:
        raise ValueError(f"u_weight must be in [0, 1], got {u_weight}")


def blend(u, p, u_weight: float = U_WEIGHT):
    """``sigmoid(u_weight logit u + (1 - u_weight) logit p)``: the network's U and the ranker's p as one
    success score (each clipped to [1e-6, 1 - 1e-6] first)."""
    check_u_weight(u_weight)
    u, p = (np.clip(np.asarray(v, dtype=np.float64), 1e-6, 1 - 1e-6) for v in (u, p))
    z = u_weight * np.log(u / (1 - u)) + (1 - u_weight) * np.log(p / (1 - p))
    return 1.0 / (1.0 + np.exp(-z))


def rerank(plan, observation, ranker: Ranker, objective, k: int = 4, u_weight: float = U_WEIGHT):
    """``plan`` with the union of its best ``k`` grasps by f1 and by f3 (``objective`` itself when it is an
    f3: its tolerance and balance source) scored by ``ranker`` and put
    first, ordered by ``objective`` with U replaced by :func:`blend` of U and the ranker's probability
    (``quality`` and ``graspability`` of those grasps become the blend's; U stays in
    ``info["u_network"]``, p in ``info["p_ranker"]``). The grasps the ranker did not score follow in
    their order with quality 0: no grasp outside the scored union outranks one in it, wherever the plan is
    sorted by quality (the verifier's candidates)."""
    from planner.inference import Objective

    check_u_weight(u_weight)  # before any scoring

    f3 = objective if objective.kind == "f3" else Objective("f3")  # f3's own tolerance and balance source
    by_f1 = sorted(plan.grasps, key=lambda g: -g.graspability)[:k]
    by_f3 = sorted(plan.grasps, key=lambda g: -float(f3.quality(g.graspability, len(g.targets), g.balance)))[:k]
    chosen = list({g.targets: g for g in by_f1 + by_f3}.values())
    if not chosen:
        return plan
    p = ranker.score(observation, [g.grasp for g in chosen], [g.targets for g in chosen])
    s = blend([g.graspability for g in chosen], p, u_weight)
    scored = [replace(g, graspability=float(si), quality=float(objective.quality(si, len(g.targets), g.balance)))
              for g, si in zip(chosen, s)]
    scored.sort(key=lambda g: -g.quality)
    scored_targets = {g.targets for g in scored}
    rest = [replace(g, quality=0.0) for g in plan.grasps if g.targets not in scored_targets]
    info = {**plan.info, "reranked": len(scored),
            "u_network": {",".join(map(str, g.targets)): g.graspability for g in chosen},
            "p_ranker": {",".join(map(str, g.targets)): float(pi) for g, pi in zip(chosen, p)}, "u_weight": u_weight}
    return replace(plan, grasps=scored + rest, info=info)


def plan_reranked(observation, planner, objective, ranker: Ranker | None, constraints=None, top_k: int | None = None,
                  rerank_k: int = 4, u_weight: float = U_WEIGHT, **plan_kwargs):
    """:func:`planner.inference.plan` of every subset, re-ranked by ``ranker`` (:func:`rerank`) when one
    is given, then its best ``top_k`` (all when None). ``plan_kwargs``: ``subsets``, ``pile``."""
    from planner.constraints import Constraints
    from planner.inference import plan

    constraints = Constraints() if constraints is None else constraints
    if ranker is None:
        return plan(observation, planner, objective, constraints, top_k=top_k, **plan_kwargs)
    result = rerank(plan(observation, planner, objective, constraints, top_k=None, **plan_kwargs), observation, ranker,
                    objective, rerank_k, u_weight)
    return replace(result, grasps=result.grasps[:top_k]) if top_k else result
