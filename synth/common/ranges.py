"""Inclusive whole-number ranges as written on command lines."""

from __future__ import annotations


def parse_range(text: str, name: str) -> tuple[int, int]:
    """'A-B' or 'A' -> (A, B); a clear ``ValueError`` naming ``name`` otherwise."""
    try:
        parts = [int(v) for v in str(text).split("-")]
    except ValueError:
        raise ValueError(f"{name} must look like 'A-B' or 'A' with whole numbers, got {text!r}") from None
    if len(parts) == 1:
        parts = parts * 2
    if len(parts) != 2 or parts[0] > parts[1] or parts[0] < 0:
        raise ValueError(f"{name} must look like 'A-B' with 0 <= A <= B, got {text!r}")
    return parts[0], parts[1]
