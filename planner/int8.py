"""The planning U-Net in int8 on the CPU: post-training static quantization (opt-in precision
``"int8"``, :mod:`planner.runtime`).

Every 3x3 convolution runs as one oneDNN int8 call, ``torch.ops.onednn.qconv2d_pointwise`` (the
kernel ``torch.compile``'s x86 quantization lowers to, here called directly: no compiler at run
time): uint8 activations x int8 weights (AVX512-VNNI where the CPU has it), the folded BatchNorm's
bias and the ReLU applied to the fp32 accumulator, the result requantized to uint8.

* **Weights**: symmetric int8 per output channel (scale = max |w| / 127), computed at load from the
  fp32 weights (BatchNorm folded), deterministic.
* **Activations**: uint8 per tensor, from the ranges recorded by :func:`calibrate` on real inputs
  (:class:`Int8Calibration`, a versioned JSON file beside the weights that names their hash).
  Where a skip connection and the transposed convolution's output are concatenated, both are
  written in the concatenation's scale (the union of their ranges) so that the concatenation is
  a plain copy of bytes.
* **Input** (intensity, height, mask): one uint8 tensor with one zero point and a scale per channel,
  folded into the first convolution's weights (padding stays a true zero).
* **Transposed convolutions** (2x2, stride 2) run as the equivalent 1x1 int8 convolution to 4x the
  channels, put in place by the copy that concatenates; **max pooling** on uint8 is exact.
* **Kept in float**: the last decoder convolution writes fp32 (no requantization) and the 1x1 head
  and its activations (cos 2phi, sin 2phi, width, U, B) run in fp32, as in the bf16 path.
  Precision ``"int8-bf16-top"`` (``float_top``) also keeps the full-resolution level in bf16 (the
  encoder's first block and the decoder's last, 21 % of the operations): there the
  activations' ranges are widest against their detail, and quantizing them doubled the error of
  the U logit (docs/model.md, "int8").

Only ``mask_injection = "input"`` networks are supported (the shipped one).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from planner.errors import CheckpointError
from synth.common.formats import VersionedJson

INT8_CALIBRATION = VersionedJson(
    "loggrasp.planner.int8-calibration", "1.0", "int8 calibration", CheckpointError,
    fix="calibrate the checkpoint again with this loggrasp (python -m experiments.int8_calibration --model M)",
    unreadable_fix="calibrate the checkpoint (python -m experiments.int8_calibration --model M)")
CALIBRATION_SUFFIX = ".int8.json"  # beside the checkpoint: default.safetensors -> default.int8.json
UINT8_MAX = 255  # largest uint8 code [-]
INT8_MAX = 127  # largest symmetric int8 weight code [-]
CLIP_QUANTILE = 0.99999  # an activation's range: these quantiles of its values (1.0: min/max) [-]; fake-quantized
#                          on 2 x 16 masks of other piles the U logit's mean error was 0.040 against min/max's 0.048
VALUES_PER_BATCH = 200_000  # activation values drawn per calibration batch and point for the quantiles [-]
_QUANTILE_MAX_VALUES = 16_000_000  # torch.quantile's input limit [-]


def calibration_path(checkpoint: str | Path) -> Path:
    """Where a checkpoint's int8 calibration lives: beside it, ``<stem>.int8.json``."""
    checkpoint = Path(checkpoint)
    return checkpoint.with_name(checkpoint.stem + CALIBRATION_SUFFIX)


def weights_sha256(model) -> str:
    """sha256 over a model's state dict (names, dtypes, shapes and bytes, in name order): which
    weights a calibration belongs to."""
    h = hashlib.sha256()
    for name, t in sorted(model.state_dict().items()):
        t = t.detach().cpu().contiguous()
        h.update(f"{name}:{t.dtype}:{tuple(t.shape)};".encode())
        h.update((t.float() if t.dtype.is_floating_point else t).numpy().tobytes())
    return h.hexdigest()


