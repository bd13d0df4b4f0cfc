"""Authenticated frames in the style of AUTOSAR SecOC: origin, not only integrity.

E2E (:mod:`field.link.codec`) detects corruption, but anyone on the bus can compute a CRC: a
node that should not speak could forge a "success" outcome or a command. With a pre-shared key
every frame carries a freshness value and a truncated MAC, and a receiver drops any frame whose
MAC or freshness does not check out (SecOC's "verification failed" → PDU dropped).

Secured frame layout (all CAN FD lengths, little-endian)::

    [0, A)        the authentic PDU: the frame's bytes up to the last one a DBC signal uses
                  (E2E header included; the DBC's reserved tail is not sent and reads as zero)
    [A, A+8)      freshness value (uint64): sender clock in ms << 16 | key id << 8 | a per-ms
                  sequence (8 bits)
    [A+8, A+16)   MAC: HMAC-SHA256(K_dir, "LGSECOC2" | frame id (uint16) | authentic PDU | FV),
                  truncated to its first 8 bytes (64 bits); K_dir = HMAC-SHA256(key[key id],
                  "LGSECOC2 direction " | "laptop->crane" or "crane->laptop"), the frame kind's
                  direction (an HKDF-Expand step; the file's keys are uniformly random, so no
                  extract step is needed)
    [A+16, L)     zero padding up to the next CAN FD length L

The freshness value is time-based and strictly increasing per sender, so a receiver accepts a
frame only when its FV lies within ``window_s`` of the receiver's clock and was not seen
before: replayed, duplicated and long-delayed frames all fail, across restarts too. This needs
the laptop and the crane clocks to agree within ``window_s`` (GNSS time on a real crane; the
plan timestamps already need it). The key is 32 random bytes, stored hex-encoded in a file
only its owner can read (mode 0600); it is never logged or shown.

Key rotation without downtime: a key file may hold several keys, one ``KEY_ID HEX`` per line
(key id 0-255; a file of one bare hex line is key id 0). A node sends with the first key and
accepts every key in its file; the key id travels in the freshness value. Rotate by (1) adding
the new key as a second line on every node, (2) moving it to the first line on every node (each
node sends with it while the others still accept the old one), (3) removing the old line. A
frame naming a key id the receiver does not hold fails (``check="key_id"``).

Per-direction keys: the MAC key of a frame is derived from the file's key and the frame's
direction, so a laptop frame can never pass as a crane frame under any identifier. A MAC alone
does not stop a holder of the file from making crane frames (the laptop, which must verify
crane frames, can also compute them): crane frames are therefore also signed with a key only
the crane holds (:mod:`field.link.signing`).
"""

from __future__ import annotations

import functools
import hashlib
import hmac
import os
import secrets
import stat
import threading
import time
from collections import deque
from pathlib import Path
from typing import Callable

from field.errors import AuthenticationError, KeyFileError
from synth.common.files import atomic_write_bytes

MAC_BYTES = 8  # truncated MAC length [bytes]
FV_BYTES = 8  # freshness value length [bytes]
TRAILER_BYTES = FV_BYTES + MAC_BYTES
KEY_BYTES = 32  # generated key length [bytes]
MIN_KEY_BYTES = 16  # shortest key accepted [bytes]
DEFAULT_WINDOW_S = 2.0  # freshness window: |FV time - receiver clock| allowed [s]
FD_LENGTHS = (8, 12, 16, 20, 24, 32, 48, 64)
_LABEL = b"LGSECOC2"
MAX_KEY_ID = 255  # key ids travel in 8 bits of the freshness value [-]


@functools.lru_cache(maxsize=None)
def secured_length(kind: str) -> int:
    """Length of the authenticated frame of ``kind`` [bytes]: the next CAN FD length."""
    from field.link.codec import authentic_length

    need = authentic_length(kind) + TRAILER_BYTES
    for n in FD_LENGTHS:
        if n >= need:
            return n
    raise ValueError(f"{kind}: {need} bytes do not fit one CAN FD frame")


# --- the key file ---------------------------------------------------------------------------


def load_key(path: str | Path) -> bytes:
    """The key a node sends with (the first in ``path``); see :func:`load_keys`."""
    key_id, keys = load_keys(path)
    return keys[key_id]


