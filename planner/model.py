"""The grasp-map network: a U-Net (Ronneberger et al. 2015) from (I, D, M_T) to (C, S, W, U, B).

Inputs (``in_channels`` = 3, see :mod:`planner.data` for the normalisation): intensity in [0, 1],
relative height [m] (see :func:`planner.data.normalise_depth`) and the target mask M_T in {0, 1}.
``in_channels = 2`` is the paper's no-depth ablation (I, M_T).

Outputs, in this order (``OUTPUT_NAMES``), all (N, 5, H, W):

* ``C`` = cos 2phi and ``S`` = sin 2phi: ``tanh`` -> (-1, 1); phi is the pile-frame grasp angle
  (:mod:`synth.geometry.frames`);
* ``W`` opening width [m]: ``sigmoid`` scaled to (``min_width_m``, ``max_width_m``) = (0.30, 1.55);
* ``U`` graspability as a *logit* (train with BCE-with-logits; ``sigmoid`` gives u in (0, 1));
* ``B`` balance, encoded by ``b_encoding`` (:func:`encode_balance` / :func:`decode_balance`):
  ``"cos_beta"`` (the paper's): cos(beta) by ``sigmoid`` -> (0, 1) (the grapple never tips past 90
  degrees) — its training targets span ~0.98-1.0, so its masked MSE is ~1e-4 of the loss and B is
  flat; ``"beta_10deg"``: the tilt beta in units of 10 degrees by ``softplus`` -> (0, inf), a target
  of order 1 whose MSE the loss can see. The checkpoint's config says which; inference decodes
  either to cos(beta) for the objective f3.

Architecture: ``depth`` down-sampling levels of two 3x3 conv + BatchNorm + ReLU, max-pool down,
transposed-conv up, skip concatenation, a 1x1 head. Channels double per level from
``base_channels``. Parameter counts at 3 in / 5 out: base 16 ~1.9 M, base 23 ~4.0 M (default,
the paper's "4.1M parameter UNet"), base 24 ~4.4 M. Image sides must be divisible by 2**depth.

``mask_injection = "decoder"`` (an option, not the paper's design): the encoder sees only (I, D)
and the target mask, area-averaged to each resolution, is concatenated to the bottleneck and to
every decoder stage. Planning then encodes the image once and runs only the decoder per target
subset (:meth:`forward_shared`), which is roughly half of the network's operations. Trained the
same way; the input tensor still carries M_T as its last channel.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Literal

OUTPUT_NAMES = ("C", "S", "W", "U", "B")
B_ENCODINGS = ("cos_beta", "beta_10deg")
_BETA_UNIT_DEG = 10.0  # the unit of beta in the "beta_10deg" encoding [deg]
INPUT_NAMES = {3: ("I", "D", "M_T"), 2: ("I", "M_T")}


@dataclass(frozen=True)
class UNetConfig:
    base_channels: int = 23  # channels of the first level [-]; doubles per level
    depth: int = 4  # number of down-sampling levels [-]
    in_channels: int = 3  # 3 = (I, D, M_T); 2 = (I, M_T) no-depth ablation [-]
    out_channels: int = 5  # (C, S, W, U-logit, B) [-]
    size_px: int = 128  # input image side the network was built/trained for [px]
    extent_m: float = 5.0  # side of the training images [m]; extent_m / size_px is the pixel pitch it knows
    min_width_m: float = 0.30  # W output range low end [m]
    max_width_m: float = 1.55  # W output range high end [m]
    mask_injection: Literal["input", "decoder"] = "input"  # "input": M_T is an input channel (paper); "decoder": see module doc
    b_encoding: Literal["cos_beta", "beta_10deg"] = "cos_beta"  # what the B output means (module doc)

    def __post_init__(self) -> None:
        if not 2 <= self.base_channels <= 256:
            raise ValueError(f"base_channels must be in [2, 256], got {self.base_channels}")
        if not 1 <= self.depth <= 6:
            raise ValueError(f"depth must be in [1, 6], got {self.depth}")
        if self.in_channels not in INPUT_NAMES:
            raise ValueError(f"in_channels must be 3 (I, D, M_T) or 2 (I, M_T), got {self.in_channels}")
        if self.out_channels != len(OUTPUT_NAMES):
            raise ValueError(f"out_channels must be {len(OUTPUT_NAMES)} (C, S, W, U, B), got {self.out_channels}")
        if self.size_px < 16 or self.size_px % (2 ** self.depth):
            raise ValueError(
                f"size_px={self.size_px} must be >= 16 and divisible by 2**depth={2 ** self.depth}; "
                "choose another image size or depth"
            )
        if not 0.5 <= self.extent_m <= 100.0:
            raise ValueError(f"extent_m must be in [0.5, 100] m (the training images' side), got {self.extent_m}")
        if self.b_encoding not in B_ENCODINGS:
            raise ValueError(f"b_encoding must be one of {list(B_ENCODINGS)}, got {self.b_encoding!r}")
        if self.mask_injection not in ("input", "decoder"):
            raise ValueError(f"mask_injection must be 'input' or 'decoder', got {self.mask_injection!r}")
        if not 0 < self.min_width_m < self.max_width_m:
            raise ValueError("need 0 < min_width_m < max_width_m")

    @property
    def pixel_m(self) -> float:
        """The pixel pitch of the training images [m]: observations must have it."""
        return self.extent_m / self.size_px

    @property
    def uses_depth(self) -> bool:
        return self.in_channels == 3

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "UNetConfig":
        from synth.common.configs import config_from_dict

        return config_from_dict(UNetConfig, d)

    @staticmethod
    def tiny(**kw) -> "UNetConfig":
        """A very small network for tests (a few thousand parameters)."""
        base = dict(base_channels=4, depth=2, size_px=32)
        base.update(kw)
        return UNetConfig(**base)


def build_unet(config: UNetConfig):
    """Build the network (imports torch)."""
    import torch
    from torch import nn

    def block(cin: int, cout: int) -> nn.Sequential:
        return nn.Sequential(
            nn.Conv2d(cin, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
            nn.Conv2d(cout, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
        )

    class UNet(nn.Module):
        def __init__(self, cfg: UNetConfig) -> None:
            super().__init__()
            self.config = cfg
            ch = [cfg.base_channels * 2 ** i for i in range(cfg.depth + 1)]
            self.late = cfg.mask_injection == "decoder"
            m = 1 if self.late else 0  # extra mask channel per decoder stage
            cin = cfg.in_channels - m
            self.down = nn.ModuleList([block(cin, ch[0])] + [block(ch[i - 1], ch[i]) for i in range(1, cfg.depth + 1)])
            self.pool = nn.MaxPool2d(2)
            self.up = nn.ModuleList([nn.ConvTranspose2d(ch[i] + (m if i == cfg.depth else 0), ch[i - 1], 2, stride=2)
                                     for i in range(cfg.depth, 0, -1)])
            self.dec = nn.ModuleList([block(2 * ch[i - 1] + m, ch[i - 1]) for i in range(cfg.depth, 0, -1)])
            self.head = nn.Conv2d(ch[0], cfg.out_channels, 1)
            self.w_lo = cfg.min_width_m
            self.w_span = cfg.max_width_m - cfg.min_width_m
            self.b_act = torch.sigmoid if cfg.b_encoding == "cos_beta" else nn.functional.softplus

        def encode(self, x: torch.Tensor) -> list[torch.Tensor]:
            feats = []
            for i, blk in enumerate(self.down):
                x = blk(x if i == 0 else self.pool(x))
                feats.append(x)
            return feats

        def decode(self, feats: list[torch.Tensor], mask: torch.Tensor | None) -> torch.Tensor:
            import torch.nn.functional as F

            skips = list(feats)
            x = skips.pop()
            n = mask.shape[0] if mask is not None else x.shape[0]
            if x.shape[0] != n:
                x = x.expand(n, -1, -1, -1)
            if mask is not None:
                x = torch.cat([x, F.avg_pool2d(mask, 2 ** len(skips)).to(x.dtype)], dim=1)
            for level, (up, dec) in enumerate(zip(self.up, self.dec)):
                skip = skips.pop()
                parts = [up(x), skip if skip.shape[0] == n else skip.expand(n, -1, -1, -1)]
                if mask is not None:
                    k = len(skips)
                    parts.append((F.avg_pool2d(mask, 2 ** k) if k else mask).to(parts[0].dtype))
                x = dec(torch.cat(parts, dim=1))
            return self.finish(x)

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            if self.late:
                return self.decode(self.encode(x[:, :-1]), x[:, -1:])
            return self.decode(self.encode(x), None)

        def forward_shared(self, image: torch.Tensor, masks: torch.Tensor) -> torch.Tensor:
            """Outputs for one image (1, C-1, H, W) and N masks (N, 1, H, W); with decoder
            injection the image is encoded once."""
            if self.late:
                return self.decode(self.encode(image), masks)
            n = masks.shape[0]
            return self.forward(torch.cat([image.expand(n, -1, -1, -1), masks.to(image.dtype)], dim=1))

        def finish(self, x: torch.Tensor) -> torch.Tensor:
            raw = self.head(x.to(self.head.weight.dtype)).float()  # head may stay fp32 in a bf16 body
            raw = raw.contiguous()  # channels-last out of an inference body: the slices below become dense
            c_s = torch.tanh(raw[:, 0:2])
            w = self.w_lo + self.w_span * torch.sigmoid(raw[:, 2:3])
            u_logit = raw[:, 3:4]
            b = self.b_act(raw[:, 4:5])
            return torch.cat([c_s, w, u_logit, b], dim=1)

    return UNet(config)


def encode_balance(cos_beta, encoding: str):
    """cos(beta) -> the B target of ``encoding`` (numpy, element-wise; cos beta clipped to [-1, 1])."""
    import numpy as np

    cb = np.asarray(cos_beta, dtype=np.float32)
    if encoding == "cos_beta":
        return cb
    if encoding == "beta_10deg":
        return (np.degrees(np.arccos(np.clip(cb, -1.0, 1.0))) / _BETA_UNIT_DEG).astype(np.float32)
    raise ValueError(f"b_encoding must be one of {list(B_ENCODINGS)}, got {encoding!r}")


def decode_balance(b, encoding: str):
    """The network's B output of ``encoding`` -> cos(beta) (numpy, element-wise)."""
    import numpy as np

    b = np.asarray(b, dtype=np.float32)
    if encoding == "cos_beta":
        return b
    if encoding == "beta_10deg":
        return np.cos(np.radians(b * _BETA_UNIT_DEG)).astype(np.float32)
    raise ValueError(f"b_encoding must be one of {list(B_ENCODINGS)}, got {encoding!r}")


