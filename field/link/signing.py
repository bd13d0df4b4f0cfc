"""Signed crane answers: a laptop's key file cannot make crane frames.

A MAC cannot tell the crane from a laptop: the laptop verifies crane frames, and verifying a MAC
means computing it, so whoever holds a laptop's SecOC key file (:mod:`field.link.secoc`) could
make the crane's acknowledgements, outcomes, status and heartbeats. So every crane -> laptop
frame (:data:`field.link.codec.CRANE_TO_LAPTOP`) also carries an Ed25519 signature (RFC 8032,
64 bytes) made with a signing key only the crane holds; a laptop holds the crane's public key,
which verifies but cannot sign::

    signature = Ed25519(crane signing key, "LGSIGN1 crane->laptop" | frame id (uint16 LE)
                        | authentic PDU | freshness value)

over the same bytes the frame's SecOC MAC covers (the MAC stays: it keeps nodes without the key
file out cheaply, before a signature is checked). A crane frame is acted on only after MAC,
signature and freshness all pass; a failed signature is an :class:`AuthenticationError`
(``check="signature"``), dropped and counted like a failed MAC.

Carriage. Zenoh: the payload is the authenticated frame followed by its 64-byte signature.
CAN FD: 64 bytes do not fit beside a payload, so the data frame is followed by a **signature
frame** on the identifier of its kind (``AckSignature``, ``OutcomeSignature``, ``StatusSignature``,
``CraneHeartbeatSignature`` in loggrasp.dbc, each the identifier after its data frame's): the 64
signature bytes, nothing else. The crane sends the pair back to back (one lock: pairs never
interleave). The laptop keeps a data frame whose MAC passed as *pending* (never acted on) and
pairs it with the next signature frame of its kind:

* the signature verifies against a pending frame of that kind (newest first, at most
  :data:`PENDING_PER_KIND` held): that frame is delivered, then checked for freshness;
* it verifies against none of them (a forged signature, or one made for another data frame):
  the signature frame is dropped and counted as an authentication failure; the pending frames
  stay for their own signature;
* no pending frame of the kind (its data frame delayed behind it, or lost): the signature is
  held in turn, and a data frame arriving within ``signature_wait_s`` is checked against it;
  one never matched is dropped, counted in ``orphan_signatures``;
* a pending frame whose signature has not come within ``signature_wait_s``: dropped, counted in
  ``unsigned_dropped`` - a lost frame, which every path of the link already survives (a status
  query recovers an outcome, the supervision and the timeouts do the rest).

Key files (PEM, what ``openssl pkey`` reads): the crane's signing key is PKCS#8 (``loggrasp
link-key --crane-signing PATH`` writes PATH, mode 0600, refused if group or others may read it)
and its public key SubjectPublicKeyInfo (PATH.pub, which every laptop gets).
"""

from __future__ import annotations

import logging
import os
import stat
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from field.errors import AuthenticationError, KeyFileError, LinkError

log = logging.getLogger(__name__)

SIG_BYTES = 64  # an Ed25519 signature [bytes]
PENDING_PER_KIND = 4  # CAN: data frames of one kind held for their signature frames [-]
_LABEL = b"LGSIGN1 crane->laptop"
_CREATE = "create a pair with `loggrasp link-key --crane-signing PATH` (PATH for the crane, PATH.pub for laptops)"


# --- key files ------------------------------------------------------------------------------


def generate_signing_key(path: str | Path) -> tuple[Path, Path]:
    """Write a new Ed25519 signing key to ``path`` (PKCS#8 PEM, mode 0600) and its public key to
    ``path.pub``; refuses to overwrite either. Returns both paths."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    path = Path(path)
    pub = public_key_path(path)
    for p in (path, pub):
        if p.exists():
            raise KeyFileError(f"{p} exists; a key is never overwritten - remove it first or choose another path")
    key = Ed25519PrivateKey.generate()
    private = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                serialization.NoEncryption())
    public = key.public_key().public_bytes(serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo)
    path.parent.mkdir(parents=True, exist_ok=True)
    _write_new(pub, public, 0o644)
    try:
        _write_new(path, private, 0o600)
    except BaseException:
        pub.unlink(missing_ok=True)  # nothing half-written: no public key without its private one
        raise
    return path, pub


def public_key_path(path: str | Path) -> Path:
    """Where ``link-key --crane-signing PATH`` writes the public key: ``PATH.pub``."""
    path = Path(path)
    return path.with_name(path.name + ".pub")


def _write_new(path: Path, data: bytes, mode: int) -> None:
    """Write ``data`` to a new file (O_EXCL, ``mode``): complete, or removed."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    except FileExistsError as exc:
        raise KeyFileError(f"{path} exists; a key is never overwritten - remove it first") from exc
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    except BaseException:
        path.unlink(missing_ok=True)
        raise


