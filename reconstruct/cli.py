"""``loggrasp synth scan`` (the twin's field scans), ``loggrasp reconstruct`` and ``compare-piles``."""

from __future__ import annotations

from pathlib import Path

import typer

from synth.cli import fail


def scan_command(
    out: Path = typer.Option(..., "--out", help="Scan folder to write (scan/, gnss.csv, truth/)."),
    seed: int = typer.Option(0, "--seed"),
    logs: str = typer.Option("3-5", "--logs", help="Logs, 'A-B'."),
    obstacles: str = typer.Option("0-2", "--obstacles", help="Obstacles, 'A-B'."),
    packed: bool = typer.Option(False, "--packed"),
    site: str = typer.Option("64.1,20.0", "--site", help="Site origin LAT,LON (SWEREF 99) [deg], optional ,H [m]."),
    float_fixes: int = typer.Option(2, "--float-fixes", help="Endpoints measured with an RTK float fix only."),
    unsurveyed: int = typer.Option(0, "--unsurveyed-logs", help="Logs left out of the survey (chosen among those "
                                   "the scan shows well): a degraded survey."),
    height: float = typer.Option(3.0, "--height", help="Camera height above the pile [m]."),
    hfov: float = typer.Option(50.0, "--hfov", help="Horizontal field of view [deg]."),
    pairs: str = typer.Option("2x2", "--pairs", help="Grid of stereo pairs over the pile, NXxNY (along x across)."),
    unposed: bool = typer.Option(False, "--unposed", help="No camera poses: calibrations without T_pile_cam, no "
                                 "scan_pose.json, the rig moved by hand between pairs (truth/poses.json keeps them)."),
    handheld: bool | None = typer.Option(None, "--handheld/--grid", help="Move the rig between pairs like a handheld or "
                                  "boom camera (default: with --unposed), or hold a straight-down grid."),
) -> None:
    """Make a field scan of a generated pile whose truth is known: a ZED 2-like stereo pair with its
    calibration, an RTK GNSS endpoint CSV with realistic noise, and the true pile kept apart in truth/.

    Example: loggrasp synth scan --seed 3 --logs 3-5 --site 64.1,20.0 --out scans/s3
    Unposed (SfM + GNSS georegistration): loggrasp synth scan --seed 3 --unposed --out scans/s3u
    Degraded survey: loggrasp synth scan --seed 3 --float-fixes 4 --unsurveyed-logs 1 --out scans/s3d
    """
    from reconstruct.twin_scan import DEFAULT_SITE, make_twin_scan
    from synth.errors import SynthError
    from synth.jobs import parse_range

    try:
        parts = [float(v) for v in site.split(",")]
        if len(parts) not in (2, 3):
            raise ValueError(f"--site must be LAT,LON or LAT,LON,H, got {site!r}")
        site_t = (parts[0], parts[1], parts[2] if len(parts) == 3 else DEFAULT_SITE[2])
        try:
            grid = tuple(int(v) for v in pairs.lower().split("x"))
        except ValueError:
            grid = ()
        if len(grid) != 2 or min(grid) < 1 or max(grid) > 4:
            raise ValueError(f"--pairs must look like 2x2 (1..4 each), got {pairs!r}")
        path = make_twin_scan(out, seed, parse_range(logs, "--logs"), parse_range(obstacles, "--obstacles"),
                              packed=packed, site=site_t, n_float=float_fixes, height_m=height, hfov_deg=hfov,
                              grid=grid, unposed=unposed, handheld=handheld, n_unsurveyed=unsurveyed)
    except (SynthError, ValueError) as exc:
        fail(str(exc))
    typer.echo(f"scan written to {path} (truth in {path / 'truth'})")


