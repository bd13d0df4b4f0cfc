"""``twin://``: the crane link with an in-process controller twin behind it.

A :class:`field.controller.CraneController` is served on a private python-can ``virtual``
channel and a :class:`field.link.can_backend.CanLink` talks to it, so the whole CAN stack (DBC
codec, E2E, counters, heartbeats, recording) runs exactly as against a real crane.

URL parameters: ``crane_base=E,N,H`` / ``crane_max_reach_m`` / ``crane_max_pile_age_s`` (the simulated
crane's own reach envelope and staleness limit), ``executor=NAME`` (registered executor, default ``fixed``), ``delay_ms`` and
``outcome`` (for ``fixed``); other parameters go to the executor as strings
(``twin://?executor=pybullet&pile=runs/pile.json&trial=fast``); plus the common link options
(``record=...``; ``secoc_key=PATH`` keys the laptop and the twin crane alike).
"""

from __future__ import annotations

import uuid
from dataclasses import replace
from typing import Any

import can

from field.link.base import LinkConfig, LinkURL
from field.link.can_backend import CanControllerTransport, CanLink


class TwinLink(CanLink):
    backend_name = "twin"
    _requires_key = False  # a private in-process bus: no other node can reach it

    def __init__(self, config: LinkConfig | None = None, *, controller_config: Any = None, executor: Any = None):
        from field.controller import ControllerConfig, CraneController, FixedOutcomeExecutor

        self.channel = f"loggrasp-twin-{uuid.uuid4().hex[:12]}"
        key, signing = (config or LinkConfig()).secoc_key_path, (config or LinkConfig()).signing_key_path
        # the twin's bus is private to this process and gone with it: nothing can replay a command into
        # a restarted twin, so it opts out of the journal (explicitly; the controller logs it); it signs
        # its answers only when given a signing key (signing_key=), as nothing else speaks on its bus
        controller_config = controller_config or ControllerConfig(no_journal=True, insecure_link=_unsigned(key, signing))
        if key is not None:  # the twin crane holds the same key as the laptop
            signing = signing or controller_config.signing_key_path
            controller_config = replace(controller_config, secoc_key_path=key, signing_key_path=signing,
                                        insecure_link=controller_config.insecure_link or signing is None)
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
        if controller_config is None and ("crane_base" in q or "crane_max_pile_age_s" in q or "crane_max_reach_m" in q):
            # the simulated crane's own limits (a real controller has them configured on board)
            from field.controller import ControllerConfig, ReachEnvelope

            try:
                kw: dict[str, Any] = {}
                if "crane_base" in q:
                    e, n, h = (float(v) for v in q.pop("crane_base").split(","))
                    kw["reach"] = ReachEnvelope(base_easting_m=e, base_northing_m=n, base_height_m=h,
                                                max_reach_m=float(q.pop("crane_max_reach_m", 10.0)))
                if "crane_max_pile_age_s" in q:
                    kw["max_pile_age_s"] = float(q.pop("crane_max_pile_age_s"))
            except ValueError as exc:
                raise ValueError(f"twin:// crane_base must be E,N,H and crane_max_pile_age_s a number: {exc}") from exc
            controller_config = ControllerConfig(**kw, no_journal=True,
                                                 insecure_link=_unsigned(cfg.secoc_key_path, cfg.signing_key_path))
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


def _unsigned(key: str | None, signing: str | None) -> bool:
    """Whether the twin crane opts out (insecure_link): no SecOC key, or no signing key beside it."""
    return key is None or signing is None