def _read(path: Path, what: str, flag: str) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise KeyFileError(f"{what} {path} cannot be read ({exc.strerror}); fix {flag} or {_CREATE}") from exc


def load_signing_key(path: str | Path) -> Any:
    """The crane's Ed25519 signing key from ``path`` (``signing_key=`` in the crane's URL).
    Refuses a file group or others may read, a public key, and anything but an Ed25519 key."""
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
    from cryptography.hazmat.primitives.serialization import load_pem_private_key

    path = Path(path)
    data = _read(path, "crane signing key", "signing_key=")
    if b"PUBLIC KEY-----" in data:
        raise KeyFileError(f"signing_key={path} is a public key; the crane needs its private signing key "
                           f"(the file without .pub)")
    if stat.S_IMODE(path.stat().st_mode) & (stat.S_IRWXG | stat.S_IRWXO):
        raise KeyFileError(f"crane signing key {path} is accessible by group/others (mode "
                           f"{stat.S_IMODE(path.stat().st_mode):04o}); run `chmod 600 {path}`")
    try:
        key = load_pem_private_key(data, password=None)
    except (ValueError, TypeError) as exc:
        raise KeyFileError(f"crane signing key {path} is not a PEM private key without a password; {_CREATE}") from exc
    if not isinstance(key, Ed25519PrivateKey):
        raise KeyFileError(f"crane signing key {path} is a {type(key).__name__}, not Ed25519; {_CREATE}")
    return key


def load_public_key(path: str | Path) -> Any:
    """The crane's Ed25519 public key from ``path`` (``crane_key=`` in the laptop's URL). Refuses a
    private key: a laptop must never hold what signs the crane's answers."""
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey
    from cryptography.hazmat.primitives.serialization import load_pem_public_key

    path = Path(path)
    data = _read(path, "crane public key", "crane_key=")
    if b"PRIVATE KEY-----" in data:
        raise KeyFileError(f"crane_key={path} is the crane's PRIVATE signing key; a laptop gets only the public "
                           f"key ({public_key_path(path).name}) - move this file back to the crane")
    try:
        key = load_pem_public_key(data)
    except (ValueError, TypeError) as exc:
        raise KeyFileError(f"crane public key {path} is not a PEM public key; {_CREATE}") from exc
    if not isinstance(key, Ed25519PublicKey):
        raise KeyFileError(f"crane public key {path} is a {type(key).__name__}, not Ed25519; {_CREATE}")
    return key


# --- signing and verifying ------------------------------------------------------------------


def signed_bytes(kind: str, secured: bytes) -> bytes:
    """What a signature covers: label | frame id | authentic PDU | freshness value."""
    from field.link.codec import authentic_length, frame_id
    from field.link.secoc import FV_BYTES

    n = authentic_length(kind) + FV_BYTES
    return _LABEL + frame_id(kind).to_bytes(2, "little") + bytes(secured[:n])


class AnswerSigner:
    """The crane's side: the signature of an authenticated crane -> laptop frame."""

    def __init__(self, key: Any, source: str = "<key>"):
        self._key = key
        self.source = source

    @classmethod
    def from_file(cls, path: str | Path) -> "AnswerSigner":
        return cls(load_signing_key(path), str(path))

    def __repr__(self) -> str:  # never the key
        return f"<AnswerSigner key={self.source}>"

    def sign(self, kind: str, secured: bytes) -> bytes:
        return self._key.sign(signed_bytes(kind, secured))


