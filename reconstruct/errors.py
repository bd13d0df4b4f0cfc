"""Error hierarchy of the reconstruction. Every error says what was wrong and what to do.

``ReconstructError`` is the root of every error raised by :mod:`reconstruct`; add subclasses
for new stages next to the GNSS ones below.
"""

from __future__ import annotations

from synth.common.errors import LoggraspError


class ReconstructError(LoggraspError):
    """Root of every error raised by :mod:`reconstruct`."""


# --- GNSS surveys of log ends (reconstruct.survey.gnss) ---------------------------------------------


class GnssError(ReconstructError):
    """A GNSS survey of log end points could not be used."""


class GnssFileError(GnssError):
    """A survey, raw receiver log or time-window file is missing or unreadable."""


class GnssFormatError(GnssError, ValueError):
    """A survey file is malformed: a bad row, an unknown column or CRS, a log whose end is
    missing or duplicated, coordinates that make no sense for Sweden (e.g. swapped lat/lon)."""


class GnssQualityError(GnssError):
    """Points are not good enough: not RTK-fixed (and float not allowed), or no epochs in a
    time window. Re-measure them, or accept float solutions explicitly."""


class GnssOutlierError(GnssError):
    """A point lies implausibly far from the other points or from the scanned area (a wrong
    log id, a point measured elsewhere, a typo in a coordinate)."""


# --- stereo scans, fitting and registration (reconstruct.scan.stereo / fit / pipeline) -------------


class ScanError(ReconstructError):
    """A stereo scan cannot be used: a missing or unreadable image or calibration, left and
    right images of different sizes, a calibration that does not fit the images, or no depth."""


class CalibrationError(ScanError):
    """A pair's calibration is missing, unreadable or corrupt (calibration.yaml, a ZED SN*.conf), has
    no section for the images' resolution, or two calibrations of one pair disagree."""


class ScanPlanError(ReconstructError):
    """No scan plan covers the surveyed end points: no points, non-finite ones, an end too near the
    camera, or ends spread wider than the largest grid planned (a point far off)."""


class FitError(ReconstructError):
    """The scan does not support a model: a log with (almost) no scan points around its GNSS
    axis (outside the scanned area, or wrong endpoints), or a fit that failed."""


class SeparationError(FitError):
    """The twin's pile check would have to move a log farther than a fit's noise explains to clear
    another body. ``logs``: the pile indices of the logs of that contact (the moving one first)."""

    def __init__(self, message: str, logs: tuple[int, ...] = ()) -> None:
        super().__init__(message)
        self.logs = tuple(logs)


class LogNotSeenError(FitError):
    """(Almost) no scan points lie on a log around its GNSS axis: it is hidden under other logs,
    outside the scanned area, or its end points are wrong. :func:`reconstruct.fitting.fit.fit_pile`
    places a log hidden under others from its survey alone; any other case is an error."""


class RegistrationError(ReconstructError):
    """The scan could not be aligned to the site frame (endpoints far from the scanned area,
    residuals too large, too few logs to constrain the transform)."""


# --- unposed scans: pair poses from SfM (reconstruct.scan.sfm), coarse georegistration (pipeline) ---


class SfmError(ScanError):
    """The stereo pairs' relative poses could not be recovered by structure from motion."""


class SfmRegistrationError(SfmError):
    """SfM placed too few images: some pairs do not overlap the others (or lack texture). The
    message names them; re-take overlapping pairs, drop them, or give the pairs their poses."""


class SfmScaleError(SfmError):
    """The metric scale from the pairs' calibrated baselines is inconsistent across pairs."""


class CoarseRegistrationError(RegistrationError):
    """The scan could not be placed in the site frame from the GNSS end points alone: no ground
    plane, no yaw that puts the surveyed logs on the scan, or two equally good yaws (a symmetric
    pile). Give a scan pose (scan_pose.json), or survey a log that breaks the symmetry."""
