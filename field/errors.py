"""Error hierarchy of the field stack. Every error says what was wrong and what to do.

``FieldError`` is the root of every error raised by :mod:`field`. Link errors (the laptop <->
crane link, :mod:`field.link`) derive from :class:`LinkError`, in the python-can habit of one
root with initialisation / operation / timeout subclasses.
"""

from __future__ import annotations

from typing import Any

from synth.common.errors import LoggraspError


class FieldError(LoggraspError):
    """Root of every error raised by :mod:`field`."""


# --- crane link -----------------------------------------------------------------------------


class LinkError(FieldError):
    """The crane link failed: it could not be opened, a frame could not be sent, the bus or
    session reported an error. Check the link URL / cabling / Zenoh config and retry."""


class LinkTimeout(LinkError):
    """No answer (acknowledgement, outcome or status) arrived in time.

    ``status`` holds the controller status learned by the status query made after the timeout
    (``None`` when that query failed too: the controller is unreachable — check the crane on
    site before doing anything else).
    """

    def __init__(self, message: str, *, command_id: int | None = None, status: Any = None):
        super().__init__(message)
        self.command_id = command_id
        self.status = status


class CommandRejected(LinkError):
    """The controller (or the laptop-side safety checks, ``local=True``) refused a command.

    ``reason`` is a :class:`field.link.messages.RejectReason`; the command was NOT executed.
    Fix the cause named by the reason and send a NEW command (new command id).
    """

    def __init__(self, message: str, *, reason: Any, command_id: int | None = None, local: bool = False):
        super().__init__(message)
        self.reason = reason
        self.command_id = command_id
        self.local = local


class LinkClosed(LinkError):
    """The link was used after ``close()`` (or the peer vanished). Open a new link."""


class ProtocolError(LinkError):
    """A frame could not be encoded or decoded: a value out of the wire range, a wrong length,
    a failed end-to-end check or an unknown protocol version. ``reason`` (a
    :class:`field.link.messages.RejectReason` or ``None``) names the check that failed."""

    def __init__(self, message: str, *, reason: Any = None, integrity_ok: bool = False):
        super().__init__(message)
        self.reason = reason
        #: the frame passed its end-to-end (and, when on, authentication) check, so the ids in
        #: it are what the sender put there; a reply may name them. False: nothing in it counts.
        self.integrity_ok = integrity_ok


class AuthenticationError(ProtocolError):
    """An authenticated (SecOC-style) frame failed its check: wrong MAC, wrong length, a crane
    frame without the crane's signature, or a freshness value that is stale or seen before (a
    replay). The frame is dropped. ``check`` names which: ``"mac"``, ``"length"``, ``"key_id"``,
    ``"signature"`` or ``"freshness"``; ``"threshold"``: too many of them, the link failed."""

    def __init__(self, message: str, *, check: str = "mac", **kwargs: Any):
        super().__init__(message, **kwargs)
        self.check = check


class KeyFileError(LinkError):
    """The pre-shared key for authenticated frames could not be used: missing, unreadable, too
    short, or readable by group/others. The message names the file and how to fix it."""


# --- crane controller twin ------------------------------------------------------------------


class ControllerError(FieldError):
    """The crane controller twin could not start or run (bad config, unknown executor)."""