class AnswerVerifier:
    """The laptop's side: checks a crane frame's signature with the crane's public key."""

    def __init__(self, public_key: Any, source: str = "<key>"):
        self._key = public_key
        self.source = source

    @classmethod
    def from_file(cls, path: str | Path) -> "AnswerVerifier":
        return cls(load_public_key(path), str(path))

    def check(self, kind: str, secured: bytes, signature: bytes) -> AuthenticationError | None:
        """None when ``signature`` is the crane's over ``secured``, else why not."""
        from cryptography.exceptions import InvalidSignature

        try:
            self._key.verify(bytes(signature), signed_bytes(kind, secured))
        except InvalidSignature:
            return AuthenticationError(f"{kind}: the crane's signature does not verify with {self.source} (a forged "
                                       f"crane frame - made with a laptop's key file? - or a signature for another "
                                       f"frame)", check="signature")
        return None


def carriage_frames(kind: str, data: bytes) -> list[tuple[str, bytes]]:
    """The CAN FD frames of one crane -> laptop ``data``: the frame itself, and its signature frame
    when ``data`` ends in a signature (a frame's authenticated length + 64 bytes)."""
    from field.link.codec import SIGNATURE_KIND
    from field.link.secoc import secured_length

    if kind in SIGNATURE_KIND and len(data) == secured_length(kind) + SIG_BYTES:
        return [(kind, bytes(data[:-SIG_BYTES])), (SIGNATURE_KIND[kind], bytes(data[-SIG_BYTES:]))]
    return [(kind, bytes(data))]


# --- the laptop's check of crane frames ------------------------------------------------------


@dataclass
class _Pending:
    secured: bytes  # the data frame as received (MAC checked); for a held signature: the signature
    plain: bytes  # what it carries (empty for a held signature)
    since_s: float  # monotonic arrival time [s]


