"""How the planning network runs: precision by CPU capability, the fused convolution + ReLU, the
batch size, and which of equal pixels a plan picks (planner.runtime, planner.model, planner.inference)."""

import math

import numpy as np
import pytest
import torch
from torch import nn

from planner.constraints import Constraints
from planner.inference import Planner, plan
from planner.model import UNetConfig, build_unet, fuse_conv_relu, prepare_for_inference
from planner.runtime import MASKS_PER_THREAD, default_precision, masks_per_pass, resolve_precision
from planner_helpers import observation

TINY = UNetConfig.tiny()


def test_precision_is_bf16_only_where_the_cpu_has_bf16_dot_products():
    assert default_precision("cpu", {"avx512_bf16": True, "avx512_f": True}) == "bf16"  # this AMD EPYC
    assert default_precision("cpu", {"amx_bf16": True, "avx512_bf16": True}) == "bf16"  # Xeon with AMX
    assert default_precision("cpu", {"amx_bf16": True}) == "bf16"
    # AVX-512 without BF16 (bf16 would be emulated: ~3x slower than fp32) and AVX2 only
    assert default_precision("cpu", {"avx512_f": True, "avx512_bw": True, "avx2": True}) == "fp32"
    assert default_precision("cpu", {"avx2": True, "avx512_bf16": False}) == "fp32"
    assert default_precision("cpu", {}) == "fp32"  # a torch that cannot say: the safe format
    assert default_precision("cuda", {}) == "bf16"


def test_precision_is_int8_only_with_int8_dot_products_a_calibration_and_the_kernels(monkeypatch):
    import planner.runtime as runtime

    monkeypatch.setattr(runtime, "int8_kernels_available", lambda: True)
    epyc = {"avx512_bf16": True, "avx512_vnni": True}  # this AMD EPYC (Zen 4)
    assert default_precision("cpu", epyc, int8_calibrated=True) == "int8"
    assert default_precision("cpu", {"avx_vnni": True}, int8_calibrated=True) == "int8"
    assert default_precision("cpu", {"amx_int8": True, "amx_bf16": True}, int8_calibrated=True) == "int8"
    assert default_precision("cpu", epyc) == "bf16"  # weights without a calibration
    assert default_precision("cpu", {"avx512_bf16": True, "avx512_f": True}, int8_calibrated=True) == "bf16"
    assert default_precision("cpu", {"avx2": True}, int8_calibrated=True) == "fp32"  # int8 emulated: no gain
    assert default_precision("cuda", epyc, int8_calibrated=True) == "bf16"
    assert resolve_precision("auto", "cpu", int8_calibrated=True) == default_precision("cpu", None, True)
    monkeypatch.setattr(runtime, "int8_kernels_available", lambda: False)  # a torch without them
    assert default_precision("cpu", epyc, int8_calibrated=True) == "bf16"


def test_planner_resolves_auto_precision_and_refuses_others():
    torch.manual_seed(0)
    m = build_unet(TINY)
    pl = Planner(m, TINY)
    assert pl.precision == default_precision("cpu") and pl.precision in ("bf16", "fp32")
    assert Planner(m, TINY, precision="fp32").precision == "fp32"
    assert resolve_precision("auto", "cuda") == "bf16"
    with pytest.raises(ValueError, match="precision"):
        Planner(m, TINY, precision="fp16")


@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
def test_fused_conv_relu_gives_the_pairs_numbers(dtype):
    torch.manual_seed(0)
    seq = nn.Sequential(nn.Conv2d(3, 8, 3, padding=1), nn.ReLU(), nn.Conv2d(8, 8, 3, padding=1), nn.ReLU(),
                        nn.MaxPool2d(2)).eval().to(dtype).to(memory_format=torch.channels_last)
    x = torch.randn(2, 3, 16, 16, dtype=dtype).contiguous(memory_format=torch.channels_last)
    with torch.inference_mode():
        ref = seq(x)
        assert fuse_conv_relu(seq) == 2
        got = seq(x)
    assert len(seq) == 3 and not any(isinstance(m, nn.ReLU) for m in seq)
    assert (ref >= 0).all() and (ref == 0).any()  # the ReLU matters here
    torch.testing.assert_close(got, ref, rtol=0, atol=0)


def test_inference_copy_fuses_every_block():
    torch.manual_seed(0)
    m = prepare_for_inference(build_unet(TINY), "fp32")
    fused = [mod for mod in m.modules() if type(mod).__name__ == "ConvReLU"]
    assert len(fused) == 2 * (2 * TINY.depth + 1)  # two per encoder, bottleneck and decoder block
    assert not any(isinstance(mod, nn.ReLU) for mod in m.modules())


def test_masks_per_pass_grow_with_the_threads():
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        assert masks_per_pass() == MASKS_PER_THREAD
        torch.set_num_threads(2)
        assert masks_per_pass() == 2 * MASKS_PER_THREAD
        assert masks_per_pass(5) == 5
    finally:
        torch.set_num_threads(threads)
    with pytest.raises(ValueError, match="batch_size"):
        Planner(build_unet(TINY), TINY, batch_size=0)


def test_batch_size_does_not_change_the_outputs():
    torch.manual_seed(0)
    m = build_unet(TINY)
    m.train()
    m(torch.rand(4, 3, 32, 32))  # BatchNorm statistics away from the defaults
    obs = observation(3)
    x = np.random.default_rng(0).random((7, 3, 32, 32), dtype=np.float32)
    outs = [Planner(m, TINY, precision="fp32", batch_size=b).predict(x) for b in (1, 3, 16, None)]
    for o in outs[1:]:
        np.testing.assert_allclose(o, outs[0], rtol=0, atol=1e-5)
    p1, p16 = (plan(obs, Planner(m, TINY, precision="fp32", batch_size=b)) for b in (1, 16))
    assert [(g.targets, g.pixel) for g in p1.grasps] == [(g.targets, g.pixel) for g in p16.grasps]


def _two_equal_peaks(x):
    out = np.zeros((len(x), 5, 32, 32), np.float32)
    out[:, 0], out[:, 2], out[:, 3], out[:, 4] = -1.0, 0.8, -10.0, 1.0
    out[:, 3, 20, 5] = out[:, 3, 8, 25] = math.log(0.9 / 0.1)  # equal U; (8, 25) first in raster order
    return out


@pytest.mark.parametrize("keep_out", [False, True])
def test_of_equal_pixels_the_first_in_raster_order_is_chosen(keep_out):
    torch.manual_seed(0)
    pl = Planner(build_unet(TINY), TINY, precision="fp32", quality_smoothing_px=0.0)
    pl.predict = _two_equal_peaks
    far = ((-2.5, -2.5), (-2.3, -2.5), (-2.3, -2.3))  # a keep-out zone in a corner, away from both
    p = plan(observation(3), pl, constraints=Constraints(keep_out_zones=(far,) if keep_out else ()))
    assert {g.pixel for g in p.grasps} == {(8, 25)}
    assert not p.rejected
