"""Planner checkpoints: one ``.safetensors`` file holding the weights and, in its JSON header,
the format version, the network's :class:`~planner.model.UNetConfig` (architecture, input channels,
input size) and free metadata (training run, data set, epoch...).

Loading never unpickles anything (``torch.load`` is not used). A missing, corrupt, foreign or
newer-major-version file, or weights that do not fit the stored architecture, raise
:class:`~planner.errors.CheckpointError` saying what to do.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from planner.errors import CheckpointError
from synth.common.formats import VersionedJson
from planner.model import UNetConfig

CHECKPOINT_FORMAT_NAME = "loggrasp.planner.checkpoint"
CHECKPOINT_FORMAT_VERSION = "1.0"

#: The trained default model shipped with loggrasp (safetensors + config in its header).
DEFAULT_MODEL = Path(__file__).resolve().parent / "weights" / "default.safetensors"
#: The grasp ranker shipped with loggrasp (:mod:`planner.ranker`; trained as docs/results/ranker-r1 says).
DEFAULT_RANKER = Path(__file__).resolve().parent / "weights" / "ranker.safetensors"


def save_tensors(path: str | Path, tensors: dict, header: dict[str, Any]) -> Path:
    """Write ``tensors`` (name -> torch tensor) and a JSON ``header`` atomically as safetensors."""
    from safetensors.torch import save

    from synth.common.files import atomic_write_bytes

    path = Path(path)
    flat = {k: v.detach().cpu().contiguous().clone() for k, v in tensors.items()}
    data = save(flat, metadata={"loggrasp": json.dumps(header)})
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, data)
    return path


def load_tensors(path: str | Path, expected_format: str) -> tuple[dict, dict]:
    """Read a file written by :func:`save_tensors`; checks its format name and major version."""
    from safetensors import SafetensorError
    from safetensors.torch import load

    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} does not exist; train one first or pass the right path")
    try:
        raw = path.read_bytes()
        tensors = load(raw)
        header_len = int.from_bytes(raw[:8], "little")
        meta = json.loads(raw[8 : 8 + header_len]).get("__metadata__") or {}
        header = json.loads(meta["loggrasp"])
    except (SafetensorError, OSError, ValueError, KeyError, TypeError) as exc:
        raise CheckpointError(f"{path} is not a readable loggrasp safetensors file ({exc}); "
                              "it may be truncated or corrupt: use another checkpoint or retrain") from exc
    VersionedJson(expected_format, CHECKPOINT_FORMAT_VERSION, "checkpoint", CheckpointError,
                  fix="upgrade loggrasp or retrain").check(header, path)
    return tensors, header


def save_checkpoint(path: str | Path, model, config: UNetConfig, meta: dict[str, Any] | None = None) -> Path:
    """Save ``model`` (built from ``config``) with free JSON-serialisable ``meta``."""
    header = {"format": CHECKPOINT_FORMAT_NAME, "format_version": CHECKPOINT_FORMAT_VERSION,
              "model_config": config.to_dict(), "meta": dict(meta or {})}
    return save_tensors(path, model.state_dict(), header)


def load_checkpoint(path: str | Path, *, in_channels: int | None = None, size_px: int | None = None):
    """Load a checkpoint: returns ``(model, config, meta)`` with the model in eval mode on the CPU.

    ``in_channels`` / ``size_px``, when given, must match what the network was built for."""
    from planner.model import build_unet

    tensors, header = load_tensors(path, CHECKPOINT_FORMAT_NAME)
    try:
        config = UNetConfig.from_dict(header["model_config"])
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{path}: the stored network configuration is invalid ({exc})") from exc
    if in_channels is not None and in_channels != config.in_channels:
        raise CheckpointError(f"{path} was trained with {config.in_channels} input channels "
                              f"({', '.join(_names(config))}), but {in_channels} were asked for; "
                              "use a checkpoint trained for this input")
    if size_px is not None and size_px != config.size_px:
        raise CheckpointError(f"{path} was trained on {config.size_px} px images, but the input is {size_px} px; "
                              "render at the checkpoint's size or use a matching checkpoint")
    model = build_unet(config)
    try:
        model.load_state_dict(tensors, strict=True)
    except RuntimeError as exc:
        raise CheckpointError(f"{path}: the weights do not fit the stored architecture ({exc}); "
                              "the file is inconsistent: retrain or use another checkpoint") from exc
    model.eval()
    return model, config, header.get("meta", {})


def _names(config: UNetConfig) -> tuple[str, ...]:
    from planner.model import INPUT_NAMES

    return INPUT_NAMES[config.in_channels]