def load_keys(path: str | Path) -> tuple[int, dict[int, bytes]]:
    """(the key id this node sends with, every key it accepts by id) from ``path``: one bare hex
    key (id 0), or ``KEY_ID HEX`` lines, the first the sending key (``#`` starts a comment).
    Refuses a file group or others may read."""
    path = Path(path)
    try:
        st = path.stat()
    except OSError as exc:
        raise KeyFileError(f"SecOC key file {path} cannot be read ({exc.strerror}); create one with "
                           f"`loggrasp link-key {path}` or fix the --secoc-key / secoc_key= path") from exc
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise KeyFileError(f"SecOC key file {path} is accessible by group/others (mode "
                           f"{stat.S_IMODE(st.st_mode):04o}); run `chmod 600 {path}`")
    try:
        lines = [ln.split("#", 1)[0].split() for ln in path.read_text().splitlines()]
        entries = [(0, ln[0]) if len(ln) == 1 else (int(ln[0]), ln[1]) for ln in lines if ln]
        if not entries or any(len(ln) > 2 for ln in lines):
            raise ValueError("no key")
        keys = {kid: bytes.fromhex(text) for kid, text in entries}
    except (OSError, ValueError) as exc:
        raise KeyFileError(f"SecOC key file {path} does not hold a hex key (or KEY_ID HEX lines); create a new one "
                           f"with `loggrasp link-key {path}`") from exc
    if len(keys) != len(entries) or not all(0 <= kid <= MAX_KEY_ID for kid in keys):
        raise KeyFileError(f"SecOC key file {path}: key ids must be distinct, in 0..{MAX_KEY_ID}")
    for kid, key in keys.items():
        if len(key) < MIN_KEY_BYTES:
            raise KeyFileError(f"SecOC key {kid} in {path} is {len(key)} bytes, need at least {MIN_KEY_BYTES}; "
                               f"create a new one with `loggrasp link-key {path}`")
    return entries[0][0], keys


def generate_key_file(path: str | Path) -> Path:
    """Write a new random key to ``path`` (mode 0600, refuses to overwrite)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError as exc:
        raise KeyFileError(f"{path} exists; a key is never overwritten - remove it first or choose "
                           f"another path") from exc
    with os.fdopen(fd, "w") as f:
        f.write(secrets.token_hex(KEY_BYTES) + "\n")
    return path


def add_key(path: str | Path) -> int:
    """Add a new random key to the key file ``path`` as its last ``KEY_ID HEX`` line (the next free key
    id; the sending key, the first line, stays) - step 1 of a rotation. The file is replaced whole
    (mode 0600), never left half-written. Returns the new key id."""
    path = Path(path)
    sending, keys = load_keys(path)  # refuses an unreadable, open or malformed file first
    new_id = next((kid for kid in range(max(keys) + 1, MAX_KEY_ID + 1)), None)
    if new_id is None:
        new_id = next((kid for kid in range(MAX_KEY_ID + 1) if kid not in keys), None)
    if new_id is None:
        raise KeyFileError(f"SecOC key file {path} holds {len(keys)} keys, every key id in 0..{MAX_KEY_ID}; remove "
                           f"old lines first")
    order = [sending, *(kid for kid in keys if kid != sending)]
    text = "".join(f"{kid} {keys[kid].hex()}\n" for kid in order) + f"{new_id} {secrets.token_hex(KEY_BYTES)}\n"
    atomic_write_bytes(path, text.encode(), mode=0o600)  # mkstemp makes it 0600 from the start
    return new_id


# --- freshness ------------------------------------------------------------------------------


class FreshnessCounter:
    """A sender's freshness values: ``clock ms << 16 | key id << 8 | sequence``, strictly
    increasing for one key id (the sequence starts at random in a new millisecond; past 255 the
    millisecond moves on)."""

    def __init__(self, clock: Callable[[], float] = time.time):
        self._clock = clock
        self._last_ms, self._last_seq = 0, 0
        self._lock = threading.Lock()

    def next(self, key_id: int = 0) -> int:
        with self._lock:
            ms = int(self._clock() * 1000)
            if ms > self._last_ms:
                seq = secrets.randbits(7)
            else:
                ms, seq = self._last_ms, self._last_seq + 1
                if seq > 0xFF:
                    ms, seq = ms + 1, 0
            self._last_ms, self._last_seq = ms, seq
            return ms << 16 | (key_id & 0xFF) << 8 | seq


class ReplayGuard:
    """A receiver's freshness check per message kind: inside the window, never seen before."""

    def __init__(self, window_s: float, clock: Callable[[], float] = time.time):
        self.window_s = window_s
        self._clock = clock
        self._seen: dict[str, set[int]] = {}
        self._order: dict[str, deque[int]] = {}
        self._lock = threading.Lock()

    def check(self, kind: str, fv: int) -> str | None:
        """``None`` if fresh (and remember it), else why not."""
        skew = (fv >> 16) / 1000.0 - self._clock()
        if abs(skew) > self.window_s:
            return (f"freshness value {skew:+.2f} s off this clock (window {self.window_s:.1f} s): a "
                    f"delayed or replayed frame, or the two clocks disagree")
        with self._lock:
            seen = self._seen.setdefault(kind, set())
            if fv in seen:
                return "freshness value seen before: a duplicated or replayed frame"
            order = self._order.setdefault(kind, deque())
            seen.add(fv)
            order.append(fv)
            oldest = (int((self._clock() - 2 * self.window_s) * 1000)) << 16
            while order and order[0] < oldest:
                seen.discard(order.popleft())
        return None


# --- securing and verifying -----------------------------------------------------------------


