"""The soak's attackers and supervision faults, beside the random channel faults of
:class:`field.link.faults.ChaosChannel` (corruption, repetition, sequence, loss, delay).

:class:`Forger` makes the frames of the IEC 61784-3 classes a channel fault cannot make:

- ``insertion``: an E2E-valid frame from a node without the key (no SecOC trailer, or a random one);
- ``masquerade``: an E2E-valid frame MACed with a key no crane holds, or with the lane's own key
  file but the other direction's key (a laptop's key posing as the crane, and the reverse), or -
  toward the laptop - what a holder of a laptop's key file can make: the right MAC, but a
  signature not by the crane (random bytes, or another Ed25519 key's; on CAN its own frame);
- ``addressing``: a genuine frame of another crane (MACed with that crane's key), or a genuine
  frame of this lane sent under another kind's identifier / key expression.

Forged answers name the lane's latest command id (an attacker reads the bus), forged commands
fresh random ids. :class:`Outages` silences a lane's supervision for a while (CAN: the laptop's
heartbeat frames dropped, or frozen = the first one re-sent, a stuck sender; Zenoh: the
laptop's liveliness token withdrawn) and keeps the windows, so the soak can prove that nothing
ran while its laptop was not live.
"""

from __future__ import annotations

import collections
import hashlib
import hmac
import random
import secrets
import threading
import time
from typing import Callable

from field.link.codec import CraneHeartbeat, Encoder, LaptopHeartbeat, StatusRequest, authentic_length, frame_id
from field.link.messages import Ack, ControllerState, Outcome, OutcomeClass
from field.link.secoc import FV_BYTES, SecOC, _direction_key, load_key, secured_length

FORGED_CLASSES = ("insertion", "masquerade", "addressing")
TO_CRANE_FORGED = ("GraspCommand", "StatusRequest", "LaptopHeartbeat")
TO_LAPTOP_FORGED = ("Ack", "Outcome", "CraneHeartbeat")


class Forger:
    """Forged frames for one lane (key file ``key_path``; ``other_key_path``: another crane's)."""

    def __init__(self, key_path: str, other_key_path: str, make_cmd: Callable, seed: int,
                 to_crane_kinds: tuple[str, ...] = TO_CRANE_FORGED):
        self.own = SecOC.from_key_file(key_path)
        self.other = SecOC.from_key_file(other_key_path)
        self.foreign = SecOC(secrets.token_bytes(32))  # a key no crane holds
        from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

        from field.link.signing import AnswerSigner

        self.not_the_crane = AnswerSigner(Ed25519PrivateKey.generate(), "a laptop's own Ed25519 key")
        self._own_key = load_key(key_path)
        self._enc = Encoder()
        self._make_cmd = make_cmd
        self._rng = random.Random(seed)
        self.to_crane_kinds = to_crane_kinds

    def _plain(self, kind: str, last_id: int) -> bytes:
        r = self._rng
        msg = {"GraspCommand": lambda: self._make_cmd(r.randrange(1, 2**32)),
               "StatusRequest": lambda: StatusRequest(r.randrange(2**32)),
               "LaptopHeartbeat": lambda: LaptopHeartbeat(r.randrange(2**32)),
               "Ack": lambda: Ack(last_id or 1, True),
               "Outcome": lambda: Outcome(last_id or 1, OutcomeClass.SUCCESS, 2, 1000),
               "CraneHeartbeat": lambda: CraneHeartbeat(r.randrange(2**32), ControllerState.IDLE)}[kind]()
        return self._enc.encode(msg)[1]

    def frame(self, to_crane: bool, last_id: int) -> tuple[str, str, bytes]:
        """(class, kind to send under, frame bytes): one forged frame toward the crane or the laptop."""
        r = self._rng
        kinds = self.to_crane_kinds if to_crane else TO_LAPTOP_FORGED
        kind = r.choice(kinds)
        plain = self._plain(kind, last_id)
        cls = r.choice(FORGED_CLASSES)
        if cls == "insertion":
            if r.random() < 0.5:
                return cls, kind, plain  # no trailer at all
            n = authentic_length(kind)
            return cls, kind, plain[:n] + secrets.token_bytes(16) + bytes(secured_length(kind) - n - 16)
        if cls == "masquerade":
            x = r.random()
            if x < 1 / 3:
                return cls, kind, self.foreign.secure(kind, plain)
            if x < 2 / 3 or to_crane:
                return cls, kind, self._wrong_direction(kind, plain)
            secured = self.own.secure(kind, plain)  # a laptop's key file: the crane -> laptop MAC is right
            signature = secrets.token_bytes(64) if r.random() < 0.5 else self.not_the_crane.sign(kind, secured)
            return cls, kind, secured + signature
        if r.random() < 0.5 or len(kinds) < 2:
            return cls, kind, self.other.secure(kind, plain)  # another crane's genuine frame
        under = r.choice([k for k in kinds if k != kind])
        return cls, under, self.own.secure(kind, plain)  # this lane's genuine frame, misaddressed

    def _wrong_direction(self, kind: str, plain: bytes) -> bytes:
        """``plain`` secured as SecOC does, but with the other direction's key of the lane's file."""
        from field.link.secoc import _direction

        wrong = "crane->laptop" if _direction(kind) == "laptop->crane" else "laptop->crane"
        n = authentic_length(kind)
        pdu = plain[:n]
        fv = ((int(time.time() * 1000) << 16) | self._rng.randrange(256)).to_bytes(FV_BYTES, "little")
        mac = hmac.new(_direction_key(self._own_key, wrong), b"LGSECOC2" + frame_id(kind).to_bytes(2, "little") + pdu + fv,
                       hashlib.sha256).digest()[:8]
        out = pdu + fv + mac
        return out + bytes(secured_length(kind) - len(out))


