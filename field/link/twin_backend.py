"""``twin://``: the crane link with an in-process controller twin behind it.

A :class:`field.controller.CraneController` is served on a private python-can ``virtual``
channel and a :class:`field.link.can_backend.CanLink` talks to it, so the whole CAN stack (DBC
codec, E2E, counters, heartbeats, recording) runs exactly as against a real crane.

URL parameters: ``executor=NAME`` (registered executor, default ``fixed``), ``delay_ms`` and
``outcome`` (for ``fixed``); other parameters go to the executor as strings
(``twin://?executor=pybullet&pile=runs/pile.json&trial=fast``); plus the common link options
(``record=...`` etc.).
"""

from __future__ import annotations

import uuid
from typing import Any

import can

from field.link.base import LinkConfig, LinkURL
from field.link.can_backend import CanControllerTransport, CanLink


class TwinLink(CanLink):
    backend_name = "twin"

    def __init__(self, config: LinkConfig | None = None, *, controller_config: Any = None, executor: Any = None):
        from field.controller import CraneController, FixedOutcomeExecutor

        self.channel = f"loggrasp-twin-{uuid.uuid4().hex[:12]}"
        self.controller = CraneController(controller_config, executor if executor is not None else FixedOutcomeExecutor())
        self.transport = CanControllerTransport(
            bus=can.Bus(interface="virtual", channel=self.channel, fd=True),
            heartbeat_period_s=self.controller.config.heartbeat_period_s,
        )
        try:
            self.transport.start(self.controller)
            self.controller.start()
            super().__init__({"interface": "virtual", "channel": self.channel, "fd": True}, config)
        except BaseException:
            self.controller.close()
            self.transport.close()
            raise

    @classmethod
    def from_url(cls, url: LinkURL, config: LinkConfig | None = None, *, controller_config: Any = None, executor: Any = None) -> "TwinLink":
        from field.controller import FixedOutcomeExecutor, make_executor

        cfg, q = url.pop_link_config(config)
        if executor is None:
            name = q.pop("executor", "fixed")
            kwargs: dict[str, Any] = {}
            if "delay_ms" in q:
                kwargs["delay_s"] = float(q.pop("delay_ms")) / 1000.0
            if "outcome" in q:
                kwargs["outcome_class"] = q.pop("outcome")
            if name == "fixed":
                if q:
                    raise ValueError(f"unknown twin:// parameters {sorted(q)}")
                executor = FixedOutcomeExecutor(**kwargs)
            else:  # the remaining parameters are the executor's (strings), e.g. pile=PATH&trial=fast
                executor = make_executor(name, **kwargs, **q)
        elif q:
            raise ValueError(f"unknown twin:// parameters {sorted(q)}")
        link = cls(cfg, controller_config=controller_config, executor=executor)
        link._await_controller()
        return link

    def _close_transport(self) -> None:
        try:
            super()._close_transport()
        finally:
            self.controller.close()
            self.transport.close()
