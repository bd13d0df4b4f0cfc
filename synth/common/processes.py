"""Worker processes of the parallel jobs (data generation, evaluation, verification)."""

from __future__ import annotations

import os


def exit_with_parent(poll_s: float = 1.0) -> None:
    """Worker-process initializer: end this process when the process that started it dies.

    A killed job's ``ProcessPoolExecutor`` workers otherwise live on (they are not its process
    group's when it was started in the background) and keep writing into its output folder,
    racing the next run. A daemon thread notices the parent going (this process re-parented)
    within ``poll_s`` and exits at once."""
    import threading
    import time

    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_s)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()
