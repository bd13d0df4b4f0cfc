"""Small helpers of the field tests (import as ``tests.field.helpers``)."""

from __future__ import annotations

import time
from typing import Callable

#: how long a test waits for something that should happen "at once" [s]: generous, so that a
#: loaded 2-core machine never fails a test that is right (the wait ends as soon as it holds)
PATIENCE_S = 10.0


def wait_until(predicate: Callable[[], bool], timeout_s: float = PATIENCE_S, poll_s: float = 0.01) -> bool:
    """Poll ``predicate`` until it is true (returns True) or ``timeout_s`` passed (False)."""
    deadline = time.monotonic() + timeout_s
    while True:
        if predicate():
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(poll_s)