@dataclass(frozen=True)
class Int8Calibration:
    """Activation ranges of one network's weights, recorded on real inputs."""

    weights_sha256: str  # :func:`weights_sha256` of the network calibrated
    input_ranges: tuple[tuple[float, float], ...]  # (min, max) of each input channel (I, D, M_T) [input units]
    ranges: dict = field(default_factory=dict)  # activation point name -> (low, high) of its fp32 values (the
    #                                             1 - q and q quantiles, :func:`calibrate`) [-]
    meta: dict = field(default_factory=dict)  # how it was made: stores, samples, seed

    def __post_init__(self) -> None:
        for name, (lo, hi) in list(self.ranges.items()) + list(enumerate(self.input_ranges)):
            if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
                raise ValueError(f"calibration range of {name} must be finite with min <= max, got ({lo}, {hi})")

    def check(self, model, where: str = "the model") -> None:
        """:class:`CheckpointError` unless this calibration was made for ``model``'s weights."""
        have = weights_sha256(model)
        if have != self.weights_sha256:
            raise CheckpointError(f"the int8 calibration was made for weights {self.weights_sha256[:12]}, not for "
                                  f"{where} ({have[:12]}); calibrate it again (python -m experiments.int8_calibration)")


def write_calibration(path: str | Path, cal: Int8Calibration) -> Path:
    body = {"weights_sha256": cal.weights_sha256, "input_ranges": [list(r) for r in cal.input_ranges],
            "ranges": {k: list(v) for k, v in sorted(cal.ranges.items())}, "meta": cal.meta}
    return INT8_CALIBRATION.write(path, body)


def read_calibration(path: str | Path) -> Int8Calibration:
    """An :class:`Int8Calibration` file; :class:`CheckpointError` when it is missing, corrupt,
    foreign, of another major version or malformed."""
    d = INT8_CALIBRATION.read(path)
    try:
        return Int8Calibration(str(d["weights_sha256"]), tuple((float(a), float(b)) for a, b in d["input_ranges"]),
                               {str(k): (float(v[0]), float(v[1])) for k, v in d["ranges"].items()},
                               dict(d.get("meta", {})))
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise CheckpointError(f"{path}: not a valid int8 calibration ({exc}); calibrate the checkpoint again") from exc


# ---------------------------------------------------------------------------------------------
# calibration: the fp32 network's activations, walked in the int8 network's order
# ---------------------------------------------------------------------------------------------
def _blocks(folded):
    """(conv_a, conv_b) of each folded block (Conv2d, ReLU, Conv2d, ReLU): encoder then decoder."""
    return [(b[0], b[2]) for b in folded.down], [(b[0], b[2]) for b in folded.dec]


def float_walk(folded, x, record=None):
    """The folded fp32 network's output for ``x``, calling ``record(name, tensor)`` at every point
    the int8 network quantizes (the names of :attr:`Int8Calibration.ranges`)."""
    import torch
    import torch.nn.functional as F

    record = record or (lambda name, t: None)
    down, dec = _blocks(folded)
    feats = []
    for i, (a, b) in enumerate(down):
        x = F.relu(a(x if i == 0 else F.max_pool2d(x, 2)))
        record(f"down{i}.a", x)
        x = F.relu(b(x))
        record(f"down{i}.b", x)
        feats.append(x)
    x = feats.pop()
    for j, (up, (a, b)) in enumerate(zip(folded.up, dec)):
        u = up(x)
        record(f"up{j}", u)
        x = F.relu(a(torch.cat([u, feats.pop()], dim=1)))
        record(f"dec{j}.a", x)
        x = F.relu(b(x))
        if j < len(dec) - 1:
            record(f"dec{j}.b", x)
    return folded.finish(x)


def calibrate(model, inputs, meta: dict | None = None, clip_quantile: float = CLIP_QUANTILE,
              values_per_batch: int = VALUES_PER_BATCH, seed: int = 0) -> Int8Calibration:
    """Record the ranges of ``model``'s activations on ``inputs`` (an iterable of float32 arrays
    (N, C, H, W) as :func:`planner.data.make_inputs` makes them): per point, the ``clip_quantile``
    and ``1 - clip_quantile`` quantiles of ``values_per_batch`` values drawn per batch (generator
    seeded with ``seed``: the same inputs give the same file). The input's ranges are its min/max."""
    import torch

    from planner.model import fold_batch_norm

    _check_supported(model.config)
    if not 0.5 < clip_quantile <= 1.0:
        raise ValueError(f"clip_quantile must be in (0.5, 1], got {clip_quantile}")
    folded = fold_batch_norm(model)
    drawn: dict[str, list] = {}
    gen = torch.Generator().manual_seed(seed)
    in_lo = in_hi = None

    def record(name, t):
        v = t.reshape(-1)
        drawn.setdefault(name, []).append(v[torch.randint(0, v.numel(), (min(v.numel(), values_per_batch),),
                                                          generator=gen)].clone())

    n = 0
    with torch.inference_mode():
        for batch in inputs:
            x = torch.from_numpy(np.ascontiguousarray(batch, dtype=np.float32))
            lo, hi = x.amin(dim=(0, 2, 3)).numpy(), x.amax(dim=(0, 2, 3)).numpy()
            in_lo = lo if in_lo is None else np.minimum(in_lo, lo)
            in_hi = hi if in_hi is None else np.maximum(in_hi, hi)
            float_walk(folded, x, record)
            n += len(x)
    if not n:
        raise ValueError("calibrate needs at least one input sample")
    ranges = {}
    for name, parts in drawn.items():
        v = torch.cat(parts)[:_QUANTILE_MAX_VALUES]
        qs = torch.quantile(v, torch.tensor([1.0 - clip_quantile, clip_quantile]))
        ranges[name] = (float(qs[0]), float(qs[1]))
    return Int8Calibration(weights_sha256(model), tuple((float(a), float(b)) for a, b in zip(in_lo, in_hi)), ranges,
                           {**(meta or {}), "samples": n, "clip_quantile": clip_quantile,
                            "values_per_batch": values_per_batch, "seed": seed})