class SecOC:
    """Secure outgoing frames (with key ``key_id``) and verify incoming ones (with any key in
    ``accept``, by the key id a frame names; default: ``key`` alone)."""

    def __init__(self, key: bytes, *, window_s: float = DEFAULT_WINDOW_S, clock: Callable[[], float] = time.time,
                 source: str = "<key>", key_id: int = 0, accept: dict[int, bytes] | None = None):
        keys = {**(accept or {}), key_id: key}
        if any(len(k) < MIN_KEY_BYTES for k in keys.values()):
            raise KeyFileError(f"a SecOC key from {source} is shorter than {MIN_KEY_BYTES} bytes")
        if not window_s > 0:
            raise ValueError(f"SecOC freshness window must be > 0 s, got {window_s}")
        self.key_id = key_id
        self._keys = {(kid, d): _direction_key(k, d) for kid, k in keys.items() for d in _DIRECTIONS}
        self.source = source
        self.window_s = window_s
        self._fv = FreshnessCounter(clock)
        self._replay = ReplayGuard(window_s, clock)

    @classmethod
    def from_key_file(cls, path: str | Path, **kwargs) -> "SecOC":
        key_id, keys = load_keys(path)
        return cls(keys[key_id], source=str(path), key_id=key_id, accept=keys, **kwargs)

    def __repr__(self) -> str:  # never the key
        return f"<SecOC key={self.source} window={self.window_s:g}s>"

    def _mac(self, kind: str, pdu: bytes, fv: bytes) -> bytes:
        """The MAC of a frame under the key its FV names (AuthenticationError: a key not held)."""
        from field.link.codec import frame_id

        kid = (int.from_bytes(fv, "little") >> 8) & 0xFF
        key = self._keys.get((kid, _direction(kind)))
        if key is None:
            raise AuthenticationError(f"{kind}: key id {kid} is not in this node's key file {self.source} "
                                      f"(a rotated key not installed here yet, or a foreign one)", check="key_id")
        msg = _LABEL + frame_id(kind).to_bytes(2, "little") + pdu + fv
        return hmac.new(key, msg, hashlib.sha256).digest()[:MAC_BYTES]

    def secure(self, kind: str, frame: bytes) -> bytes:
        """The authenticated frame for an E2E-protected ``frame`` of ``kind``."""
        from field.link.codec import authentic_length

        n = authentic_length(kind)
        pdu = bytes(frame[:n])
        fv = self._fv.next(self.key_id).to_bytes(FV_BYTES, "little")
        out = pdu + fv + self._mac(kind, pdu, fv)
        return out + bytes(secured_length(kind) - len(out))

    def verify(self, kind: str, data: bytes, *, check_freshness: bool = True) -> bytes:
        """The plain frame (DBC length) inside an authenticated one; raises
        :class:`AuthenticationError` (the frame must be dropped)."""
        from field.link.codec import _message, authentic_length

        n = authentic_length(kind)
        if len(data) != secured_length(kind):
            raise AuthenticationError(f"{kind}: {len(data)} bytes, an authenticated frame has "
                                      f"{secured_length(kind)} (is the other side running without the key?)",
                                      check="length")
        pdu, fv, mac = bytes(data[:n]), bytes(data[n:n + FV_BYTES]), bytes(data[n + FV_BYTES:n + TRAILER_BYTES])
        if not hmac.compare_digest(mac, self._mac(kind, pdu, fv)) or any(data[n + TRAILER_BYTES:]):
            raise AuthenticationError(f"{kind}: MAC check failed (forged or corrupted frame, or another key)")
        if check_freshness:
            why = self._replay.check(kind, int.from_bytes(fv, "little"))
            if why is not None:
                raise AuthenticationError(f"{kind}: {why}", check="freshness")
        return pdu + bytes(_message(kind).length - n)

    def check_freshness(self, kind: str, data: bytes) -> AuthenticationError | None:
        """The freshness check of an authenticated frame whose MAC :meth:`verify` passed without it
        (a signed crane frame is checked, and its freshness value remembered, once its signature
        verified): None if fresh, else why not."""
        from field.link.codec import authentic_length

        n = authentic_length(kind)
        why = self._replay.check(kind, int.from_bytes(bytes(data[n:n + FV_BYTES]), "little"))
        return None if why is None else AuthenticationError(f"{kind}: {why}", check="freshness")


_DIRECTIONS = ("laptop->crane", "crane->laptop")


def _direction(kind: str) -> str:
    from field.link.codec import CRANE_TO_LAPTOP

    return _DIRECTIONS[1] if kind in CRANE_TO_LAPTOP else _DIRECTIONS[0]


def _direction_key(key: bytes, direction: str) -> bytes:
    """The MAC key of one direction: an HKDF-Expand step (one block) over the file's key."""
    return hmac.new(key, _LABEL + b" direction " + direction.encode() + b"\x01", hashlib.sha256).digest()


def unwrap(secoc: SecOC | None, kind: str, data: bytes) -> tuple[bytes | None, AuthenticationError | None]:
    """A received frame of ``kind`` as plain bytes: ``data`` itself on a link without a key, else what
    :meth:`SecOC.verify` finds inside it; ``(None, why)`` for a frame that fails the check (it is dropped,
    and the caller counts and reports ``why``)."""
    if secoc is None:
        return data, None
    try:
        return secoc.verify(kind, data), None
    except AuthenticationError as exc:
        return None, exc
