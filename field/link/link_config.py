"""The link's common options (:class:`LinkConfig`) and its URL (:class:`LinkURL`)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any
from urllib.parse import parse_qsl, unquote, urlsplit

from field.link.safety import SafetyConfig


@dataclass(frozen=True)
class LinkConfig:
    """Options every backend understands (URL query parameters of the same names)."""

    heartbeat_period_s: float = 0.05  # laptop heartbeat period [s] (CAN)
    heartbeat_timeout_s: float = 1.0  # controller counts as lost after this long without a heartbeat [s]
    status_timeout_s: float = 0.3  # status query answer deadline [s]
    connect_timeout_s: float = 3.0  # wait this long for the controller's first sign of life at open [s]
    require_controller: bool = True  # open fails when no controller answers within connect_timeout_s
    record_path: str | None = None  # record the session's traffic here (CAN: BLF)
    secoc_key_path: str | None = None  # pre-shared key file: authenticated frames only (SecOC style)
    insecure: bool = False  # the explicit opt-out: no key, frames not authenticated (URL insecure=1) [-]
    secoc_window_s: float = 2.0  # SecOC freshness window [s]
    crane_key_path: str | None = None  # laptop: the crane's Ed25519 public key; its answers must carry its signature
    signing_key_path: str | None = None  # crane: its Ed25519 signing key (controllers sharing a URL; laptops ignore it)
    signature_wait_s: float = 0.25  # CAN: a crane frame waits this long for its signature frame, then is dropped [s]
    # more crane frames than this failing their MAC, signature or key id within auth_failure_window_s: a node
    # forging the crane's answers is on the link - it fails (LinkError), the laptop stops commanding
    max_auth_failures: int = 20  # [-]
    auth_failure_window_s: float = 10.0  # [s]
    safety: SafetyConfig = field(default_factory=SafetyConfig)

    def __post_init__(self) -> None:
        for name in ("heartbeat_period_s", "heartbeat_timeout_s", "status_timeout_s", "connect_timeout_s",
                     "secoc_window_s", "signature_wait_s", "auth_failure_window_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0):
                raise ValueError(f"LinkConfig.{name} must be > 0 s, got {v!r}")
        if not (isinstance(self.max_auth_failures, int) and self.max_auth_failures >= 1):
            raise ValueError(f"LinkConfig.max_auth_failures must be an integer >= 1, got {self.max_auth_failures!r}")
        if self.heartbeat_timeout_s <= self.heartbeat_period_s:
            raise ValueError(
                f"heartbeat_timeout_s ({self.heartbeat_timeout_s}) must exceed heartbeat_period_s "
                f"({self.heartbeat_period_s}); use several periods"
            )


@dataclass(frozen=True)
class LinkURL:
    """A parsed link URL: ``scheme://netloc/path?query``."""

    scheme: str
    netloc: str
    path: str  # without the leading "/", unquoted
    query: dict[str, str]

    @classmethod
    def parse(cls, url: str) -> "LinkURL":
        if not isinstance(url, str) or "://" not in url:
            raise ValueError(
                f"link URL must look like 'can://virtual/ch0', 'zenoh://127.0.0.1:7447/crane1' or "
                f"'twin://', got {url!r}"
            )
        parts = urlsplit(url)
        return cls(parts.scheme.lower(), unquote(parts.netloc), unquote(parts.path.lstrip("/")), dict(parse_qsl(parts.query)))

    def pop_link_config(self, base: LinkConfig | None = None) -> tuple[LinkConfig, dict[str, str]]:
        """Split the query into a :class:`LinkConfig` and the backend's own parameters."""
        cfg = base or LinkConfig()
        q = dict(self.query)
        kw: dict[str, Any] = {}
        safety: dict[str, Any] = {}
        try:
            if "heartbeat_ms" in q:
                kw["heartbeat_period_s"] = float(q.pop("heartbeat_ms")) / 1000.0
            if "heartbeat_timeout_ms" in q:
                kw["heartbeat_timeout_s"] = float(q.pop("heartbeat_timeout_ms")) / 1000.0
            if "status_timeout_ms" in q:
                kw["status_timeout_s"] = float(q.pop("status_timeout_ms")) / 1000.0
            if "connect_timeout_s" in q:
                kw["connect_timeout_s"] = float(q.pop("connect_timeout_s"))
            if "record" in q:
                kw["record_path"] = q.pop("record")
            if "secoc_key" in q:
                kw["secoc_key_path"] = q.pop("secoc_key")
            if "crane_key" in q:
                kw["crane_key_path"] = q.pop("crane_key")
            if "signing_key" in q:
                kw["signing_key_path"] = q.pop("signing_key")
            if "max_auth_failures" in q:
                kw["max_auth_failures"] = int(q.pop("max_auth_failures"))
            if "signature_wait_s" in q:
                kw["signature_wait_s"] = float(q.pop("signature_wait_s"))
            if "insecure" in q:
                kw["insecure"] = _flag(q.pop("insecure"), "insecure")
            if "secoc_window_s" in q:
                kw["secoc_window_s"] = float(q.pop("secoc_window_s"))
            if "max_pile_age_s" in q:
                safety["max_pile_age_s"] = float(q.pop("max_pile_age_s"))
        except ValueError as exc:
            raise ValueError(f"bad number in link URL query {self.query}: {exc}") from exc
        if safety:
            kw["safety"] = replace(cfg.safety, **safety)
        return replace(cfg, **kw), q


def _flag(text: str, name: str) -> bool:
    """A yes/no URL query value (1/0, true/false, yes/no)."""
    value = {"1": True, "true": True, "yes": True, "0": False, "false": False, "no": False}.get(text.lower())
    if value is None:
        raise ValueError(f"link URL query {name}={text!r}: use {name}=1 or {name}=0")
    return value


def with_insecure(url: str) -> str:
    """``url`` with ``insecure=1`` (the explicit opt-out of authenticated frames)."""
    return f"{url}{'&' if '?' in url else '?'}insecure=1"


def keyed_url(url: str, secoc_key: str | None, signing_key: str | None = None) -> str:
    """One URL for both ends of a link on one machine (a rig, the demo, a benchmark): the SecOC key,
    the crane's public key (``signing_key`` + ``.pub``) for the laptop and its signing key for the
    controller (a laptop never uses ``signing_key=``). Without a signing key ``insecure=1`` opts out of
    signed answers; without any key, of authentication."""
    if secoc_key is None:
        return with_insecure(url)
    url = f"{url}{'&' if '?' in url else '?'}secoc_key={secoc_key}"
    if signing_key is None:
        return with_insecure(url)
    return f"{url}&crane_key={signing_key}.pub&signing_key={signing_key}"