def count_parameters(model) -> int:
    return sum(p.numel() for p in model.parameters())


def prepare_for_inference(model, precision: str = "bf16", device: str = "cpu"):
    """An inference copy of ``model``: BatchNorm folded into the convolutions, the body in
    bfloat16 (``precision="bf16"``; the 1x1 head stays fp32) and channels-last memory on the CPU.
    Folding and a pure-bf16 body remove the memory-bound BatchNorm and halve the traffic of ReLU,
    pooling and concatenation (about a third less CPU time than fp32-weights + autocast here).
    On the CPU each convolution + ReLU then runs as one oneDNN call with the ReLU as a post-op
    (:func:`fuse_conv_relu`): the same numbers, one pass less over every activation."""
    import torch

    if precision not in ("fp32", "bf16"):
        raise ValueError(f"precision must be 'fp32' or 'bf16', got {precision!r}")
    m = fold_batch_norm(model)
    head = m.head
    if precision == "bf16":
        m = m.to(torch.bfloat16)
        m.head = head.float()
    m = m.to(device)
    if device == "cpu":
        m = m.to(memory_format=torch.channels_last)
        fuse_conv_relu(m)
    return m


def fold_batch_norm(model):
    """An fp32 eval copy of ``model`` on the CPU with every BatchNorm folded into the convolution
    before it: each block becomes (Conv2d, ReLU, Conv2d, ReLU)."""
    import copy

    from torch import nn
    from torch.nn.utils.fusion import fuse_conv_bn_eval

    m = copy.deepcopy(model).eval().cpu().float()
    for mod in m.modules():
        if isinstance(mod, nn.Sequential) and len(mod) == 6 and isinstance(mod[1], nn.BatchNorm2d):
            fused = [fuse_conv_bn_eval(mod[0], mod[1]), mod[2], fuse_conv_bn_eval(mod[3], mod[4]), mod[5]]
            for _ in range(6):
                del mod[0]
            for f in fused:
                mod.append(f)
    return m


