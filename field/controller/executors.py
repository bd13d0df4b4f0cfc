"""What the controller runs for an accepted command: the executor protocol and its registry.

Executors are registered by name in :data:`EXECUTORS` (imported when chosen): ``"fixed"``
(deterministic, here, for tests) and ``"pybullet"`` (:mod:`field.executor`, grasp trials on the
twin pile: ``make_executor("pybullet", pile="pile.json")``).
"""

from __future__ import annotations

import importlib
import json
import os
import time
from pathlib import Path
from typing import Any, Callable, Protocol, runtime_checkable

from field.errors import ControllerError
from field.link.messages import GraspCommand, Outcome, OutcomeClass

EXECUTION_LOG_FORMAT = "loggrasp.execution_log"
EXECUTION_LOG_VERSION = "1.0"


@runtime_checkable
class GraspExecutor(Protocol):
    """What the controller runs for an accepted command.

    ``execute(cmd, should_abort) -> Outcome`` executes the grasp (blocking; called on a worker
    thread, one command at a time) and returns its outcome for ``cmd.command_id``.
    ``should_abort()`` turns True once the grasp must stop (e-stop, commanding laptop lost,
    shutdown): the executor polls it, stops promptly and returns the true state (logs held at
    that moment). The controller reports ``ABORTED`` whatever class it returns then. Raising
    marks the controller FAULT (outcome ABORTED).

    A plain callable ``cmd -> Outcome`` is accepted too; it cannot be stopped (an ``abort()``
    method on it is called on abort).
    """

    def execute(self, cmd: GraspCommand, should_abort: Callable[[], bool]) -> Outcome: ...


#: executor name -> "module:Class" (imported when chosen, so pybullet loads only for "pybullet").
EXECUTORS: dict[str, str] = {
    "fixed": "field.controller.executors:FixedOutcomeExecutor",  # deterministic, for tests
    "pybullet": "field.executor:PybulletTrialExecutor",  # grasp trials on the twin pile (pile=...)
}


def make_executor(name: str, **kwargs: Any) -> GraspExecutor:
    """Instantiate a registered executor by name."""
    if name not in EXECUTORS:
        raise ControllerError(f"unknown executor {name!r}; registered: {sorted(EXECUTORS)}")
    module_name, _, attr = EXECUTORS[name].partition(":")
    try:
        cls = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise ControllerError(f"executor {name!r} could not be loaded ({exc}); install what it needs") from exc
    return cls(**kwargs)


class FixedOutcomeExecutor:
    """Deterministic test executor: after ``delay_s`` returns a fixed outcome.

    ``delay_by_target_logs`` overrides the delay per target log count (a slow command in tests).

    ``logs_grasped`` defaults to the command's target count. Every execution start is appended
    to ``log_path`` (when given; read it with :func:`read_execution_log`) so tests in another
    process can prove a command never ran twice. ``should_abort`` cuts the delay short.
    """

    poll_s = 0.005  # how often should_abort is looked at while "moving" [s]

    def __init__(
        self,
        delay_s: float = 0.05,
        outcome_class: OutcomeClass | str | int = OutcomeClass.SUCCESS,
        logs_grasped: int | None = None,
        balance_cos_milli: int = 985,
        log_path: str | None = None,
        delay_by_target_logs: dict[int, float] | None = None,
    ):
        if not delay_s >= 0:
            raise ValueError(f"delay_s must be >= 0 s, got {delay_s}")
        if isinstance(outcome_class, str):
            outcome_class = OutcomeClass[outcome_class.upper()]
        self.delay_s = float(delay_s)
        self.outcome_class = OutcomeClass(outcome_class)
        self.logs_grasped = logs_grasped
        self.balance_cos_milli = int(balance_cos_milli)
        self.log_path = log_path
        # per-target-count delay overrides [s] (lets a test make one command slow)
        self.delay_by_target_logs = {int(k): float(v) for k, v in (delay_by_target_logs or {}).items()}
        self.executed: list[int] = []
        self.aborted: list[int] = []  # ids whose delay was cut short by should_abort
        if log_path is not None and not Path(log_path).exists():
            Path(log_path).parent.mkdir(parents=True, exist_ok=True)
            with open(log_path, "w") as f:
                f.write(json.dumps({"format": EXECUTION_LOG_FORMAT, "version": EXECUTION_LOG_VERSION}) + "\n")

    def execute(self, cmd: GraspCommand, should_abort: Callable[[], bool]) -> Outcome:
        self.executed.append(cmd.command_id)
        self._log_start(cmd.command_id)
        end = time.monotonic() + self.delay_by_target_logs.get(cmd.target_log_count, self.delay_s)
        while (left := end - time.monotonic()) > 0:
            if should_abort():
                self.aborted.append(cmd.command_id)
                break
            time.sleep(min(left, self.poll_s))
        n = cmd.target_log_count if self.logs_grasped is None else self.logs_grasped
        return Outcome(cmd.command_id, self.outcome_class, n, self.balance_cos_milli)

    def __call__(self, cmd: GraspCommand) -> Outcome:
        return self.execute(cmd, lambda: False)

    def _log_start(self, command_id: int) -> None:
        if self.log_path is None:
            return
        with open(self.log_path, "a") as f:
            f.write(json.dumps({"command_id": command_id, "t": time.time()}) + "\n")
            f.flush()
            os.fsync(f.fileno())


def read_execution_log(path: str | Path) -> list[int]:
    """Command ids in the order a :class:`FixedOutcomeExecutor` started them."""
    lines = Path(path).read_text().splitlines()
    if not lines:
        return []
    head = json.loads(lines[0])
    if head.get("format") != EXECUTION_LOG_FORMAT or str(head.get("version", "")).split(".")[0] != "1":
        raise ControllerError(f"{path} is not a version-1 {EXECUTION_LOG_FORMAT} file")
    return [int(json.loads(line)["command_id"]) for line in lines[1:] if line.strip()]