class AnswerCheck:
    """SecOC (MAC, freshness) and, with the crane's public key, its signature on crane frames.

    ``inline`` (Zenoh): :meth:`unwrap` gets ``frame | signature``. Otherwise (CAN): :meth:`unwrap`
    holds a data frame as pending and :meth:`on_signature` pairs a signature frame with it (or
    holds a signature that came first). Counters: ``unsigned_dropped`` (a data frame whose
    signature never came within ``wait_s``), ``orphan_signatures`` (a signature frame that no
    data frame matched within ``wait_s``)."""

    def __init__(self, secoc: Any, verifier: AnswerVerifier | None, *, inline: bool, wait_s: float,
                 clock: Callable[[], float] = time.monotonic, max_failures: int = 20, failure_window_s: float = 10.0):
        if not wait_s > 0:
            raise ValueError(f"signature_wait_s must be > 0 s, got {wait_s}")
        self.max_failures, self.failure_window_s = max_failures, failure_window_s
        self._failures: deque[float] = deque()  # clock times of recent MAC / signature / key id failures [s]
        self.secoc = secoc
        self.verifier = verifier
        self.inline = inline
        self.wait_s = wait_s
        self._clock = clock
        self._pending: dict[str, deque[_Pending]] = {}  # data frames waiting for their signature
        self._early: dict[str, deque[_Pending]] = {}  # signature frames that came before their data frame
        self._lock = threading.Lock()
        self.unsigned_dropped = 0
        self.orphan_signatures = 0

    def unwrap(self, kind: str, data: bytes) -> tuple[bytes | None, AuthenticationError | None]:
        """A received crane frame as plain bytes; ``(None, why)`` when it fails a check, ``(None,
        None)`` when it is held for its signature frame (CAN)."""
        from field.link.secoc import unwrap

        if self.verifier is None:
            if self.inline and self.secoc is not None and _ends_in_signature(kind, data):
                data = data[:-SIG_BYTES]  # the operator opted out of checking the crane's signatures
            return unwrap(self.secoc, kind, data)
        if self.inline:
            if not _ends_in_signature(kind, data):
                return None, AuthenticationError(f"{kind}: {len(data)} bytes, a signed crane frame has "
                                                 f"{_signed_length(kind)} (does the crane sign its answers?)",
                                                 check="length")
            return self._checked(kind, bytes(data[:-SIG_BYTES]), bytes(data[-SIG_BYTES:]))
        plain, why = self._mac(kind, data)
        if plain is None:
            return None, why
        with self._lock:
            early = self._expire(self._early, kind, "orphan_signatures")
            match = next((e for e in reversed(early) if self.verifier.check(kind, data, e.secured) is None), None)
            if match is None:
                self._hold(kind, _Pending(bytes(data), plain, self._clock()))
                return None, None
            early.remove(match)
        return self._fresh(kind, bytes(data), plain)

    def on_signature(self, kind: str, signature: bytes) -> tuple[bytes | None, AuthenticationError | None]:
        """CAN: the signature frame of a ``kind`` frame: the plain frame it releases, or why not."""
        if self.verifier is None:
            return None, None  # signatures are not checked (opted out): the data frame went through
        if len(signature) != SIG_BYTES:
            return None, AuthenticationError(f"{kind}: a signature frame of {len(signature)} bytes, need {SIG_BYTES}",
                                             check="length")
        with self._lock:
            pending = self._expire(self._pending, kind, "unsigned_dropped")
            if not pending:  # its data frame is late (or lost): hold the signature for it
                self._keep(self._expire(self._early, kind, "orphan_signatures"),
                           _Pending(bytes(signature), b"", self._clock()), "orphan_signatures")
                return None, None
            match = next((p for p in reversed(pending)
                          if self.verifier.check(kind, p.secured, signature) is None), None)
            if match is None:
                return None, AuthenticationError(f"{kind}: a signature frame matches none of the {len(pending)} "
                                                 f"{kind} frame(s) waiting for theirs (forged, or made for another "
                                                 f"frame)", check="signature")
            pending.remove(match)
        return self._fresh(kind, match.secured, match.plain)

    def count_failure(self, why: AuthenticationError) -> str | None:
        """Count one crane frame that failed its check; past ``max_failures`` MAC, signature or key id
        failures within ``failure_window_s``, why the link must fail (stale frames do not count: a
        clock or a replay, not a forger)."""
        if why.check == "freshness":
            return None
        now = self._clock()
        with self._lock:
            window = self._failures
            window.append(now)
            while window and now - window[0] > self.failure_window_s:
                window.popleft()
            if len(window) <= self.max_failures:
                return None
        return (f"{len(window)} crane frames failed their MAC or the crane's signature within "
                f"{self.failure_window_s:g} s (limit {self.max_failures}): a node is forging the crane's answers, or "
                f"this laptop's secoc_key= / crane_key= are not this crane's - check the bus / network and the key "
                f"files, then open a new link")

    def expire(self) -> None:
        """Drop (and count) every held frame and signature past the wait, of every kind (a
        receiver calls it on each frame: a crane heartbeat comes every period)."""
        with self._lock:
            for kind in list(self._pending):
                self._expire(self._pending, kind, "unsigned_dropped")
            for kind in list(self._early):
                self._expire(self._early, kind, "orphan_signatures")

    def _checked(self, kind: str, secured: bytes, signature: bytes) -> tuple[bytes | None, AuthenticationError | None]:
        plain, why = self._mac(kind, secured)
        if plain is None:
            return None, why
        why = self.verifier.check(kind, secured, signature)
        return (None, why) if why is not None else self._fresh(kind, secured, plain)

    def _mac(self, kind: str, data: bytes) -> tuple[bytes | None, AuthenticationError | None]:
        try:
            return self.secoc.verify(kind, data, check_freshness=False), None
        except AuthenticationError as exc:
            return None, exc

    def _fresh(self, kind: str, secured: bytes, plain: bytes) -> tuple[bytes | None, AuthenticationError | None]:
        why = self.secoc.check_freshness(kind, secured)
        return (None, why) if why is not None else (plain, None)

    def _hold(self, kind: str, entry: _Pending) -> None:
        """Keep a data frame for its signature (under ``_lock``)."""
        pending = self._expire(self._pending, kind, "unsigned_dropped")
        if all(p.secured != entry.secured for p in pending):  # a copy of a waiting frame: released once
            self._keep(pending, entry, "unsigned_dropped")

    def _keep(self, held: deque[_Pending], entry: _Pending, counter: str) -> None:
        if len(held) >= PENDING_PER_KIND:  # the oldest gives way, counted as never matched
            held.popleft()
            setattr(self, counter, getattr(self, counter) + 1)
        held.append(entry)

    def _expire(self, held: dict[str, deque[_Pending]], kind: str, counter: str) -> deque[_Pending]:
        """The held entries of ``kind`` still inside the wait; the others dropped and counted in
        ``counter`` (under ``_lock``)."""
        entries = held.setdefault(kind, deque())
        now = self._clock()
        while entries and now - entries[0].since_s > self.wait_s:
            entries.popleft()
            setattr(self, counter, getattr(self, counter) + 1)
        return entries


