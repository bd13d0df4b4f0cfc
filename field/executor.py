"""The controller twin's hands: accepted grasp commands executed as grasp trials in pybullet.

A :class:`PybulletTrialExecutor` holds the (true, georeferenced) pile the crane stands at. For a
command it converts the SWEREF 99 TM position and the grid heading back into the pile frame,
runs :func:`synth.physics.trial.run_trial` from the settled pile and reports the outcome the way a real
controller would (class, logs held, balance). An abort (e-stop, commanding laptop lost) stops
the trial within one simulation step and reports the logs the grapple holds at that moment. Registered in
:data:`field.controller.EXECUTORS` as ``"pybullet"``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from field.errors import ControllerError
from field.link.messages import GraspCommand, Outcome, OutcomeClass

_CLASS = {
    "success": OutcomeClass.SUCCESS,
    "more_than_intended": OutcomeClass.MORE_THAN_INTENDED,
    "fewer_or_other": OutcomeClass.FEWER,
    "collision": OutcomeClass.COLLISION,
    "not_closed": OutcomeClass.NOT_CLOSED,
    "dropped": OutcomeClass.DROPPED,
}


def command_to_grasp(cmd: GraspCommand, georef):
    """(Grasp in the pile frame, grasp-point height z [m]) of a grasp command: the laptop's own
    conversion (:meth:`GraspCommand.to_pile_grasp`, i.e. :func:`field.geo.tm_to_grasp`)."""
    return cmd.to_pile_grasp(georef)


class PybulletTrialExecutor:
    """Execute commands as grasp trials on ``pile`` (a PileSpec or a pile.json path)."""

    def __init__(self, pile, trial: str = "fast") -> None:
        from synth.scene.pile import PileSpec, read_pile
        from synth.physics.trial import TrialConfig

        self.pile = pile if isinstance(pile, PileSpec) else read_pile(Path(pile))
        if self.pile.georef is None:
            raise ControllerError("the controller twin's pile has no georeference: it cannot place "
                                  "SWEREF 99 TM commands on it; give it a georeferenced pile.json")
        if trial not in ("fast", "careful"):
            raise ControllerError(f"trial preset must be 'fast' or 'careful', got {trial!r}")
        self.config = TrialConfig.preset(trial)
        self.last_result = None

    def execute(self, cmd: GraspCommand, should_abort: Callable[[], bool]) -> Outcome:
        """Run the trial; ``should_abort`` is asked every simulation step. An aborted trial stops
        at once (boom and claws held) and reports ABORTED with the logs between the claws at
        that moment (held or enclosed: what the operator must know before opening the grapple)."""
        from synth.physics.trial import run_trial

        grasp, _ = command_to_grasp(cmd, self.pile.georef)
        result = run_trial(self.pile, grasp, int(cmd.target_log_count), self.config, should_abort=should_abort)
        self.last_result = result
        cos_b = result.cos_beta if result.cos_beta == result.cos_beta else 1.0
        balance = int(round(max(-1.0, min(1.0, cos_b)) * 1000))
        if result.stop_reason == "aborted":
            in_grapple = set(result.grasped) | set(result.enclosed)
            return Outcome(cmd.command_id, OutcomeClass.ABORTED, len(in_grapple), balance)
        return Outcome(cmd.command_id, _CLASS[result.outcome.value], len(result.grasped), balance)

    def __call__(self, cmd: GraspCommand) -> Outcome:
        return self.execute(cmd, lambda: False)
