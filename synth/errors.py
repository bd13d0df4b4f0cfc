"""Error hierarchy of the simulator twin. Every error says what was wrong and what to do."""

from synth.common.errors import LoggraspError


class SynthError(LoggraspError):
    """Root of every error raised by :mod:`synth`."""


class PileFormatError(SynthError):
    """A pile file is missing, malformed, or of a format version this code cannot read."""


class PileValidationError(SynthError):
    """A pile is physically impossible (logs through the terrain or each other, off the area...)."""


class GenerationError(SynthError):
    """Pile generation could not produce a valid pile within its attempt budget."""


class RenderError(SynthError):
    """A render could not be produced."""


class OutputError(SynthError):
    """An output folder or file cannot be written."""
