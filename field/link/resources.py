"""Open buses and Zenoh sessions, tracked so a test fixture can fail a test that leaks one."""

from __future__ import annotations

import threading
from typing import Callable

_RESOURCES: dict[int, tuple[str, Callable[[], None]]] = {}
_RES_LOCK = threading.Lock()


def track_resource(obj: object, description: str, closer: Callable[[], None]) -> None:
    """Register an open bus / Zenoh session; :func:`untrack_resource` when closed."""
    with _RES_LOCK:
        _RESOURCES[id(obj)] = (description, closer)


def untrack_resource(obj: object) -> None:
    with _RES_LOCK:
        _RESOURCES.pop(id(obj), None)


def open_resources() -> list[str]:
    """Descriptions of buses / sessions opened by :mod:`field.link` and not closed yet."""
    with _RES_LOCK:
        return [d for d, _ in _RESOURCES.values()]


def close_leaked_resources() -> list[str]:
    """Close everything still open (test teardown); returns what was closed."""
    with _RES_LOCK:
        items = list(_RESOURCES.items())
        _RESOURCES.clear()
    for _, (_, closer) in items:
        try:
            closer()
        except Exception:  # best effort during teardown
            pass
    return [d for _, (d, _) in items]
