"""``loggrasp synth scan`` (the twin's field scans), ``loggrasp reconstruct`` and ``compare-piles``.

Flags take their defaults from the config dataclasses (:func:`synth.common.cli.option`); errors
are raised and printed once by ``field.cli.run``."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Literal

import typer

from reconstruct.config import ReconstructConfig
from reconstruct.survey.cli import GNSS_HELP, GNSS_WINDOWS_HELP, gnss_source
from synth.cli import JSON
from synth.common.cli import CliError, Output, check_input, check_output_dir, option

SITE_HELP = "Site origin LAT,LON (SWEREF 99) [deg], optional ,H (ellipsoidal) [m]."


def parse_site(text: str, flag: str = "--site") -> tuple[float, ...]:
    """``LAT,LON`` or ``LAT,LON,H`` -> floats; a :class:`CliError` naming ``flag`` otherwise."""
    try:
        parts = tuple(float(v) for v in text.split(","))
    except ValueError:
        parts = ()
    if len(parts) not in (2, 3) or not all(map(lambda v: v == v, parts)):
        raise CliError(f"{flag} must be LAT,LON or LAT,LON,H in degrees (and metres), e.g. 64.1,20.0; got {text!r}")
    return parts


def gnss_crs_warning(path) -> str | None:
    """A warning when a survey CSV names no CRS (the reader then assumes SWEREF 99)."""
    if not isinstance(path, (str, Path)):  # raw logs: the survey is made in SWEREF 99
        return None
    p = Path(path)
    if p.suffix.lower() != ".csv":
        return None
    try:
        with open(p, errors="replace") as f:
            head = [next(f, "") for _ in range(50)]
    except OSError:
        return None
    if any(re.match(r"\s*#\s*crs\s*:", line, re.IGNORECASE) for line in head):
        return None
    return (f"{p} has no '# crs:' line: SWEREF 99 assumed (EPSG:4619 for lat/lon columns, EPSG:3006 for "
            "easting/northing); add the line to say which")


def scan_command(
    out: Path = option("--out", "Scan folder to write (scan/, gnss.csv, truth/).", default=..., metavar="DIR"),
    seed: int = option("--seed", "Pile and survey seed: same seed, same scan.", default=0),
    logs: str = option("--logs", "Logs, 'A-B' or 'A'.", default="3-5"),
    obstacles: str = option("--obstacles", "Obstacles, 'A-B' or 'A'.", default="0-2"),
    packed: bool = option("--packed", "Aligned, tightly packed logs.", default=False),
    site: str = option("--site", SITE_HELP, default="64.1,20.0", metavar="LAT,LON[,H]"),
    float_fixes: int = option("--float-fixes", "Endpoints measured with an RTK float fix only.", default=2, min=0,
                              names=["n_float"]),
    unsurveyed: int = option("--unsurveyed-logs", "Logs left out of the survey (chosen among those the scan shows "
                             "well): a degraded survey.", default=0, min=0, names=["n_unsurveyed"]),
    height: float = option("--height", "Camera height above the pile.", default=3.0, unit="m", min=0.5,
                           names=["height_m"]),
    hfov: float = option("--hfov", "Horizontal field of view.", default=50.0, unit="deg", min=10.0, max=170.0,
                         names=["hfov_deg"]),
    pairs: str = option("--pairs", "Grid of stereo pairs over the pile, NXxNY (along x, across; 1..4 each), or "
                        "auto: the smallest grid (at least 2x2) whose footprint covers every surveyed log end plus "
                        "ScanPlanConfig.margin_m (0.3 m) and 2 sigma of the point, planned from the survey "
                        "(reconstruct.scan.plan).", default="2x2", metavar="NXxNY|auto"),
    unposed: bool = option("--unposed", "No camera poses: calibrations without T_pile_cam, no scan_pose.json, the rig "
                           "moved by hand between pairs (truth/poses.json keeps them).", default=False),
    handheld: bool = typer.Option(None, "--handheld/--grid", help="Move the rig between pairs like a handheld or "
                                  "boom camera (default: with --unposed), or hold a straight-down grid."),
    as_json: bool = JSON,
) -> None:
    """Make a field scan of a generated pile whose truth is known: ZED 2-like stereo pairs with their
    calibrations, an RTK GNSS endpoint CSV with realistic noise, and the true pile kept apart in truth/.

    \b
    Example: loggrasp synth scan --seed 3 --logs 3-5 --site 64.1,20.0 --out scans/s3
    Unposed (SfM + GNSS georegistration): loggrasp synth scan --seed 3 --unposed --out scans/s3u
    Degraded survey: loggrasp synth scan --seed 3 --float-fixes 4 --unsurveyed-logs 1 --out scans/s3d
    Pairs planned from the survey (a loose pile): loggrasp synth scan --seed 3 --pairs auto --out scans/s3a
    """
    from reconstruct.scan.twin_scan import DEFAULT_SITE, make_twin_scan
    from synth.geometry.geodesy import check_geodetic
    from synth.common.ranges import parse_range

    o = Output(as_json)
    parts = parse_site(site)
    check_geodetic(parts[0], parts[1], "--site")
    site_t = (parts[0], parts[1], parts[2] if len(parts) == 3 else DEFAULT_SITE[2])
    grid, plan = parse_pairs(pairs), None
    if grid is None:
        from reconstruct.scan.plan import ScanPlanConfig

        try:
            plan = ScanPlanConfig(height_m=height, hfov_deg=hfov)
        except ValueError as exc:
            raise CliError(f"--pairs auto with --height {height} --hfov {hfov}: {exc}") from exc
        grid = (2, 2)
    log_range, obst_range = parse_range(logs, "--logs"), parse_range(obstacles, "--obstacles")
    if log_range[0] < 1:
        raise CliError("--logs must start at 1 or more")
    check_output_dir(out, "--out")
    path = make_twin_scan(out, seed, log_range, obst_range, packed=packed, site=site_t, n_float=float_fixes,
                          height_m=height, hfov_deg=hfov, grid=grid, plan=plan, unposed=unposed, handheld=handheld,
                          n_unsurveyed=unsurveyed,
                          progress=o.progress)
    nxt = next_step(path, float_fixes)
    o.say(f"scan written to {path} (the truth apart in {path / 'truth'}); next: {nxt}")
    o.result("loggrasp.synth-scan", {"out": str(path), "scan": str(path / "scan"), "gnss": str(path / "gnss.csv"),
                                     "truth": str(path / "truth" / "pile.json"), "next": nxt})


def parse_pairs(text: str) -> tuple[int, int] | None:
    """``--pairs``: ``NXxNY`` (1..4 each) -> the grid; ``auto`` -> None (planned from the survey); a
    :class:`CliError` naming the flag otherwise."""
    if text.strip().lower() == "auto":
        return None
    try:
        grid = tuple(int(v) for v in text.lower().split("x"))
    except ValueError:
        grid = ()
    if len(grid) != 2 or min(grid) < 1 or max(grid) > 4:
        raise CliError(f"--pairs must look like 2x2 (1..4 each) or be auto, got {text!r}")
    return grid[0], grid[1]


def next_step(scan_out: Path, n_float: int) -> str:
    """The command that reconstructs a twin scan written to ``scan_out`` (``--allow-float`` when its
    survey has float points: accepting them stays the user's explicit choice, made visible here)."""
    return (f"loggrasp reconstruct {scan_out / 'scan'} --gnss {scan_out / 'gnss.csv'} --out {scan_out / 'recon'}"
            + (" --allow-float" if n_float > 0 else ""))


def reconstruct_command(
    scan: Path = typer.Argument(..., metavar="SCAN", help="Scan folder: stereo pair folder(s) + scan_pose.json."),
    gnss: list[Path] = option("--gnss", GNSS_HELP, default=..., metavar="FILE"),
    gnss_windows: Path = option("--gnss-windows", GNSS_WINDOWS_HELP, default=None, metavar="FILE"),
    out: Path = option("--out", "Output folder: pile.json, ortho.npz, previews, report.json.", default=...,
                       metavar="DIR"),
    allow_float: bool = option("--allow-float", "Accept RTK float endpoints (decimetres off): the scan then places every "
                               "end it sees, a float point places only an end it does not (reported weak).",
                               field=(ReconstructConfig, "allow_float")),
    pair_poses: Literal["auto", "calibration", "sfm"] = option(
        "--pair-poses", "Where the pairs' poses come from: auto (the calibrations' T_pile_cam, SfM when they have "
        "none), calibration, sfm (pycolmap).", field=(ReconstructConfig, "pair_poses"), metavar="auto|calibration|sfm"),
    georegister: Literal["auto", "scan-pose", "gnss"] = option(
        "--georegister", "How the scan is placed in the site frame: auto (scan_pose.json; from the GNSS ends for an "
        "unposed scan), scan-pose, gnss.", field=(ReconstructConfig, "georegister"), metavar="auto|scan-pose|gnss"),
    log_direction: str = option("--log-direction", "Turn the pile frame so the logs' mean direction lies at this angle "
                                "[deg] from +x, or 'site' to keep the site's axes.", default="45", metavar="DEG|site",
                                names=["log_direction_deg"]),
    estimator: Literal["rules22", "joint"] = option(
        "--estimator", "How logs are matched and their ends placed: rules22 (fitting revision 22, the default) or "
        "joint (one assignment, each end a posterior of the scan and its survey point with an outlier component; "
        "being measured, see docs/reconstruction.md).", field=(ReconstructConfig, "estimator"),
        metavar="rules22|joint"),
    as_json: bool = option("--json", "Print report.json (format loggrasp.reconstruction-report) on standard output.",
                           default=False),
) -> None:
    """Rebuild the scanned pile in the twin from a stereo scan and RTK GNSS log endpoints.

    \b
    Example: loggrasp reconstruct scans/s3/scan --gnss scans/s3/gnss.csv --out recon/s3
    No poses at all (SfM + GNSS): loggrasp reconstruct scans/s3u/scan --gnss scans/s3u/gnss.csv --out recon/s3u
    Raw rover logs: loggrasp reconstruct scans/s3/scan --gnss rover.ubx --gnss-windows windows.csv --out recon/s3
    """
    from reconstruct.config import parse_log_direction
    from reconstruct.pipeline import reconstruct

    o = Output(as_json)
    cfg = ReconstructConfig(allow_float=allow_float, pair_poses=pair_poses, georegister=georegister,
                            log_direction_deg=parse_log_direction(log_direction), estimator=estimator)
    check_input(scan, "SCAN", "dir")
    source = gnss_source(gnss, gnss_windows)
    check_output_dir(out, "--out")
    warning = gnss_crs_warning(source)
    if warning:
        o.warn(warning)
    result = reconstruct(scan, source, out, cfg, progress=o.progress)
    rep = result.report
    o.result("loggrasp.reconstruction-report", rep)
    o.table(f"{result.pile.n_logs} logs, {result.pile.n_obstacles} obstacles in {result.time_s:.1f} s",
            list(LOG_TABLE.values()), [log_table_row(row) for row in rep.get("logs", [])])
    for log in rep.get("logs", []):
        if log.get("fit") == "hidden":
            o.say(f"log {log['log_id']}: hidden under other logs (no scan points on it): placed on its GNSS axis, its "
                  "diameter estimated; check it before trusting grasps that take it")
    for k in rep.get("fusion", {}).get("new_logs", {}):
        o.say(f"log {k}: not in the survey; found in the scan and placed from it alone")
    for w in rep.get("weak_ends", []):
        o.warn(f"weak estimate: {w}")
    for w in rep.get("contradicted_points", []):
        o.warn(f"survey point not used: {w}")
    for w in rep.get("end_moves", []):
        o.warn(f"pile check: {w}")
    for w in rep.get("survey_warnings", []):
        o.warn(f"GNSS survey: {w}")
    reg = rep.get("registration", {})
    line = f"scan pose: {rep.get('scan_pose_source')}; pair poses: {rep.get('pair_poses_source')}"
    if "residual_rms_after_m" in reg:
        before = reg.get("residual_rms_before_m")
        line += (f"; GNSS residual RMS {'-' if before is None else f'{before:.3f}'} -> "
                 f"{reg['residual_rms_after_m']:.3f} m")
    o.say(line)
    o.say(f"wrote {out}/pile.json, ortho.npz, preview.png, compare.png, report.json")


#: the per-log report's columns: report key -> column title
LOG_TABLE = {"log_id": "log", "fit": "fit", "end_source": "ends butt/top", "length_m": "length m", "diameter_m": "diam. m",
             "top_diameter_m": "top diam. m", "gnss_residual_a_m": "GNSS res. a m",
             "gnss_residual_b_m": "GNSS res. b m", "rms_m": "fit rms m", "coverage": "coverage",
             "n_points": "points", "moved_m": "moved m"}


def log_table_row(log: dict) -> list[str]:
    """One fitted log (``report.json`` ``logs`` entry) as the per-log table's cells."""
    def cell(v) -> str:
        if v is None:
            return "-"
        if isinstance(v, (list, tuple)):
            return "/".join(cell(x) for x in v)
        if isinstance(v, float):
            return "-" if v != v else f"{v:.3f}"
        return str(v)

    return [cell(log.get(k)) for k in LOG_TABLE]


COMPARISON_FORMAT = "loggrasp.pile-comparison"


def compare_command(
    truth: Path = typer.Argument(..., metavar="TRUTH", help="Ground-truth pile.json (or its folder)."),
    recon: Path = typer.Argument(..., metavar="RECON", help="Reconstructed pile.json (or its folder)."),
    as_json: bool = option("--json", f"Print the full comparison as JSON (format {COMPARISON_FORMAT}).", default=False),
) -> None:
    """Per-log and summary errors of a reconstruction against the truth (endpoint, diameter, mask IoU, obstacles).

    \b
    Example: loggrasp compare-piles scans/s3/truth recon/s3 --json
    """
    from reconstruct.compare import compare_piles
    from synth.scene.pile import read_pile

    o = Output(as_json)
    check_input(truth, "TRUTH")
    check_input(recon, "RECON")
    result = compare_piles(read_pile(truth), read_pile(recon))
    o.result(COMPARISON_FORMAT, result)
    summary = result.get("summary", {})
    o.table(f"reconstruction {recon} against the truth {truth}", ["measure", "value"],
            [[k, _cell(v)] for k, v in summary.items()])


def _cell(v) -> str:
    if isinstance(v, float):
        return "-" if v != v else f"{v:.4g}"
    if isinstance(v, dict):
        return ", ".join(f"{k} {_cell(x)}" for k, x in v.items())
    if isinstance(v, (list, tuple)):
        return ",".join(_cell(x) for x in v)
    return "-" if v is None else str(v)