def _check_supported(config) -> None:
    if config.mask_injection != "input":
        raise ValueError("int8 planning supports mask_injection='input' networks only; use precision 'bf16'")


# ---------------------------------------------------------------------------------------------
# quantization parameters and the int8 network
# ---------------------------------------------------------------------------------------------
def act_qparams(lo: float, hi: float) -> tuple[float, int]:
    """(scale, zero point) of uint8 codes covering [lo, hi] (widened to hold 0, exactly)."""
    lo, hi = min(lo, 0.0), max(hi, 0.0)
    span = max(hi - lo, 1e-8)
    scale = span / UINT8_MAX
    return scale, int(round(-lo / scale))


def input_qparams(ranges) -> tuple[np.ndarray, int]:
    """(per-channel scales, shared zero point) of the uint8 input: 0 is exact in every channel."""
    lo = np.minimum([r[0] for r in ranges], 0.0)
    hi = np.maximum([r[1] for r in ranges], 0.0)
    zp = int(round(UINT8_MAX * float(np.max(-lo / np.maximum(hi - lo, 1e-8)))))
    scales = np.maximum(hi / max(UINT8_MAX - zp, 1), np.where(lo < 0, -lo / max(zp, 1), 0.0))
    return np.maximum(scales, 1e-8).astype(np.float32), zp


