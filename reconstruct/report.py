"""The reconstruction report (``report.json``): its format, the reader beside the writer
(:func:`reconstruct.pipeline.reconstruct`), and the lines it gives a person: weak ends, contradicted
survey points, each log's end uncertainty."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from reconstruct.errors import ReconstructError
from reconstruct.fitting.fuse import FuseConfig
from synth.common.formats import VersionedJson


REPORT_FORMAT = "loggrasp.reconstruction-report"
REPORT_VERSION = "1.3"  # 1.1: per-log "fit" (scan, partial, hidden); 1.2: per-end "ends" (source, sigma), "fusion",
#                       "weak_ends", "contradicted_points"; 1.3: per-end "gnss_position_m", "gnss_sigma_m"
#                       and, for an end the pile check placed at its survey point, "pile_check"; "end_moves"
REPORT = VersionedJson(REPORT_FORMAT, REPORT_VERSION, "reconstruction report", ReconstructError,
                       unreadable_fix="reconstruct the scan again", filename="report.json")


def weak_ends(logs: list, cfg: FuseConfig | None = None) -> list[str]:
    """One line per log end placed on a weak estimate (less certain than ``weak_sigma_m``, or against
    its survey point): what placed it and how sure it is."""
    cfg = cfg or FuseConfig()
    out = []
    for lf in logs:
        for end, e in zip("ab", lf.ends or []):
            if e["sigma_m"] > cfg.weak_sigma_m or e["contradicted"]:
                out.append(f"{lf.log_id} end {end}: {e['source']} (scan: {e['scan']}), +-{e['sigma_m'] * 100:.0f} cm")
    return out


def log_end_sigmas(report: dict) -> list[float | None]:
    """Per log of a reconstruction report (:func:`reconstruct`'s ``report``): the 1-sigma 3-D
    uncertainty of its less certain end [m], None for a log whose ends were not fused."""
    return [max((float(e["sigma_m"]) for e in log.get("ends") or []), default=None)
            for log in report.get("logs", [])]


def contradicted_points(logs: list) -> list[str]:
    """One line per survey point the scan contradicts (not used): how far it is from the placed end."""
    out = []
    for lf in logs:
        for end, e in zip("ab", lf.ends or []):
            if e["contradicted"]:
                out.append(f"{lf.log_id} end {end} ({e['gnss_fix']}): {e['gnss_residual_m'] * 100:.0f} cm from where "
                           f"the scan puts it ({e['gnss_residual_sigma']:.1f} sigma); check or re-measure it")
    return out


def read_report(path: str | Path) -> dict:
    """Read a ``report.json`` written by :func:`reconstruct` (the version is checked)."""
    return REPORT.read(path)


def json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"cannot serialise {type(o).__name__}")