def _signed_length(kind: str) -> int:
    from field.link.secoc import secured_length

    return secured_length(kind) + SIG_BYTES


def _ends_in_signature(kind: str, data: bytes) -> bool:
    return len(data) == _signed_length(kind)


# --- loading the keys of each end ------------------------------------------------------------


def load_answer_check(config: Any, clock: Callable[[], float], backend: str, requires_key: bool,
                      inline: bool) -> AnswerCheck:
    """The laptop's :class:`AnswerCheck` from a :class:`~field.link.link_config.LinkConfig`: refused
    without a SecOC key or without the crane's public key, unless ``insecure`` opts out."""
    secoc = None
    if config.secoc_key_path is None:
        if config.crane_key_path is not None:
            raise LinkError(f"crane_key={config.crane_key_path} needs secoc_key=KEYFILE too: a crane's signature "
                            f"covers its authenticated frames")
        if requires_key and not config.insecure:
            raise LinkError(
                f"the {backend} link has no SecOC key: without one any node on the bus can forge commands and the "
                f"crane's answers. Give both ends a key (secoc_key=KEYFILE in the URL; create one with `loggrasp "
                f"link-key KEYFILE`), or opt out explicitly with insecure=1 in the URL (--insecure-link)")
        if requires_key:
            log.warning("the %s link runs WITHOUT authentication (insecure=1): any node on the bus can forge "
                        "commands and the crane's answers", backend)
    else:
        from field.link.secoc import SecOC

        secoc = SecOC.from_key_file(config.secoc_key_path, window_s=config.secoc_window_s, clock=clock)
    verifier = None
    if config.crane_key_path is not None:
        verifier = AnswerVerifier.from_file(config.crane_key_path)
    elif secoc is not None and requires_key and not config.insecure:
        raise LinkError(
            f"the {backend} link has no crane public key: with the SecOC key alone, whoever holds a laptop's key "
            f"file can forge the crane's answers. Add crane_key=CRANE.pub to the URL (`loggrasp link-key "
            f"--crane-signing CRANE` writes the pair; the crane uses signing_key=CRANE), or opt out explicitly "
            f"with insecure=1 in the URL (--insecure-link)")
    elif secoc is not None and requires_key:
        log.warning("the %s link does NOT check the crane's signatures (insecure=1): whoever holds a laptop's key "
                    "file can forge the crane's answers", backend)
    return AnswerCheck(secoc, verifier, inline=inline, wait_s=config.signature_wait_s,
                       max_failures=config.max_auth_failures, failure_window_s=config.auth_failure_window_s)


def load_crane_keys(config: Any, clock: Callable[[], float]) -> tuple[Any, AnswerSigner | None]:
    """The controller's (SecOC, signer) from a :class:`~field.controller.ControllerConfig`: a key
    and a signing key, or the explicit opt-out ``insecure_link`` (logged)."""
    from field.errors import ControllerError

    if config.secoc_key_path is None:
        if not config.insecure_link:
            raise ControllerError("a crane controller needs a SecOC key (ControllerConfig.secoc_key_path, or "
                                  "secoc_key=KEYFILE in the link URL): without one any node on the bus can "
                                  "command the crane. Opt out explicitly with insecure_link=True (URL insecure=1, "
                                  "crane-sim --insecure-link)")
        log.warning("crane controller WITHOUT authentication (insecure_link=True): any node on the bus can "
                    "command the crane")
        return None, None
    from field.link.secoc import SecOC

    secoc = SecOC.from_key_file(config.secoc_key_path, window_s=config.secoc_window_s, clock=clock)
    if config.signing_key_path is not None:
        return secoc, AnswerSigner.from_file(config.signing_key_path)
    if not config.insecure_link:
        raise ControllerError("a crane controller with a SecOC key needs its signing key too "
                              "(ControllerConfig.signing_key_path, or signing_key=PATH in the link URL; `loggrasp "
                              "link-key --crane-signing PATH` writes it): without it laptops cannot tell its answers "
                              "from a laptop's forgeries. Opt out explicitly with insecure_link=True (URL insecure=1, "
                              "crane-sim --insecure-link)")
    log.warning("crane controller answers NOT signed (insecure_link=True): whoever holds a laptop's key file can "
                "forge them")
    return secoc, None
