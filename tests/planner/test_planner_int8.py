"""The int8 planning network (planner.int8, precision "int8"): its pieces give the float network's
numbers, the shipped model plans as in bf16, the calibration file is versioned and tied to its
weights, and where int8 cannot run the planner says so in one line."""

import json

import numpy as np
import pytest
import torch

import planner.runtime as runtime
from planner.checkpoint import DEFAULT_MODEL
from planner.errors import CheckpointError
from planner.inference import Objective, Planner, load_planner, plan
from planner.int8 import (INT8_CALIBRATION, _pool_u8, _unshuffle_cat, _up_as_1x1, act_qparams, build_int8, calibrate,
                          calibration_path, float_walk, input_qparams, read_calibration, weights_sha256,
                          write_calibration)
from planner.model import UNetConfig, build_unet, fold_batch_norm
from planner_helpers import observation

TINY = UNetConfig.tiny()
needs_int8 = pytest.mark.skipif(not runtime.int8_kernels_available(), reason="this torch has no oneDNN int8 kernels")
U_TOL = 0.05  # |u| of a subset's best grasp, int8 against bf16, on the small pile (measured: 0.022) [-]


def _tiny_model():
    torch.manual_seed(0)
    m = build_unet(TINY).eval()
    with torch.no_grad():
        for mod in m.modules():
            if isinstance(mod, torch.nn.BatchNorm2d):
                mod.running_mean.uniform_(-0.1, 0.1)
                mod.running_var.uniform_(0.5, 1.5)
    return m


