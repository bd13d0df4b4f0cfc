"""Plan grasps on one observation: every target subset through the network, batched.

For a top-down observation (intensity, depth, instance map of :class:`synth.render.ortho.OrthoObservation`)
the planner

1. finds the visible logs (instance codes ``i + 1``) and chooses target subsets
   (:mod:`planner.subsets`: all 2^n - 1, or those that fit one grapple opening);
2. drops subsets over the lift capacity (:mod:`planner.constraints`);
3. runs the network on all remaining target masks in batches, in inference mode
   (channels-last, convolution + ReLU fused, bfloat16 where the CPU computes it natively:
   :mod:`planner.runtime`);
4. scores each pixel with ``Q = f(u, tau, b)`` (:class:`Objective`), masks pixels out of reach,
   takes the best pixel whose grasp rectangle avoids the keep-out zones;
5. decodes phi = atan2(S, C) / 2 from C and S *smoothed* with a Gaussian around that pixel
   (never by averaging angles), the width [m], and the pile-frame position via
   :class:`synth.geometry.frames.OrthoGrid`.

The :class:`Plan` lists the best grasp of each subset, best first.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from planner.balance import HangModel
from planner.constraints import Constraints, polygon_raster
from planner.data import make_inputs
from planner.errors import ObservationError
from planner.model import OUTPUT_NAMES, UNetConfig, decode_balance
from planner.runtime import INT8_PRECISIONS, masks_per_pass, resolve_precision
from planner.subsets import SubsetPolicy, choose_subsets
from synth.geometry.frames import OrthoGrid, wrap_phi
from synth.geometry.grasp import MAX_WIDTH_M, MIN_WIDTH_M, RECT_WIDTH_M, Grasp
from synth.physics.world import OBSTACLE_BASE

PLAN_FORMAT_NAME = "loggrasp.plan"  # plan.json, ``loggrasp plan --json``
PLAN_FORMAT_VERSION = "1.0"
OBSTACLE_CODE_BASE = OBSTACLE_BASE  # instance codes >= this are obstacles (synth.render.ortho)
SIGMA_B = 0.25  # the paper's f3 balance tolerance [cos beta]
HANG_SIGMA_B = 0.05  # f3's tolerance on the hang model's b [cos beta]: chosen on seeds 950,000,000+
#                      (docs/results/aft4/tune-950), held out on 970,000,000+ (docs/model.md)
BALANCE_SOURCES = ("network", "hang")  # what f3's b is (Objective.balance)
PRODUCT_F3_BALANCE = "network"  # f3's b in plan and the field trial (docs/model.md, "The balance f3 scores")


def f3_sigma_b(balance: str, sigma_b: float | None = None) -> float:
    """f3's balance tolerance: ``sigma_b`` when given, else the one chosen for the balance
    source (the paper's 0.25 on the B map, 0.05 on the hang model's tilt); :class:`Objective`
    checks both."""
    if sigma_b is not None:
        return sigma_b
    return HANG_SIGMA_B if balance == "hang" else SIGMA_B


@dataclass(frozen=True)
class Objective:
    """Pixel quality ``Q = f(u, tau, b)`` (the paper's f1, f2, f3)."""

    kind: Literal["f1", "f2", "f3"] = "f1"  # "f1": u; "f2": u tau^mu; "f3": u tau^mu exp(-(b - b_opt)^2 / sigma_b^2)
    mu: float = 1.0 / 3.0  # exponent on the number of target logs [-]
    b_opt: float = 1.0  # optimal balance cos(beta) [-]
    sigma_b: float = SIGMA_B  # balance tolerance [cos beta]
    balance: Literal["network", "hang"] = "network"  # f3's b: the network's B map (the paper's) or the tilt the
    #                                                  load will hang with (planner.balance.HangModel)
    hang: HangModel = HangModel()  # ... with balance "hang"

    def __post_init__(self) -> None:
        if self.kind not in ("f1", "f2", "f3"):
            raise ValueError(f"objective kind must be 'f1', 'f2' or 'f3', got {self.kind!r}")
        if self.balance not in BALANCE_SOURCES:
            raise ValueError(f"objective balance must be one of {BALANCE_SOURCES}, got {self.balance!r}")
        if self.mu < 0 or not self.sigma_b > 0:
            raise ValueError("need mu >= 0 and sigma_b > 0")

    def quality(self, u, tau, b):
        """Element-wise quality; ``tau`` broadcasts (e.g. shape (N, 1, 1) for N subsets)."""
        u = np.asarray(u, dtype=np.float32)
        if self.kind == "f1":
            return u
        q = u * np.power(np.asarray(tau, dtype=np.float32), np.float32(self.mu))
        if self.kind == "f3":
            q = q * np.exp(-((np.asarray(b, dtype=np.float32) - self.b_opt) ** 2) / self.sigma_b ** 2)
        return q


@dataclass
class Planner:
    """A loaded network plus how to run it."""

    model: object  # torch.nn.Module in eval mode
    config: UNetConfig
    device: Literal["cpu", "cuda"] = "cpu"  # "cpu" or "cuda"
    precision: Literal["auto", "bf16", "fp32", "int8", "int8-bf16-top"] = "auto"  # "auto":
    # planner.runtime.default_precision without a calibration (bf16 where the CPU has bf16 dot products, else
    # fp32; load_planner's "auto" picks int8 where the checkpoint has one); "int8" and "int8-bf16-top" (CPU):
    # planner.int8 with int8_calibration; after construction the format that runs
    batch_size: int | None = None  # target masks per forward pass [-]; None: 16 per torch thread (planner.runtime)
    meta: dict = field(default_factory=dict)
    angle_smoothing_px: float = 1.0  # Gaussian sigma for C, S (and W) before decoding [px]
    quality_smoothing_px: float = 1.0  # Gaussian sigma for U and B before scoring [px]; 0 = raw
    # (GG-CNN style: the argmax then favours a grasp zone over a single-pixel spike)
    candidates_per_subset: int = 64  # pixels tried per subset against keep-out zones [-]
    views: int = 1  # dihedral views averaged at test time: 1 (none), 2 (+ mirror), 4 (quarter turns) or 8 (both) [-]
    view_spread_k: float = 0.0  # U logit lowered by k x its standard deviation over the views [-]
    # (a lower confidence bound: of two grasps the views rate alike on average, the one they agree on wins)
    int8_calibration: object = None  # planner.int8.Int8Calibration of these weights; needed by the int8 precisions

    def __post_init__(self) -> None:
        self.precision = resolve_precision(self.precision, self.device)
        if self.batch_size is not None and self.batch_size < 1:
            raise ValueError("batch_size must be >= 1 (or None: planner.runtime.masks_per_pass)")
        if not (self.angle_smoothing_px >= 0 and self.quality_smoothing_px >= 0):
            raise ValueError("angle_smoothing_px and quality_smoothing_px must be >= 0 pixels")
        check_views(self.views, self.view_spread_k)
        if self.precision in INT8_PRECISIONS:
            from planner.int8 import build_int8

            if self.int8_calibration is None:
                raise ValueError(f"precision {self.precision!r} needs the weights' int8 calibration (int8_calibration; "
                                 "load_planner reads it beside the checkpoint, planner.int8.calibration_path)")
            self._net = build_int8(self.model, self.int8_calibration, masks_per_pass(self.batch_size),
                                   float_top=self.precision == "int8-bf16-top")
            return
        from planner.model import prepare_for_inference

        self._net = prepare_for_inference(self.model, self.precision, self.device)

    @property
    def dtype(self):
        import torch

        return torch.bfloat16 if self.precision == "bf16" else torch.float32  # int8: quantized inside the net

    def _tensor(self, a: np.ndarray):
        import torch

        t = torch.from_numpy(np.ascontiguousarray(a)).to(self.device, self.dtype)
        return t.contiguous(memory_format=torch.channels_last) if self.device == "cpu" else t

    def predict(self, x: np.ndarray) -> np.ndarray:
        """Network output (N, 5, H, W) float32 for inputs (N, C, H, W) that share one image
        (all channels but the last, the target mask), batched.

        With ``views`` > 1 the output is the mean over that many dihedral views of the input
        (mirrored and/or turned by quarter turns, run through the network and mapped back, the
        angle maps turned with them): the network was trained on turned and mirrored piles but is
        not exactly equivariant, and the mean over all 8 views is — the plan no longer depends on
        which way north points in the picture. The U channel is averaged as logits, less
        ``view_spread_k`` times their standard deviation over the views."""
        if self.views == 1:
            return self._predict_once(x)
        acc = acc_u2 = None
        for flip, k in _view_list(self.views):
            y = _view_back(self._predict_once(_view(x, flip, k)), flip, k)
            acc = y if acc is None else acc + y
            u2 = np.square(y[:, _U_LOGIT], dtype=np.float64)
            acc_u2 = u2 if acc_u2 is None else acc_u2 + u2
        mean = acc / np.float32(self.views)
        if self.view_spread_k > 0:
            var = np.maximum(acc_u2 / self.views - np.square(mean[:, _U_LOGIT], dtype=np.float64), 0.0)
            mean[:, _U_LOGIT] -= np.float32(self.view_spread_k) * np.sqrt(var).astype(np.float32)
        return mean

    def _predict_once(self, x: np.ndarray) -> np.ndarray:
        import torch

        outs = []
        bs = masks_per_pass(self.batch_size)
        with torch.inference_mode():
            net = self._net
            if net.late and len(x):
                feats = net.encode(self._tensor(x[:1, :-1]))
            for k in range(0, len(x), bs):
                if net.late:
                    y = net.decode(feats, self._tensor(x[k : k + bs, -1:]))
                else:
                    y = net(self._tensor(x[k : k + bs]))
                outs.append(y.float().contiguous().cpu().numpy())
        return np.concatenate(outs) if outs else np.zeros((0, 5, *x.shape[2:]), np.float32)


VIEWS = (1, 2, 4, 8)
_U_LOGIT = OUTPUT_NAMES.index("U")  # the graspability logit in the network output


def check_views(views: int, view_spread_k: float) -> None:
    """``ValueError`` unless ``views`` is 1, 2, 4 or 8 and ``view_spread_k`` >= 0 (> 0 only with
    more than one view: a spread over views)."""
    if views not in VIEWS:
        raise ValueError(f"views must be one of {VIEWS} (dihedral views averaged), got {views!r}")
    if not view_spread_k >= 0 or (view_spread_k > 0 and views == 1):
        raise ValueError(f"view_spread_k must be >= 0 and needs views > 1 (a spread over views), "
                         f"got {view_spread_k} with views={views}")


def _view_list(views: int) -> list[tuple[bool, int]]:
    """(mirror, quarter turns) of each dihedral view; the identity first."""
    flips = (False, True) if views in (2, 8) else (False,)
    turns = range(4) if views in (4, 8) else range(1)
    return [(f, k) for f in flips for k in turns]


def _view(x: np.ndarray, flip: bool, k: int) -> np.ndarray:
    """Inputs (N, C, H, W) seen mirrored left-right (first), then turned ``k`` quarter turns
    counter-clockwise on screen (the same geometry as :mod:`planner.augment`)."""
    if flip:
        x = x[..., ::-1]
    return np.ascontiguousarray(np.rot90(x, k, axes=(-2, -1)))


def _view_back(y: np.ndarray, flip: bool, k: int) -> np.ndarray:
    """Outputs (N, 5, H, W) of a :func:`_view` mapped back to the original picture: turned back,
    then mirrored back. (cos 2phi, sin 2phi) turn by 2 x the angle: a quarter turn flips both
    signs; a mirror flips the sign of sin 2phi."""
    y = np.rot90(y, -k, axes=(-2, -1))
    if flip:
        y = y[..., ::-1]
    y = np.array(y, dtype=np.float32)
    if k % 2:
        y[:, 0:2] *= -1.0
    if flip:
        y[:, 1] *= -1.0
    return y


def default_device() -> str:
    import torch

    return "cuda" if torch.cuda.is_available() else "cpu"


def load_planner(path: str | Path, device: str = "auto", precision: str = "auto", batch_size: int | None = None,
                 quality_smoothing_px: float = 1.0, views: int = 1, view_spread_k: float = 0.0) -> Planner:
    """Load a checkpoint (:func:`planner.checkpoint.load_checkpoint`) as a :class:`Planner`
    (``views``, ``view_spread_k``: dihedral test-time views, see :meth:`Planner.predict`). With
    an int8 ``precision`` its calibration is read from beside it (:func:`planner.int8.calibration_path`)."""
    from planner.checkpoint import load_checkpoint

    device = default_device() if device == "auto" else device
    precision = checkpoint_precision(path, device, precision)  # a one-line ValueError before any file is read
    model, config, meta = load_checkpoint(path)
    cal = None
    if precision in INT8_PRECISIONS:
        from planner.int8 import calibration_path, read_calibration

        cal = read_calibration(calibration_path(path))
        cal.check(model, str(path))
    return Planner(model, config, device, precision, batch_size, meta, quality_smoothing_px=quality_smoothing_px,
                   views=views, view_spread_k=view_spread_k, int8_calibration=cal)


def checkpoint_precision(path: str | Path, device: str, precision: str = "auto") -> str:
    """The number format the checkpoint at ``path`` runs in on ``device`` ("cpu" or "cuda"):
    ``precision`` itself, or for "auto" :func:`planner.runtime.default_precision`, int8 where an int8
    calibration lies beside the checkpoint (:func:`planner.int8.calibration_path`); a ``ValueError``
    where it cannot run."""
    from planner.int8 import calibration_path

    return resolve_precision(precision, device, int8_calibrated=calibration_path(path).is_file())


def _gaussian(maps: np.ndarray, sigma_px: float) -> np.ndarray:
    """(N, H, W) float32 maps, each blurred with a Gaussian of ``sigma_px`` (reflecting borders)."""
    if sigma_px <= 0:
        return maps
    import cv2

    k = 2 * int(math.ceil(3 * sigma_px)) + 1
    return np.stack([cv2.GaussianBlur(m, (k, k), sigma_px, borderType=cv2.BORDER_REFLECT) for m in maps])


@dataclass(frozen=True)
class PlannedGrasp:
    grasp: Grasp  # pile frame
    quality: float  # q = f(u, tau, b)
    graspability: float  # u
    balance: float  # b
    targets: tuple[int, ...]  # log indices
    pixel: tuple[int, int]  # (row, col)

    def to_dict(self) -> dict:
        return {**self.grasp.to_dict(), "quality": self.quality, "graspability": self.graspability,
                "balance": self.balance, "targets": list(self.targets)}


@dataclass
class Plan:
    grasps: list[PlannedGrasp]  # best first
    subsets_evaluated: int
    elapsed_s: float
    # what the constraints did: {"targets", "constraint": "lift_capacity" | "reach" | "keep_out",
    # "action": "removed" (subset not planned) | "moved" (its best grasp replaced), "detail"}
    rejected: list[dict] = field(default_factory=list)
    info: dict = field(default_factory=dict)  # subset selection, visible logs, ...

    @property
    def best(self) -> PlannedGrasp | None:
        return self.grasps[0] if self.grasps else None

    def to_dict(self) -> dict:
        return {"format": PLAN_FORMAT_NAME, "format_version": PLAN_FORMAT_VERSION,
                "grasps": [g.to_dict() for g in self.grasps], "subsets_evaluated": self.subsets_evaluated,
                "elapsed_s": self.elapsed_s, "rejected": self.rejected, "info": self.info}

    def to_json(self) -> str:
        from synth.common.files import dumps_json

        return dumps_json(self.to_dict())


def observation_arrays(observation) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """An observation's checked planner inputs: intensity (first render), depth [m] and instance
    masks as (H, W) arrays, its extent [m] and camera height [m]; :class:`ObservationError` for
    arrays of other shapes or depth with holes."""
    inten = np.asarray(observation.intensity, dtype=np.float32)
    if inten.ndim == 3:
        inten = inten[0]  # first render (the pile's own colours)
    depth = np.asarray(observation.depth, dtype=np.float32)
    inst = np.asarray(observation.instance)
    if depth.ndim != 2 or depth.shape[0] != depth.shape[1]:
        raise ObservationError(f"depth must be a square (H, W) image, got shape {depth.shape}")
    if inten.shape != depth.shape or inst.shape != depth.shape:
        raise ObservationError(f"intensity {inten.shape}, depth {depth.shape} and instance {inst.shape} differ in size")
    if not np.isfinite(depth).all():
        n = int((~np.isfinite(depth)).sum())
        raise ObservationError(f"depth has {n} NaN/inf pixels; fill holes (e.g. stereo dropouts) before planning")
    if not np.isfinite(inten).all():
        raise ObservationError("intensity has NaN/inf pixels; fix the image before planning")
    return inten, depth, inst, float(getattr(observation, "extent_m", 5.0)), float(getattr(observation, "camera_height_m", 5.0))


def check_grid(size_px: int, extent_m: float, cfg) -> None:
    """Raise :class:`ObservationError` unless an observation of ``size_px`` pixels over ``extent_m``
    metres suits the network of ``cfg`` (a :class:`planner.model.UNetConfig`): the network knows
    logs at its training images' pixel pitch (``cfg.pixel_m``), so the observation must have that
    pitch (within 0.5 %); a larger patch is fine with more pixels, a multiple of ``2**cfg.depth``
    (the U-Net's pooling)."""
    pitch = extent_m / size_px
    if abs(pitch / cfg.pixel_m - 1.0) > 0.005:
        raise ObservationError(
            f"the observation has {100 * pitch:.2f} cm pixels ({size_px} px over {extent_m:g} m) but the network was "
            f"trained on {100 * cfg.pixel_m:.2f} cm pixels ({cfg.size_px} px over {cfg.extent_m:g} m): logs would look "
            f"{'smaller' if pitch > cfg.pixel_m else 'larger'} than they are; render at the network's pitch "
            f"({round(extent_m / cfg.pixel_m)} px over {extent_m:g} m)")
    if size_px % (2 ** cfg.depth):
        raise ObservationError(f"the observation is {size_px} px, not a multiple of {2 ** cfg.depth} (the network's "
                               f"{cfg.depth} poolings); render a patch of a multiple of {2 ** cfg.depth} pixels")


def _smoothing_window(shape: tuple[int, int], r: int, c: int, sigma: float):
    """The Gaussian weights of ``sigma`` [px] around pixel (r, c), cut at the image border (radius
    ``ceil(2 sigma)``), and the window's slices: ``(w * img[win]).sum() / w.sum()`` is img smoothed
    at (r, c)."""
    k = max(1, int(math.ceil(2 * sigma)))
    r0, r1, c0, c1 = max(0, r - k), min(shape[0], r + k + 1), max(0, c - k), min(shape[1], c + k + 1)
    dr = (np.arange(r0, r1) - r)[:, None]
    dc = (np.arange(c0, c1) - c)[None, :]
    w = np.exp(-(dr ** 2 + dc ** 2) / (2 * sigma ** 2))
    return w, (slice(r0, r1), slice(c0, c1))


def plan(observation, planner: Planner, objective: Objective = Objective(), constraints: Constraints = Constraints(),
         top_k: int | None = None, *, subsets: SubsetPolicy = SubsetPolicy(), pile=None) -> Plan:
    """Plan multi-log grasps on ``observation`` (an :class:`synth.render.ortho.OrthoObservation` or any
    object with ``intensity`` (H, W) or (R, H, W), ``depth`` (H, W) [m], ``instance`` (H, W),
    ``extent_m``, ``camera_height_m``).

    Returns the best grasp of each evaluated subset, best first (``top_k`` of them, all if None).
    ``pile`` (a :class:`synth.scene.pile.PileSpec`), when known, gives exact log volumes for the lift
    capacity. Raises :class:`ObservationError` for unusable input."""
    t0 = time.perf_counter()
    inten, depth, inst, extent_m, cam_h = observation_arrays(observation)
    cfg = planner.config
    check_grid(depth.shape[0], extent_m, cfg)
    grid = OrthoGrid(depth.shape[0], extent_m)
    codes, counts = np.unique(inst[(inst > 0) & (inst < OBSTACLE_CODE_BASE)], return_counts=True)
    if len(codes) == 0:
        raise ObservationError("the observation shows no logs (no instance codes 1..999); nothing to grasp")
    visible = {int(c) - 1: int(n) for c, n in zip(codes, counts)}
    masks = {i: inst == i + 1 for i in visible}
    try:
        chosen, info = choose_subsets(masks, grid.pixel_m, subsets)
    except ValueError as exc:
        raise ObservationError(str(exc)) from exc
    info = {**info, "visible_logs": sorted(visible)}
    rejected: list[dict] = []

    if constraints.lift_capacity_kg is not None:
        masses = constraints.log_masses_kg(visible, grid.pixel_m, pile)
        info["log_mass_kg"] = {str(i): round(m, 1) for i, m in masses.items()}
        info["log_mass_source"] = "pile volumes" if pile is not None else "mask area x assumed diameter"
        kept = []
        for s in chosen:
            m = sum(masses[i] for i in s)
            if m > constraints.lift_capacity_kg:
                rejected.append({"targets": list(s), "constraint": "lift_capacity", "action": "removed",
                                 "detail": f"{m:.0f} kg > {constraints.lift_capacity_kg:.0f} kg"})
            else:
                kept.append(s)
        chosen = kept

    grasps: list[PlannedGrasp] = []
    if chosen:
        subset_masks = np.stack([np.any([masks[i] for i in s], axis=0) for s in chosen])
        x = make_inputs(inten, depth, subset_masks, cfg.in_channels, cam_h)
        out = planner.predict(x)
        b_maps = None
        if objective.kind == "f3" and objective.balance == "hang":
            masses = constraints.log_masses_kg(visible, grid.pixel_m, pile)
            loads_kg = [sum(masses[i] for i in s) for s in chosen]
            b_maps = objective.hang.cos_beta_maps(subset_masks, grid.pixel_m, loads_kg)
        obstacles = (inst >= OBSTACLE_CODE_BASE) if constraints.clear_obstacles else None
        grasps, more = _select(out, chosen, grid, objective, constraints, planner, b_maps,
                               obstacles if obstacles is not None and obstacles.any() else None)
        rejected += more
    grasps.sort(key=lambda g: -g.quality)
    if top_k is not None:
        grasps = grasps[:top_k]
    return Plan(grasps, len(chosen), time.perf_counter() - t0, rejected, info)


def _u_maps(out: np.ndarray, planner: Planner) -> np.ndarray:
    """U of each subset's network output ``out`` (N, 5, H, W), smoothed as planning scores it."""
    return _gaussian((1.0 / (1.0 + np.exp(-out[:, 3]))).astype(np.float32), planner.quality_smoothing_px)


def _b_maps(out: np.ndarray, planner: Planner) -> np.ndarray:
    """The network's balance cos(beta) of each subset's output, smoothed as planning scores it."""
    return _gaussian(np.ascontiguousarray(decode_balance(out[:, 4], planner.config.b_encoding), dtype=np.float32),
                     planner.quality_smoothing_px)


def _select(out, chosen, grid, objective, constraints, planner, b_maps: np.ndarray | None = None,
            obstacles: np.ndarray | None = None) -> tuple[list[PlannedGrasp], list[dict]]:
    """Each subset's best grasp (the highest-quality pixel in reach whose rectangle misses the
    keep-out zones and the ``obstacles`` pixels; of equal pixels the first in raster order) and what the
    constraints did; the balance is ``b_maps`` where given, else the network's B map."""
    u = _u_maps(out, planner)
    b = b_maps if b_maps is not None else _b_maps(out, planner)
    tau = np.array([len(s) for s in chosen], np.float32)[:, None, None]
    q = objective.quality(u, tau, b)
    n, h, w = q.shape
    flat = q.reshape(n, h * w)
    reach = constraints.reach_ok(grid)
    footprints = {"keep_out": (0.0, RECT_WIDTH_M), "obstacle": (constraints.claw_plate_m, constraints.claw_width_m)}
    blocks = [(name, r, np.column_stack(grid.pixel_to_pile(*np.nonzero(r))), footprints[name])
              for name, r in (("keep_out", constraints.keep_out_raster(grid)), ("obstacle", obstacles)) if r is not None]
    best_any = np.argmax(flat, axis=1)
    if reach is not None:
        flat = np.where(reach.ravel(), flat, -np.inf)
    best = np.argmax(flat, axis=1)  # all subsets at once
    n_try = min(planner.candidates_per_subset, h * w) if blocks else 1
    grasps, rejected = [], []
    for k, s in enumerate(chosen):
        qk = flat[k]
        if reach is not None:
            if not np.isfinite(qk[best[k]]):
                rejected.append({"targets": list(s), "constraint": "reach", "action": "removed",
                                 "detail": "no pixel within reach"})
                continue
            if best[k] != best_any[k]:
                rejected.append({"targets": list(s), "constraint": "reach", "action": "moved",
                                 "detail": "best grasp out of reach; best in reach used"})
        picked, first_block = None, None
        for idx in _candidate_pixels(qk, int(best[k]), n_try):
            if not np.isfinite(qk[idx]):
                break
            g = _decode(out[k], int(idx) // w, int(idx) % w, grid, planner.angle_smoothing_px)
            block = _blocked(g, grid, blocks)
            if block is not None:
                first_block = first_block or block
                continue
            picked = (int(idx), g)
            break
        if picked is None:
            rejected.append({"targets": list(s), "constraint": first_block or "keep_out", "action": "removed",
                             "detail": f"the best {n_try} grasps all overlap a keep-out zone or an obstacle"})
            continue
        idx, g = picked
        if first_block is not None:
            rejected.append({"targets": list(s), "constraint": first_block, "action": "moved",
                             "detail": f"best grasp overlaps {_BLOCK_WORDS[first_block]}; next best used"})
        r, c = idx // w, idx % w
        grasps.append(PlannedGrasp(g, float(q[k, r, c]), float(u[k, r, c]), float(b[k, r, c]), tuple(s), (r, c)))
    return grasps, rejected


_BLOCK_WORDS = {"keep_out": "a keep-out zone", "obstacle": "an obstacle the observation shows"}


def _blocked(g: Grasp, grid: OrthoGrid, blocks: list[tuple[str, np.ndarray, np.ndarray, tuple[float, float]]]
             ) -> str | None:
    """The first of ``blocks`` ((name, (H, W) raster, (N, 2) pile-frame centres of its set pixels, footprint)) that
    grasp ``g``'s footprint overlaps, or None. A footprint (plate, across) [m] is the opening extended by ``plate``
    past each end, ``across`` wide (:meth:`Grasp.footprint`). It is rasterised only for a block with a pixel centre
    within its circumradius and two pixels of its centre: no pixel farther away can be one it touches."""
    rects: dict[tuple[float, float], np.ndarray] = {}
    for name, r, xy, (plate_m, across_m) in blocks:
        reach_m = math.hypot(g.width_m / 2 + plate_m, across_m / 2) + 2 * grid.pixel_m
        if not len(xy) or np.min(np.hypot(xy[:, 0] - g.x_m, xy[:, 1] - g.y_m)) > reach_m:
            continue
        if (plate_m, across_m) not in rects:
            rects[(plate_m, across_m)] = polygon_raster(grid, g.footprint(plate_m, across_m)).astype(bool)
        if (rects[(plate_m, across_m)] & (r > 0)).any():
            return name
    return None


def _candidate_pixels(qk: np.ndarray, first: int, n: int):
    """The pixels a subset's grasp is tried at, best first: ``first`` (its arg-max), then, only if asked
    for more, the rest of its ``n`` best (:func:`_best_pixels`)."""
    yield first
    if n > 1:
        yield from (int(i) for i in _best_pixels(qk, n)[1:])


def _best_pixels(qk: np.ndarray, n: int) -> np.ndarray:
    """Indices of the ``n`` highest values of ``qk`` (< its length), best first, equal values in
    raster order."""
    top = np.argpartition(-qk, n - 1)[:n]
    return top[np.lexsort((top, -qk[top]))]


def _decode(maps: np.ndarray, r: int, c: int, grid: OrthoGrid, sigma: float) -> Grasp:
    """The grasp at pixel (r, c) of one subset's network output ``maps`` (5, H, W): C, S and W
    smoothed there with a Gaussian of ``sigma`` [px] (0: the pixel's own values)."""
    if sigma > 0:
        w, win = _smoothing_window(maps.shape[1:], r, c, sigma)
        w_sum = w.sum()
        cs, sn, width = (float((w * maps[i][win]).sum() / w_sum) for i in range(3))
    else:
        cs, sn, width = (float(maps[i, r, c]) for i in range(3))
    x, y = grid.pixel_to_pile(r, c)
    return Grasp(float(x), float(y), float(wrap_phi(math.atan2(sn, cs) / 2.0)),
                 float(np.clip(width, MIN_WIDTH_M, MAX_WIDTH_M)))


def u_at(observation, planner: Planner, grasps: list[Grasp], targets: list[tuple[int, ...]]) -> np.ndarray:
    """The network's U (smoothed as planning smooths it) at each grasp's centre, each on its own
    target subset's maps: how the network of ``planner`` scores grasps it did not necessarily
    choose (e.g. another model's tried grasps, for a paired ranking comparison)."""
    return maps_at(observation, planner, grasps, targets)[0]


def maps_at(observation, planner: Planner, grasps: list[Grasp],
            targets: list[tuple[int, ...]]) -> tuple[np.ndarray, np.ndarray]:
    """(U, b) at each grasp's centre on its own target subset's maps, both smoothed as planning
    smooths them; b is the balance cos(beta) whatever the network's B encoding."""
    if len(grasps) != len(targets):
        raise ObservationError(f"{len(grasps)} grasps but {len(targets)} target subsets")
    inten, depth, inst, extent_m, cam_h = observation_arrays(observation)
    check_grid(depth.shape[0], extent_m, planner.config)
    grid = OrthoGrid(depth.shape[0], extent_m)
    subsets = sorted({tuple(sorted(t)) for t in targets})
    masks = np.stack([np.isin(inst, [i + 1 for i in s]) for s in subsets])
    out = planner.predict(make_inputs(inten, depth, masks, planner.config.in_channels, cam_h))
    u = _u_maps(out, planner)
    b = _b_maps(out, planner)
    row_of = {s: k for k, s in enumerate(subsets)}
    at = np.empty((2, len(grasps)))
    for j, (g, t) in enumerate(zip(grasps, targets)):
        r, c = (int(np.clip(round(float(v)), 0, depth.shape[0] - 1)) for v in grid.pile_to_pixel(g.x_m, g.y_m))
        at[:, j] = u[row_of[tuple(sorted(t))], r, c], b[row_of[tuple(sorted(t))], r, c]
    return at[0], at[1]
