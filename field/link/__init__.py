"""The laptop <-> crane link: one seam, backends chosen by URL (``can://``, ``zenoh://``, ``twin://``).

Importing this package loads neither python-can nor zenoh; a backend is imported when
:func:`open_link` chooses it. See :mod:`field.link.base` for the URL forms and
:mod:`field.link.codec` for the wire format (``loggrasp.dbc``).
"""

from field.link.base import (
    BACKENDS,
    CONTROLLER_TRANSPORTS,
    CommandFate,
    CraneLink,
    LinkConfig,
    LinkStats,
    open_link,
    open_resources,
)
from field.link.messages import (
    Ack,
    ControllerState,
    ControllerStatus,
    GraspCommand,
    Outcome,
    OutcomeClass,
    RejectReason,
)
from field.link.safety import SafetyConfig

__all__ = [
    "BACKENDS",
    "CONTROLLER_TRANSPORTS",
    "Ack",
    "CommandFate",
    "ControllerState",
    "ControllerStatus",
    "CraneLink",
    "GraspCommand",
    "LinkConfig",
    "LinkStats",
    "Outcome",
    "OutcomeClass",
    "RejectReason",
    "SafetyConfig",
    "open_link",
    "open_resources",
]