def _inputs(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = np.zeros((n, 3, TINY.size_px, TINY.size_px), np.float32)
    x[:, 0] = rng.random(x.shape[2:])
    x[:, 1] = rng.random(x.shape[2:]) * 0.5 - 0.05
    x[:, 2] = rng.random((n, *x.shape[2:])) > 0.7
    return x


def test_transposed_convolution_as_1x1_and_copy_is_exact():
    torch.manual_seed(0)
    up = torch.nn.ConvTranspose2d(6, 3, 2, stride=2)
    x = torch.randn(2, 6, 5, 7)
    skip = torch.randn(2, 4, 10, 14).contiguous(memory_format=torch.channels_last)
    w1, b1 = _up_as_1x1(up)
    u = torch.nn.functional.conv2d(x, w1, b1).contiguous(memory_format=torch.channels_last)
    with torch.no_grad():
        want = torch.cat([up(x), skip], dim=1)
    torch.testing.assert_close(_unshuffle_cat(u, skip), want, rtol=1e-6, atol=1e-6)


def test_uint8_pooling_and_codes():
    x = torch.randint(0, 256, (2, 3, 8, 6), dtype=torch.uint8).contiguous(memory_format=torch.channels_last)
    assert torch.equal(_pool_u8(x), torch.max_pool2d(x.float(), 2).to(torch.uint8))
    scale, zp = act_qparams(-1.0, 3.0)
    assert zp == round(1.0 / scale) and abs(scale * 255 - 4.0) < 1e-9  # 0 exact, the range covered
    assert act_qparams(0.5, 2.0) == (2.0 / 255, 0)  # widened to hold 0
    scales, zp = input_qparams([(0.0, 1.0), (-0.1, 0.9), (0.0, 1.0)])
    assert zp > 0 and np.all(np.array([1.0, 0.9, 1.0]) / scales <= 255 - zp + 1e-3)
    assert 0.1 / scales[1] <= zp + 1e-3  # the lowest height still has a code


@needs_int8
@pytest.mark.parametrize("float_top", [False, True])
def test_int8_network_runs_a_tiny_network(float_top):
    """Shapes, dtype and a loose bound on a tiny random network (whose output hardly depends on its
    deeper levels: the shipped model's test below is the sharp one)."""
    m = _tiny_model()
    cal = calibrate(m, [_inputs(8, s) for s in range(3)])
    x = _inputs(4, 9)
    with torch.inference_mode():
        ref = float_walk(fold_batch_norm(m), torch.from_numpy(x))
        got = build_int8(m, cal, 4, float_top=float_top)(torch.from_numpy(x).contiguous(
            memory_format=torch.channels_last))
    assert got.dtype == torch.float32 and got.shape == ref.shape
    err = (got - ref).abs().amax(dim=(0, 2, 3))
    assert float(err.max()) < 0.01 * float(ref.abs().max()) + 1e-3, err


@needs_int8
@pytest.mark.parametrize("float_top", [False, True])
def test_shipped_int8_network_is_near_the_float_network(float_top):
    """The shipped model on the 15 target masks of a small pile: mean |int8 - fp32| per output
    (measured C, S, W, U logit, B: 0.010, 0.006, 0.005, 0.056, 0.003; bf16 top level: about half)."""
    import itertools

    from planner.checkpoint import load_checkpoint
    from planner.data import make_inputs

    torch.set_num_threads(1)
    m = load_checkpoint(DEFAULT_MODEL)[0]
    obs = observation(4, size=128, seed=3)
    subsets = [s for k in range(1, 5) for s in itertools.combinations(range(4), k)]
    x = make_inputs(obs.intensity[0], obs.depth, np.stack([obs.target_mask(s) for s in subsets]), 3, 5.0)
    with torch.inference_mode():
        ref = float_walk(fold_batch_norm(m), torch.from_numpy(x))
        got = build_int8(m, read_calibration(calibration_path(DEFAULT_MODEL)), 16, float_top=float_top)(
            torch.from_numpy(x).contiguous(memory_format=torch.channels_last))
    err = (got - ref).abs().mean(dim=(0, 2, 3)).numpy()
    assert err[3] < 0.1 and np.all(np.delete(err, 3) < 0.02), err


def test_int8_is_refused_in_one_line_where_it_cannot_run(monkeypatch):
    m = build_unet(TINY)
    with pytest.raises(ValueError, match="'int8' cannot run on 'cuda'"):
        runtime.resolve_precision("int8", "cuda")
    monkeypatch.setattr(runtime, "int8_kernels_available", lambda: False)
    with pytest.raises(ValueError, match="no oneDNN int8 convolution; use 'bf16' or 'fp32'") as exc:
        Planner(m, TINY, precision="int8")
    assert "\n" not in str(exc.value)
    with pytest.raises(ValueError, match="no oneDNN int8"):
        load_planner(DEFAULT_MODEL, device="cpu", precision="int8")
    assert runtime.resolve_precision("auto", "cpu") in ("bf16", "fp32")  # no calibration: never int8
    assert load_planner(DEFAULT_MODEL, device="cpu").precision in ("bf16", "fp32")  # "auto": the float format


@needs_int8
def test_int8_needs_a_calibration_and_an_input_mask_network():
    with pytest.raises(ValueError, match="int8 calibration"):
        Planner(build_unet(TINY), TINY, precision="int8")
    late = UNetConfig.tiny(mask_injection="decoder")
    with pytest.raises(ValueError, match="mask_injection='input'"):
        calibrate(build_unet(late), [_inputs(2, 0)])
    cal = calibrate(_tiny_model(), [_inputs(2, 0)])
    with pytest.raises(ValueError, match="mask_injection='input'"):
        Planner(build_unet(late), late, precision="int8", int8_calibration=cal)


def test_calibration_file_is_versioned_and_tied_to_its_weights(tmp_path):
    m = _tiny_model()
    cal = calibrate(m, [_inputs(4, 0)], {"stores": ["test"]})
    path = write_calibration(tmp_path / "tiny.int8.json", cal)
    back = read_calibration(path)
    assert back == cal and back.meta["samples"] == 4
    back.check(m)
    other = _tiny_model()
    with torch.no_grad():
        other.head.bias += 0.01
    assert weights_sha256(other) != cal.weights_sha256
    with pytest.raises(CheckpointError, match="calibrate it again"):
        back.check(other)
    with pytest.raises(CheckpointError, match="calibrate it again"):
        build_int8(other, back)
    doc = json.loads(path.read_text())
    doc["format_version"] = "2.0"
    path.write_text(json.dumps(doc))
    with pytest.raises(CheckpointError, match="major version|version"):
        read_calibration(path)
    with pytest.raises(CheckpointError):
        read_calibration(tmp_path / "missing.int8.json")
    assert INT8_CALIBRATION.version.startswith("1.")


def test_shipped_calibration_belongs_to_the_shipped_weights():
    from planner.checkpoint import load_checkpoint

    cal = read_calibration(calibration_path(DEFAULT_MODEL))
    cal.check(load_checkpoint(DEFAULT_MODEL)[0])
    assert cal.meta["samples"] >= 200 and set(cal.meta["stores"]) == {"paper-v4", "mixed-v4"}


@needs_int8
@pytest.mark.parametrize("int8", ["int8", "int8-bf16-top"])
def test_shipped_model_plans_a_small_pile_in_int8_as_in_bf16(int8):
    torch.set_num_threads(1)
    obs = observation(4, size=128, seed=3)
    plans = {"bf16": load_planner(DEFAULT_MODEL, device="cpu", precision="bf16"),
             "int8": load_planner(DEFAULT_MODEL, device="cpu", precision=int8)}
    assert plans["int8"].precision == int8 and plans["int8"]._net.float_top == (int8 == "int8-bf16-top")
    for kind in ("f1", "f3"):
        got = {p: plan(obs, pl, Objective(kind)) for p, pl in plans.items()}
        assert got["int8"].best.targets == got["bf16"].best.targets, kind
        u_bf16 = {g.targets: g.graspability for g in got["bf16"].grasps}
        du = [abs(g.graspability - u_bf16[g.targets]) for g in got["int8"].grasps]
        assert len(du) == 15 and max(du) < U_TOL, (kind, max(du))


@needs_int8
def test_int8_outputs_do_not_depend_on_threads_or_packing():
    """Integer accumulation: the same numbers with 1 or 2 threads and weights packed for 16 or 32
    masks, up to the fp32 head's rounding (measured 3e-6; 0 with 16 masks)."""
    from planner.checkpoint import load_checkpoint

    m = load_checkpoint(DEFAULT_MODEL)[0]
    cal = read_calibration(calibration_path(DEFAULT_MODEL))
    x = torch.nn.functional.interpolate(torch.from_numpy(_inputs(4, 1)), size=128)
    x = x.contiguous(memory_format=torch.channels_last)
    threads = torch.get_num_threads()
    outs = []
    try:
        for t, batch in ((1, 16), (2, 32)):
            torch.set_num_threads(t)
            with torch.inference_mode():
                outs.append(build_int8(m, cal, batch)(x))
    finally:
        torch.set_num_threads(threads)
    torch.testing.assert_close(outs[0], outs[1], rtol=0, atol=1e-4)


@needs_int8
def test_the_shipped_model_plans_in_int8_by_default_where_the_cpu_has_int8_dot_products(tmp_path):
    """"auto" picks int8 for a checkpoint with a calibration beside it on a CPU with int8 dot products
    (AVX512-VNNI here), the float format for the same weights without one; a calibration of other
    weights is a one-line error, not a silent fallback."""
    import shutil

    from planner.int8 import calibration_path

    net = load_planner(DEFAULT_MODEL, device="cpu")
    assert net.precision == ("int8" if runtime.cpu_has_native_int8() else runtime.default_precision("cpu"))
    bare = shutil.copy(DEFAULT_MODEL, tmp_path / "bare.safetensors")
    assert load_planner(bare, device="cpu").precision in ("bf16", "fp32")
    m = _tiny_model()
    write_calibration(calibration_path(bare), calibrate(m, [_inputs(2, 0)]))
    if runtime.cpu_has_native_int8():
        with pytest.raises(CheckpointError, match="calibrate it again"):
            load_planner(bare, device="cpu")
