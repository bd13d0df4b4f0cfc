"""Running a controller as a process or on a thread, and its default journal path."""

from __future__ import annotations

import contextlib
import logging
import os
import threading
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Iterator

from field.controller.config import ControllerConfig
from field.controller.core import CraneController
from field.controller.executors import GraspExecutor, make_executor
from field.link.messages import ControllerStatus, GraspCommand, Outcome

log = logging.getLogger(__name__)


def run_controller(
    link_url: str,
    executor: GraspExecutor | Callable[[GraspCommand], Outcome] | str = "fixed",
    stop_event: threading.Event | None = None,
    config: ControllerConfig | None = None,
    *,
    ready_event: threading.Event | None = None,
    on_serve: Callable[[CraneController], None] | None = None,
    **transport_kwargs: Any,
) -> ControllerStatus:
    """Serve the crane side of ``link_url`` until ``stop_event`` is set; returns the final status.

    ``executor`` is a callable or a registered name (:data:`EXECUTORS`). The URL forms are those
    of :func:`field.link.open_link` (``can://virtual/ch0``, ``can://remote/127.0.0.1:PORT/ch0``,
    ``zenoh://127.0.0.1:7447/crane1`` — the controller LISTENS on that endpoint — ...).
    ``ready_event`` is set once the controller serves; ``on_serve(controller)`` is called just
    before (e.g. to watch its ``rejections``). A ``secoc_key=PATH`` in the URL is the
    controller's key when ``config`` names none, and ``signing_key=PATH`` its signing key; ``insecure=1`` there is the explicit opt-out
    (``insecure_link``) of a controller without one. The journal is on: ``config.journal_path``, or
    :func:`default_journal_path` of the link unless ``config.no_journal`` opts out.
    """
    from field.link.base import LinkURL, open_controller_transport

    if isinstance(executor, str):
        executor = make_executor(executor)
    stop_event = stop_event or threading.Event()
    config = config or ControllerConfig()
    url_config = LinkURL.parse(link_url).pop_link_config()[0]
    if url_config.secoc_key_path is not None and config.secoc_key_path is None:
        config = replace(config, secoc_key_path=url_config.secoc_key_path)
    if url_config.signing_key_path is not None and config.signing_key_path is None:
        config = replace(config, signing_key_path=url_config.signing_key_path)
    if url_config.insecure and not config.insecure_link:
        config = replace(config, insecure_link=True)
    if config.journal_path is None and not config.no_journal:
        config = replace(config, journal_path=str(default_journal_path(link_url)))
        log.info("controller journal: %s (the link's default)", config.journal_path)
    controller = CraneController(config, executor)
    transport = open_controller_transport(link_url, heartbeat_period_s=controller.config.heartbeat_period_s, **transport_kwargs)
    try:
        transport.start(controller)
        controller.start()
        if on_serve is not None:
            on_serve(controller)
        if ready_event is not None:
            ready_event.set()
        # poll: a signal delivered to a library thread (zenoh, python-can) must not leave the
        # main thread blocked forever, so handlers that set stop_event get to run
        while not stop_event.wait(0.1):
            pass
    finally:
        controller.close()
        transport.close()
    return controller.status()


@contextlib.contextmanager
def controller_in_thread(link_url: str, executor: GraspExecutor | Callable[[GraspCommand], Outcome] | str = "fixed",
                         config: ControllerConfig | None = None,
                         start_timeout_s: float = 30.0) -> Iterator[None]:
    """:func:`run_controller` on a thread of this process for the ``with`` block (a twin crane beside
    the laptop: the demo, benchmarks, tests); :class:`LinkError` when it cannot serve (with the cause)
    or is not serving within ``start_timeout_s``."""
    from field.errors import LinkError

    stop, ready = threading.Event(), threading.Event()
    failure: list[BaseException] = []

    def serve() -> None:
        try:
            run_controller(link_url, executor, stop, config, ready_event=ready)
        except BaseException as exc:  # raised in the caller's thread below
            failure.append(exc)
            ready.set()

    thread = threading.Thread(target=serve, daemon=True, name="crane-controller")
    thread.start()
    try:
        if not ready.wait(start_timeout_s) or failure:
            if failure:
                raise LinkError(f"the crane controller twin could not serve {link_url}: {failure[0]}") from failure[0]
            raise LinkError(f"the crane controller twin did not start on {link_url} within {start_timeout_s:g} s")
        yield
    finally:
        stop.set()
        thread.join(10)


def default_journal_path(link_url: str) -> Path:
    """Where a controller serving ``link_url`` burns its command ids by default:
    ``$XDG_STATE_HOME/loggrasp/journal-<link>.jsonl`` (``~/.local/state`` without the variable)."""
    import re

    state = Path(os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state")
    slug = re.sub(r"[^A-Za-z0-9.-]+", "_", link_url.split("?", 1)[0]).strip("_")[:80]
    return state / "loggrasp" / f"journal-{slug}.jsonl"