def fuse_conv_relu(model) -> int:
    """Replace, in place, every (Conv2d, ReLU) pair inside ``model``'s ``nn.Sequential`` blocks
    (BatchNorm already folded, see :func:`prepare_for_inference`) by one module that runs the
    convolution with the ReLU as a oneDNN post-op (``torch.ops.mkldnn._convolution_pointwise``,
    the kernel ``torch.compile`` uses for the same pattern on the CPU). Results are those of the
    pair (the ReLU is applied to the same accumulator before it is stored); what is saved is the
    second pass over the activation: about 10 % of a plan's CPU time on a 2-core AMD EPYC.
    Returns the number of pairs fused; 0 where torch has no oneDNN, or no oneDNN bf16 kernels for a
    bf16 model (nothing changes)."""
    import torch
    from torch import nn

    if not (torch.backends.mkldnn.is_available() and hasattr(torch.ops.mkldnn, "_convolution_pointwise")):
        return 0
    if (any(p.dtype == torch.bfloat16 for p in model.parameters())
            and not torch.ops.mkldnn._is_mkldnn_bf16_supported()):
        return 0  # oneDNN has no bf16 kernels on this CPU: torch's own (slow) bf16 convolution stays

    class ConvReLU(nn.Module):
        """relu(conv(x)) in one oneDNN call (inference only: no autograd through it)."""

        def __init__(self, conv: nn.Conv2d) -> None:
            super().__init__()
            self.weight, self.bias = conv.weight, conv.bias
            self.args = (list(conv.padding), list(conv.stride), list(conv.dilation), conv.groups)

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            pad, stride, dil, groups = self.args
            return torch.ops.mkldnn._convolution_pointwise(x, self.weight, self.bias, pad, stride, dil, groups,
                                                           "relu", [], "")

    n = 0
    for mod in model.modules():
        if not isinstance(mod, nn.Sequential):
            continue
        layers, out = list(mod), []
        while layers:
            a = layers.pop(0)
            if (isinstance(a, nn.Conv2d) and layers and isinstance(layers[0], nn.ReLU) and a.padding_mode == "zeros"
                    and isinstance(a.padding, tuple)):
                layers.pop(0)
                out.append(ConvReLU(a))
                n += 1
            else:
                out.append(a)
        if len(out) != len(mod):
            for _ in range(len(mod)):
                del mod[0]
            for f in out:
                mod.append(f)
    return n
