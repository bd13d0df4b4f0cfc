"""Error hierarchy of the grasp planner. Every error says what was wrong and what to do."""

from synth.common.errors import LoggraspError


class PlannerError(LoggraspError):
    """Root of every error raised by :mod:`planner`."""


class CheckpointError(PlannerError):
    """A checkpoint is missing, corrupt, of an unsupported version, or does not fit its use
    (wrong input size or channel count)."""


class ObservationError(PlannerError):
    """An observation cannot be planned on (no logs, NaN depth, wrong size, too many logs...)."""


class DataError(PlannerError):
    """A training data set is missing, empty, or inconsistent."""


class TrainingError(PlannerError):
    """Training cannot start or continue (e.g. the output folder holds a different run)."""


class VerificationError(PlannerError):
    """Verification cannot run on this input (no pile, a pile the twin cannot load, a plan made on
    another pile, a time budget too small for one trial)."""