def reconstruct_command(
    scan: Path = typer.Argument(..., help="Scan folder: stereo pair folder(s) + scan_pose.json."),
    gnss: Path = typer.Option(..., "--gnss", help="RTK endpoint survey CSV (see README)."),
    out: Path = typer.Option(..., "--out", help="Output folder: pile.json, ortho.npz, previews, report.json."),
    allow_float: bool = typer.Option(False, "--allow-float", help="Accept RTK float endpoints (not recommended)."),
    pair_poses: str = typer.Option("auto", "--pair-poses", help="Where the pairs' poses come from: auto (the "
                                   "calibrations' T_pile_cam, SfM when they have none), calibration, sfm (pycolmap)."),
    georegister: str = typer.Option("auto", "--georegister", help="How the scan is placed in the site frame: auto "
                                    "(scan_pose.json; from the GNSS ends for an unposed scan), scan-pose, gnss."),
    log_direction: str = typer.Option("45", "--log-direction", help="Turn the pile frame so the logs' mean direction "
                                      "lies at this angle [deg] from +x, or 'site' to keep the site's axes."),
) -> None:
    """Rebuild the scanned pile in the twin from a stereo scan and RTK GNSS log endpoints.

    Example: loggrasp reconstruct scans/s3/scan --gnss scans/s3/gnss.csv --out recon/s3
    No poses at all (SfM + GNSS): loggrasp reconstruct scans/s3u/scan --gnss scans/s3u/gnss.csv --out recon/s3u
    """
    from rich.console import Console
    from rich.table import Table

    from reconstruct.errors import ReconstructError
    from reconstruct.pipeline import ReconstructConfig, parse_log_direction, reconstruct
    from synth.errors import SynthError

    console = Console()
    try:
        with console.status("reconstructing") as status:
            cfg = ReconstructConfig(allow_float=allow_float, pair_poses=pair_poses, georegister=georegister,
                                    log_direction_deg=parse_log_direction(log_direction))
            result = reconstruct(scan, gnss, out, cfg, progress=lambda s: status.update(s))
    except (ReconstructError, SynthError, ValueError) as exc:
        fail(str(exc))
    table = Table(title=f"{result.pile.n_logs} logs, {result.pile.n_obstacles} obstacles in {result.time_s:.1f} s")
    for title in LOG_TABLE.values():
        table.add_column(title, justify="right")
    for row in result.report.get("logs", []):
        table.add_row(*log_table_row(row))
    console.print(table)
    for log in result.report.get("logs", []):
        if log.get("fit") == "hidden":
            typer.echo(f"log {log['log_id']}: hidden under other logs (no scan points on it): placed on its GNSS "
                       "axis, its diameter estimated; check it before trusting grasps that take it")
    for k in result.report.get("fusion", {}).get("new_logs", {}):
        typer.echo(f"log {k}: not in the survey; found in the scan and placed from it alone")
    for line in result.report.get("weak_ends", []):
        typer.echo(f"weak estimate: {line}")
    for line in result.report.get("contradicted_points", []):
        typer.echo(f"survey point not used: {line}")
    rep = result.report
    reg = rep.get("registration", {})
    line = f"scan pose: {rep.get('scan_pose_source')}; pair poses: {rep.get('pair_poses_source')}"
    if "residual_rms_after_m" in reg:
        line += (f"; GNSS residual RMS {reg.get('residual_rms_before_m', float('nan')):.3f} -> "
                 f"{reg['residual_rms_after_m']:.3f} m")
    typer.echo(line)
    typer.echo(f"wrote {out}/pile.json, ortho.npz, preview.png, compare.png, report.json")


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


def compare_command(
    truth: Path = typer.Argument(..., help="Ground-truth pile.json (or its folder)."),
    recon: Path = typer.Argument(..., help="Reconstructed pile.json (or its folder)."),
    as_json: bool = typer.Option(False, "--json", help="Print the full comparison as JSON."),
) -> None:
    """Per-log and summary errors of a reconstruction against the truth (endpoint, diameter, mask IoU, obstacles).

    Example: loggrasp compare-piles scans/s3/truth recon/s3 --json
    """
    import json

    from reconstruct.compare import compare_piles
    from synth.errors import SynthError
    from synth.pile import read_pile

    try:
        result = compare_piles(read_pile(truth), read_pile(recon))
    except (SynthError, ValueError) as exc:
        fail(str(exc))
    if as_json:
        typer.echo(json.dumps(result, indent=1))
    else:
        typer.echo(json.dumps(result["summary"], indent=1))