class _QConv:
    """One convolution as a oneDNN int8 call: uint8 in (``x_scale``, ``x_zp``), int8 weights per
    output channel, fp32 bias, optional ReLU, out as uint8 (``out``: (scale, zp)) or as float
    (``out``: a torch dtype, fp32 or bf16).
    The weights are packed for inputs of ``x_shape`` (N, C, H, W); other shapes give the same
    numbers, but oneDNN may pick a slower kernel (a 1x1 convolution at 8 x 8 px packed without the
    shape took 6.6 ms a pass instead of 0.7)."""

    def __init__(self, weight, bias, x_scale: float, x_zp: int, out, relu: bool, x_shape: list[int]) -> None:
        import torch

        w = weight.detach().float()
        self.w_scale = (w.abs().amax(dim=(1, 2, 3)) / INT8_MAX).clamp_min(1e-12).contiguous()
        w_q = torch.clamp(torch.round(w / self.w_scale[:, None, None, None]), -INT8_MAX, INT8_MAX).to(torch.int8)
        self.pad = [weight.shape[-1] // 2] * 2
        self.packed = torch.ops.onednn.qconv_prepack(w_q, self.w_scale, float(x_scale), int(x_zp), [1, 1], self.pad,
                                                     [1, 1], 1, x_shape)
        self.w_zp = torch.zeros(w.shape[0], dtype=torch.int64)
        self.bias = None if bias is None else bias.detach().float().contiguous()
        self.x_scale, self.x_zp, self.relu = float(x_scale), int(x_zp), relu
        self.out = out

    def __call__(self, x):
        import torch

        o_scale, o_zp, o_dtype = ((1.0, 0, self.out) if isinstance(self.out, torch.dtype) else
                                  (float(self.out[0]), int(self.out[1]), None))
        return torch.ops.onednn.qconv2d_pointwise(x, self.x_scale, self.x_zp, self.packed, self.w_scale, self.w_zp,
                                                  self.bias, [1, 1], self.pad, [1, 1], 1, o_scale, o_zp, o_dtype,
                                                  "relu" if self.relu else "none", [], "")


def _pool_u8(x):
    """2x2 max pooling of a uint8 (N, C, H, W) tensor (exact; torch's max_pool2d has no uint8 kernel)."""
    import torch

    a = torch.maximum(x[:, :, 0::2, :], x[:, :, 1::2, :])
    return torch.maximum(a[:, :, :, 0::2], a[:, :, :, 1::2])


def _up_as_1x1(up):
    """A 2x2 stride-2 ConvTranspose2d as the weight and bias of a 1x1 convolution to 4x the
    channels, output channel ``(2 a + b) cout + c`` holding output channel c at the sub-pixel
    (a, b) (:func:`_unshuffle_cat` puts them in place)."""
    w = up.weight.detach().float()  # (cin, cout, 2, 2)
    cin, cout = w.shape[:2]
    w1 = w.permute(2, 3, 1, 0).reshape(4 * cout, cin, 1, 1).contiguous()
    b1 = None if up.bias is None else up.bias.detach().float().repeat(4)
    return w1, b1


def _unshuffle_cat(u, skip):
    """The transposed convolution's output from its 1x1 form ``u`` (N, 4C, h, w), concatenated
    with ``skip`` (N, Cs, 2h, 2w) along the channels: (N, C + Cs, 2h, 2w) channels-last, written
    with one copy of each (both channels-last uint8)."""
    import torch

    n, c4, h, w = u.shape
    c, cs = c4 // 4, skip.shape[1]
    out = torch.empty((n, 2 * h, 2 * w, c + cs), dtype=u.dtype)  # NHWC storage
    sub = out.view(n, h, 2, w, 2, c + cs)  # (n, i, a, j, b, channel): pixel (2i + a, 2j + b)
    u_sub = u.permute(0, 2, 3, 1).view(n, h, w, 2, 2, c)  # (n, i, j, a, b, channel)
    for a in range(2):
        for b in range(2):  # four copies of contiguous channel runs: faster than one 6-d strided copy
            sub[:, :, a, :, b, :c].copy_(u_sub[:, :, :, a, b])
    out[..., c:].copy_(skip.permute(0, 2, 3, 1))
    return out.permute(0, 3, 1, 2)


class _FConv:
    """A convolution + ReLU in float (bf16 where oneDNN has bf16 kernels, else fp32) as one oneDNN
    call, for the levels kept out of int8 (:func:`build_int8`'s ``float_top``)."""

    def __init__(self, weight, bias, dtype) -> None:
        import torch

        self.weight = weight.detach().to(dtype).contiguous(memory_format=torch.channels_last)
        self.bias = None if bias is None else bias.detach().to(dtype)
        self.pad = [weight.shape[-1] // 2] * 2

    def __call__(self, x):
        import torch

        return torch.ops.mkldnn._convolution_pointwise(x, self.weight, self.bias, self.pad, [1, 1], [1, 1], 1,
                                                       "relu", [], "")


def build_int8(model, cal: Int8Calibration, batch_size: int = 16, float_top: bool = False):
    """The int8 inference network of ``model`` (an fp32 :func:`planner.model.build_unet` network)
    with calibration ``cal`` (checked against its weights). Its ``forward`` takes the fp32 input
    (N, C, H, W) and returns the fp32 outputs of :meth:`UNet.finish`. Its kernels are chosen for
    ``batch_size`` inputs of the network's ``size_px`` (:class:`_QConv`). With ``float_top`` the
    full-resolution level (the encoder's first block, the decoder's last; 21 % of the operations)
    runs in bf16: the transposed convolution into it stays int8 with a bf16 output."""
    import torch
    from torch import nn

    from planner.model import fold_batch_norm

    _check_supported(model.config)
    cal.check(model)
    folded = fold_batch_norm(model)
    down, dec = _blocks(folded)
    if len(cal.input_ranges) != model.config.in_channels:
        raise CheckpointError(f"the int8 calibration has {len(cal.input_ranges)} input channels, the network "
                              f"{model.config.in_channels}; calibrate it again")
    missing = [k for k in _point_names(len(down)) if k not in cal.ranges]
    if missing:
        raise CheckpointError(f"the int8 calibration lacks the ranges of {missing[:3]}; calibrate it again")
    q = {k: act_qparams(*v) for k, v in cal.ranges.items()}
    pool0 = q["down0.b"]  # with float_top: the pooled first level's own codes
    depth = len(down) - 1
    for j in range(depth - int(float_top)):  # a skip and the transposed convolution's output share the
        lo = min(cal.ranges[f"up{j}"][0], cal.ranges[f"down{depth - 1 - j}.b"][0])  # concatenation's codes
        hi = max(cal.ranges[f"up{j}"][1], cal.ranges[f"down{depth - 1 - j}.b"][1])
        q[f"up{j}"] = q[f"down{depth - 1 - j}.b"] = act_qparams(lo, hi)
    in_scales, in_zp = input_qparams(cal.input_ranges)
    side = model.config.size_px
    fdt = torch.bfloat16 if torch.ops.mkldnn._is_mkldnn_bf16_supported() else torch.float32

    def shape(conv, level: int) -> list[int]:
        return [batch_size, conv.weight.shape[1], side >> level, side >> level]

    class Int8UNet(nn.Module):
        late = False

        def __init__(self) -> None:
            super().__init__()
            self.config = model.config
            self.float_net = folded  # its head and finish() run in fp32
            self.float_top = float_top
            self.in_inv_scale = torch.from_numpy(1.0 / in_scales).view(1, -1, 1, 1)
            self.in_zp = in_zp
            self.pool0_inv_scale = 1.0 / pool0[0]
            a0, b0 = down[0]
            w0 = a0.weight.detach().float() * torch.from_numpy(in_scales).view(1, -1, 1, 1)
            self.down = [(_FConv(a0.weight, a0.bias, fdt), _FConv(b0.weight, b0.bias, fdt)) if float_top else
                         (_QConv(w0, a0.bias, 1.0, in_zp, q["down0.a"], True, shape(a0, 0)),
                          _QConv(b0.weight, b0.bias, *q["down0.a"], q["down0.b"], True, shape(b0, 0)))]
            for i, (a, b) in enumerate(down[1:], start=1):
                self.down.append((_QConv(a.weight, a.bias, *q[f"down{i - 1}.b"], q[f"down{i}.a"], True, shape(a, i)),
                                  _QConv(b.weight, b.bias, *q[f"down{i}.a"], q[f"down{i}.b"], True, shape(b, i))))
            self.up, self.dec = [], []
            prev = q[f"down{depth}.b"]
            for j, (up, (a, b)) in enumerate(zip(folded.up, dec)):
                w1, b1 = _up_as_1x1(up)
                level, last = depth - 1 - j, j == depth - 1
                lower = [batch_size, w1.shape[1], side >> (level + 1), side >> (level + 1)]
                if last and float_top:
                    self.up.append(_QConv(w1, b1, *prev, fdt, False, lower))
                    self.dec.append((_FConv(a.weight, a.bias, fdt), _FConv(b.weight, b.bias, fdt)))
                    break
                self.up.append(_QConv(w1, b1, *prev, q[f"up{j}"], False, lower))
                self.dec.append((_QConv(a.weight, a.bias, *q[f"up{j}"], q[f"dec{j}.a"], True, shape(a, level)),
                                 _QConv(b.weight, b.bias, *q[f"dec{j}.a"], torch.float32 if last else q[f"dec{j}.b"],
                                        True, shape(b, level))))
                prev = q[f"dec{j}.b"] if not last else None

        def quantize_input(self, x):
            y = torch.round(x.float() * self.in_inv_scale).add_(self.in_zp).clamp_(0, UINT8_MAX)
            return y.to(torch.uint8).contiguous(memory_format=torch.channels_last)

        def pool_top(self, x):
            """The bf16 first level pooled into the second level's uint8 codes."""
            y = torch.max_pool2d(x, 2).float().mul_(self.pool0_inv_scale).round_().clamp_(0, UINT8_MAX)
            return y.to(torch.uint8).contiguous(memory_format=torch.channels_last)

        def forward(self, x):
            if self.float_top:
                x = x.to(fdt).contiguous(memory_format=torch.channels_last)
            else:
                x = self.quantize_input(x)
            feats = []
            for i, (a, b) in enumerate(self.down):
                if i:
                    x = self.pool_top(x) if i == 1 and self.float_top else _pool_u8(x)
                x = b(a(x))
                feats.append(x)
            x = feats.pop()
            for up, (a, b) in zip(self.up, self.dec):
                x = b(a(_unshuffle_cat(up(x), feats.pop())))
            return self.float_net.finish(x)

    return Int8UNet().eval()


def _point_names(levels: int) -> list[str]:
    depth = levels - 1
    return ([f"down{i}.{s}" for i in range(levels) for s in "ab"] + [f"up{j}" for j in range(depth)]
            + [f"dec{j}.a" for j in range(depth)] + [f"dec{j}.b" for j in range(depth - 1)])
