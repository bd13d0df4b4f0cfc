"""Objects that hold a resource (a pybullet client, a renderer's world) and free it in ``close()``:
usable as ``with X(...) as x:``, and closed when garbage-collected as a safety net."""

from __future__ import annotations


class Closing:
    """Mixin: ``with`` support and a ``__del__`` safety net around the subclass's ``close()``
    (which must be safe to call twice)."""

    def close(self) -> None:  # pragma: no cover - every subclass has its own
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:  # pragma: no cover - safety net
        try:
            self.close()
        except Exception:  # interpreter shutdown: modules may already be gone
            pass
