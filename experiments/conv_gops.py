"""One convolution + ReLU at the planning U-Net's shapes, in every number format and int8 backend this
torch has: which of them use the CPU's bf16 and VNNI dot products (docs/model.md, "int8").

Batch 16, channels-last, one thread, CPU seconds (median of 5 runs of about 2 GFLOP each):

    OMP_NUM_THREADS=1 .venv/bin/python -m experiments.conv_gops
"""

from __future__ import annotations

import statistics
import time
import warnings

SHAPES = ((3, 16, 128), (16, 16, 128), (32, 16, 128), (32, 32, 64), (64, 64, 32), (128, 128, 16), (256, 256, 8))
BATCH = 16  # target masks per pass, as the planner runs (planner.runtime.MASKS_PER_THREAD) [-]
WORK_PER_RUN = 2e9  # operations per timed run [-]


def _cpu_s(fn, reps: int) -> float:
    fn()
    times = []
    for _ in range(5):
        c0 = time.process_time()
        for _ in range(reps):
            fn()
        times.append((time.process_time() - c0) / reps)
    return statistics.median(times)


def conv_gops(shapes=SHAPES, batch: int = BATCH, work: float = WORK_PER_RUN) -> list[dict]:
    """GOP/s of a 3x3 convolution + ReLU per (cin, cout, side) and format: bf16 and fp32 (oneDNN
    with the ReLU as post-op), int8 through ``quantized::conv2d_relu`` with each quantized engine,
    and int8 through ``onednn::qconv2d_pointwise`` (what :mod:`planner.int8` runs); each timed run
    does about ``work`` operations."""
    import torch

    torch.set_num_threads(1)
    torch.manual_seed(0)
    cl, one, rows = torch.channels_last, [1, 1], []
    for cin, cout, side in shapes:
        x = torch.rand(batch, cin, side, side).contiguous(memory_format=cl)
        w, b = torch.randn(cout, cin, 3, 3) * 0.1, torch.randn(cout) * 0.1
        ops = 2 * batch * cout * cin * 9 * side * side
        reps = max(1, int(work / ops))
        fns = {}
        for name, dt in (("bf16", torch.bfloat16), ("fp32", torch.float32)):
            xd, wd, bd = x.to(dt), w.to(dt).contiguous(memory_format=cl), b.to(dt)
            fns[name] = lambda xd=xd, wd=wd, bd=bd: torch.ops.mkldnn._convolution_pointwise(
                xd, wd, bd, one, one, one, 1, "relu", [], "")
        w_scale = w.abs().amax(dim=(1, 2, 3)) / 127
        x_scale = float(x.max() / 255)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # quantized tensors are deprecated in torch 2.13
            qw = torch.quantize_per_channel(w, w_scale, torch.zeros(cout, dtype=torch.long), 0, torch.qint8)
            for engine in torch.backends.quantized.supported_engines:
                if engine == "qnnpack":
                    continue  # the ARM engine
                torch.backends.quantized.engine = engine
                qx = torch.quantize_per_tensor(x, x_scale, 0, torch.quint8).contiguous(memory_format=cl)
                packed = torch.ops.quantized.conv2d_prepack(qw, b, one, one, one, 1)
                fns[f"int8 {engine}"] = lambda qx=qx, packed=packed: torch.ops.quantized.conv2d_relu(qx, packed, 0.05, 0)
        x_u8 = torch.clamp((x / x_scale).round(), 0, 255).to(torch.uint8).contiguous(memory_format=cl)
        w_i8 = torch.clamp((w / w_scale[:, None, None, None]).round(), -127, 127).to(torch.int8)
        pw = torch.ops.onednn.qconv_prepack(w_i8, w_scale, x_scale, 0, one, one, one, 1, list(x.shape))
        w_zp = torch.zeros(cout, dtype=torch.int64)
        fns["int8 qconv2d_pointwise"] = lambda: torch.ops.onednn.qconv2d_pointwise(
            x_u8, x_scale, 0, pw, w_scale, w_zp, b, one, one, one, 1, 0.05, 0, None, "relu", [], "")
        rows.append({"cin": cin, "cout": cout, "side_px": side,
                     **{k: ops / _cpu_s(f, reps) / 1e9 for k, f in fns.items()}})
    return rows


if __name__ == "__main__":
    rows = conv_gops()
    keys = [k for k in rows[0] if k not in ("cin", "cout", "side_px")]
    print("| conv | " + " | ".join(keys) + " |")
    print("|---|" + "---|" * len(keys))
    for r in rows:
        print(f"| {r['cin']} -> {r['cout']} @ {r['side_px']} px | " + " | ".join(f"{r[k]:.0f}" for k in keys) + " |")
