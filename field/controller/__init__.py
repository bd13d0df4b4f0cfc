"""The crane controller twin: the crane's side of the link, speaking the protocol like a real one.

:class:`CraneController` is transport-agnostic protocol logic. A transport (CAN bus or Zenoh
session, :data:`field.link.base.CONTROLLER_TRANSPORTS`) feeds it frames with
:meth:`CraneController.on_frame` and sends what it answers / publishes. For every grasp command
it checks, in this order, and rejects with the first failing reason:

0. with a SecOC key: the frame's MAC and freshness (a failing frame is dropped unanswered);
   every frame it sends is secured and, with its signing key (``signing_key_path``, needed beside
   a SecOC key unless ``insecure_link``), signed, so no laptop's key file can pass for the crane
   (:mod:`field.link.signing`);
1. end-to-end CRC (CRC), frame length / reserved bits / version / field sanity (MALFORMED). A
   reply names the command id only when the frame passed its E2E check; otherwise it carries
   id 0, so no laptop ever takes the answer to a corrupted frame for the answer to its command;
2. rolling counter (a repeated counter = duplicated frame: dropped silently; a jump larger than
   ``counter_max_delta`` or backwards = COUNTER);
3. command id seen before — every id the controller has seen, accepted or rejected, is burned
   and never executed again; with ``journal_path`` also across restarts (the id is journaled
   *before* the answer goes out and before execution starts). An identical copy of a command
   it has decided on (a duplicated or late frame) gets that same decision again, never a second
   execution; another command under a used id gets DUPLICATE_ID. So the first answer a laptop
   gets for its command is always the controller's decision about it;
4. ESTOP / FAULT / BUSY state; then UNSUPERVISED when no live laptop sent it (CAN: no laptop
   with a fresh, in-sequence heartbeat stream; Zenoh: the sender named in the query has no
   liveliness token) - nothing runs that no laptop watches;
5. :func:`check_command`: pile data age (STALE), opening width (WIDTH_RANGE), heading
   (HEADING_RANGE), target log count (MALFORMED), reach envelope around the crane base in
   SWEREF 99 TM (OUT_OF_REACH: horizontal reach and height window).

Accepted commands run on a worker thread through an injected executor (see
:class:`GraspExecutor`), started under the same lock that accepted them, so an e-stop is either
before the acceptance (the command is refused ESTOP) or after it (the grasp is aborted, or never
starts): no e-stop is ever lost. The outcome is published and remembered in the status
(``last_outcome``).

Supervision: the controller sends a heartbeat (CAN: ``send_periodic``; Zenoh: a liveliness
token) and follows the laptops (:mod:`field.link.supervision`): on CAN a laptop is alive only
while its heartbeats are fresh and in sequence; on Zenoh while its liveliness token exists. A
command is accepted only from a live laptop, which becomes its *commanding peer* (CAN: the first
established live stream; Zenoh: the sender); once that peer is not live (no fresh heartbeat for
``laptop_timeout_s``, or its token gone) the grasp is aborted, whatever happened before and
whoever else is connected. A second laptop is reported (log warning, ``ControllerStatus.laptops``). An e-stop
frame latches ESTOP — fail-safe: any frame on the e-stop identifier stops, even one that fails
its CRC or MAC. Only a local :meth:`reset_estop` clears it.

Executors are registered by name in :data:`EXECUTORS` (imported when chosen): ``"fixed"``
(deterministic, here, for tests) and ``"pybullet"`` (:mod:`field.executor`, grasp trials on the
twin pile: ``make_executor("pybullet", pile="pile.json")``).

Run as its own process with :func:`run_controller` (a CLI calls it).
"""


from field.controller.config import (
    ControllerConfig,
    ReachEnvelope,
    check_age,
    check_command,
    check_heading,
    check_reach,
    check_target_count,
    check_width,
    controller_config_from_dict,
    controller_config_to_dict,
)
from field.controller.core import CraneController, Reply, command_digest
from field.controller.executors import (
    EXECUTION_LOG_FORMAT,
    EXECUTION_LOG_VERSION,
    EXECUTORS,
    FixedOutcomeExecutor,
    GraspExecutor,
    make_executor,
    read_execution_log,
)
from field.controller.journal import JOURNAL_FORMAT, JOURNAL_VERSION, ControllerJournal
from field.controller.runner import controller_in_thread, default_journal_path, run_controller

__all__ = [
    "EXECUTION_LOG_FORMAT",
    "EXECUTION_LOG_VERSION",
    "EXECUTORS",
    "JOURNAL_FORMAT",
    "JOURNAL_VERSION",
    "ControllerConfig",
    "ControllerJournal",
    "CraneController",
    "FixedOutcomeExecutor",
    "GraspExecutor",
    "ReachEnvelope",
    "Reply",
    "check_age",
    "check_command",
    "check_heading",
    "check_reach",
    "check_target_count",
    "check_width",
    "command_digest",
    "controller_config_from_dict",
    "controller_config_to_dict",
    "controller_in_thread",
    "default_journal_path",
    "make_executor",
    "read_execution_log",
    "run_controller",
]