class Intruder:
    """A thread sending ``Forger`` frames at random moments (mean ``period_s``) to both sides."""

    def __init__(self, forger: Forger, to_crane: Callable[[str, bytes], None], to_laptop: Callable[[str, bytes], None],
                 last_id: Callable[[], int], period_s: float, seed: int):
        self.forger, self._to_crane, self._to_laptop, self._last_id = forger, to_crane, to_laptop, last_id
        self.period_s = period_s
        self.injected: collections.Counter = collections.Counter()  # (class, "to crane"/"to laptop") -> count
        self._rng = random.Random(seed)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="soak-intruder", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self._rng.expovariate(1.0 / self.period_s)):
            to_crane = self._rng.random() < 0.5
            cls, kind, data = self.forger.frame(to_crane, self._last_id())
            try:
                (self._to_crane if to_crane else self._to_laptop)(kind, data)
            except Exception:  # the lane is closing
                return
            self.injected[(cls, "to crane" if to_crane else "to laptop")] += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)


class Outages:
    """A thread that silences a lane's supervision signal now and then; ``windows`` keeps
    ``(mode, t_off, t_on)`` in ``time.monotonic()`` seconds."""

    def __init__(self, silence: Callable[[str], None], restore: Callable[[], None], modes: tuple[str, ...],
                 every_s: float, length_s: tuple[float, float], seed: int):
        self._silence, self._restore, self.modes = silence, restore, modes
        self.every_s, self.length_s = every_s, length_s
        self.windows: list[tuple[str, float, float]] = []
        self._rng = random.Random(seed)
        self._stop = threading.Event()
        self._kick = threading.Event()
        self._thread = threading.Thread(target=self._run, name="soak-outages", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        # close() sets _stop before _kick: a kick cleared after an outage is never a stop missed (it
        # waited out join's 5 s once per lane closed during an outage)
        while not self._stop.is_set():
            self._kick.wait(self._rng.uniform(0.5, 1.5) * self.every_s)
            if self._stop.is_set():
                return
            mode = self._rng.choice(self.modes)
            self._silence(mode)
            t_off = time.monotonic()
            self._stop.wait(self._rng.uniform(*self.length_s))
            self._restore()
            self.windows.append((mode, t_off, time.monotonic()))
            self._kick.clear()

    def kick(self) -> None:
        """An outage now (unless one is on): e.g. while a grasp runs."""
        self._kick.set()

    def close(self) -> None:
        self._stop.set()
        self._kick.set()
        self._thread.join(5.0)
