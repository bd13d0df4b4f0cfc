"""How the planning network runs on this machine: its number format, chosen from what the CPU can
do, and how many target masks go through it at once.

Measured with the shipped 1.94 M U-Net on a 7-log pile (127 target subsets, 184 GFLOP of
convolutions), CPU seconds per plan with one torch thread, on a 2-core AMD EPYC (Zen 4: AVX512-BF16,
no AMX; 2026-12-06, beside other jobs at load 6-7; docs/model.md, "Planning on a CPU"):

* bfloat16 with the CPU's own bf16 dot products (AVX512-BF16): 1.07 s; fp32: 2.15 s. A single
  convolution runs at 200-238 GFLOP/s in bf16 and 97-118 in fp32 on one core;
* bfloat16 on the same CPU with oneDNN held to AVX512-core (``ONEDNN_MAX_CPU_ISA=AVX512_CORE``: no
  bf16 instructions, bf16 emulated by conversions): 6.5 s against fp32's 2.0 s;
* int8 (:mod:`planner.int8`; oneDNN uint8 x int8 with AVX512-VNNI, 2026-12-07, load 4-5): 0.635 s against
  bf16's 1.100 in the same run; with the full-resolution level in bf16 ("int8-bf16-top") 0.768 s. It changes
  plans in detail, not their twin success (docs/model.md, "int8": the product's rows on 240 paired piles);
* target masks per forward pass (bf16): 4: 1.14 s, 8: 1.12 s, 16: 1.07 s, 32: 1.20 s, 64: 1.25 s.
  A mask's first-level activations are 0.5 MB in bf16: 16 masks stay near the caches, 64 do not;
* with two torch threads on cores other jobs also use (load 8-9), wall s per plan: 16 masks per
  pass 3.5-7.9, 32: 2.7-3.6, 64: 3.2-3.3. A thread descheduled inside a parallel region stalls the
  other, and smaller passes mean more regions.

So int8 is chosen where the CPU has int8 dot-product instructions (:data:`NATIVE_INT8_CPU_FEATURES`), torch
has oneDNN's int8 convolution and the weights an int8 calibration; else bfloat16 exactly where the CPU has
bf16 dot-product instructions (:data:`NATIVE_BF16_CPU_FEATURES`) and fp32 elsewhere, and a forward pass takes
:data:`MASKS_PER_THREAD` masks per torch thread (:func:`masks_per_pass`): each thread's share stays
cache-sized and the number of synchronisations does not grow with the threads.
On a GPU bfloat16 is kept (tensor cores).
"""

from __future__ import annotations

NATIVE_BF16_CPU_FEATURES = ("avx512_bf16", "amx_bf16")  # x86 features with bf16 dot products (torch's names)
MASKS_PER_THREAD = 16  # target masks per forward pass and torch thread [-] (measured above)
INT8_PRECISIONS = ("int8", "int8-bf16-top")  # opt-in, CPU only (planner.int8: oneDNN uint8 x int8 convolutions,
#                                               calibrated); "int8-bf16-top": the full-resolution level in bf16
PRECISIONS = ("auto", "bf16", "fp32", *INT8_PRECISIONS)  # "auto": :func:`default_precision`
NATIVE_INT8_CPU_FEATURES = ("avx512_vnni", "avx_vnni", "amx_int8")  # x86 features with int8 dot products


def cpu_features() -> dict:
    """The CPU's features as torch reports them (``{"avx512_bf16": True, ...}``); empty where this
    torch cannot say (then no bf16 is assumed)."""
    import torch

    try:
        return dict(torch._C._cpu._get_cpu_capability())
    except (AttributeError, RuntimeError):
        return {}


def cpu_has_native_bf16(features: dict | None = None) -> bool:
    """True when the CPU (``features``, default :func:`cpu_features`) computes bf16 dot products
    in hardware (AVX512-BF16 or AMX-BF16)."""
    features = cpu_features() if features is None else features
    return any(bool(features.get(f)) for f in NATIVE_BF16_CPU_FEATURES)


def cpu_has_native_int8(features: dict | None = None) -> bool:
    """True when the CPU (``features``, default :func:`cpu_features`) computes int8 dot products in
    hardware (AVX512-VNNI, AVX-VNNI or AMX-INT8): where :mod:`planner.int8` beats bf16."""
    features = cpu_features() if features is None else features
    return any(bool(features.get(f)) for f in NATIVE_INT8_CPU_FEATURES)


def default_precision(device: str, features: dict | None = None, int8_calibrated: bool = False) -> str:
    """The planning network's number format on ``device`` ("cpu" or "cuda"): "bf16" on a GPU; on a
    CPU "int8" where the weights have an int8 calibration (``int8_calibrated``), the CPU has int8 dot
    products (:func:`cpu_has_native_int8`) and torch has oneDNN's int8 convolution; else "bf16" with
    native bf16 (:func:`cpu_has_native_bf16`), else "fp32" (emulated bf16 is ~3x slower than fp32, see
    the module doc)."""
    if device != "cpu":
        return "bf16"
    if int8_calibrated and cpu_has_native_int8(features) and int8_kernels_available():
        return "int8"
    return "bf16" if cpu_has_native_bf16(features) else "fp32"


def masks_per_pass(batch_size: int | None = None) -> int:
    """``batch_size`` itself, or :data:`MASKS_PER_THREAD` x torch's threads for None."""
    if batch_size is not None:
        return batch_size
    import torch

    return MASKS_PER_THREAD * max(1, torch.get_num_threads())


def int8_kernels_available() -> bool:
    """True when this torch has oneDNN's int8 convolution (``torch.ops.onednn.qconv2d_pointwise``,
    what :mod:`planner.int8` runs)."""
    import torch

    return (torch.backends.mkldnn.is_available() and "onednn" in torch.backends.quantized.supported_engines
            and hasattr(torch.ops.onednn, "qconv2d_pointwise") and hasattr(torch.ops.onednn, "qconv_prepack"))


def resolve_precision(precision: str, device: str, int8_calibrated: bool = False) -> str:
    """``precision`` itself, or :func:`default_precision` for "auto"; ``ValueError`` for others and
    for the int8 ones where they cannot run (not on the CPU, or no oneDNN int8 kernels)."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {list(PRECISIONS)}, got {precision!r}")
    if precision in INT8_PRECISIONS and (device != "cpu" or not int8_kernels_available()):
        why = "it runs on the CPU only" if device != "cpu" else "this torch has no oneDNN int8 convolution"
        raise ValueError(f"precision {precision!r} cannot run on {device!r}: {why}; use 'bf16' or 'fp32'")
    return default_precision(device, int8_calibrated=int8_calibrated) if precision == "auto" else precision
