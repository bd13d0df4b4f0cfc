"""The root of every loggrasp error.

Each package has its own tree (``SynthError``, ``PlannerError``, ``ReconstructError``,
``FieldError``), each a :class:`LoggraspError`, so a caller that wants "any loggrasp problem"
catches one class and a bug (``TypeError``, ``KeyError`` …) is never caught by mistake. Every
message says what was wrong and what to do."""


class LoggraspError(Exception):
    """Root of every error loggrasp raises on purpose."""
