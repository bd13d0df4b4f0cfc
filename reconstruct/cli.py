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
    height: float = typer.Option(4.0, "--height", help="Camera height above the pile [m]."),
    hfov: float = typer.Option(60.0, "--hfov", help="Horizontal field of view [deg]."),
) -> None:
    """Make a field scan of a generated pile whose truth is known: a ZED 2-like stereo pair with its
    calibration, an RTK GNSS endpoint CSV with realistic noise, and the true pile kept apart in truth/.

    Example: loggrasp synth scan --seed 3 --logs 3-5 --site 64.1,20.0 --out scans/s3
    """
    from reconstruct.twin_scan import DEFAULT_SITE, make_twin_scan
    from synth.errors import SynthError
    from synth.jobs import parse_range

    try:
        parts = [float(v) for v in site.split(",")]
        if len(parts) not in (2, 3):
            raise ValueError(f"--site must be LAT,LON or LAT,LON,H, got {site!r}")
        site_t = (parts[0], parts[1], parts[2] if len(parts) == 3 else DEFAULT_SITE[2])
        path = make_twin_scan(out, seed, parse_range(logs, "--logs"), parse_range(obstacles, "--obstacles"),
                              packed=packed, site=site_t, n_float=float_fixes, height_m=height, hfov_deg=hfov)
    except (SynthError, ValueError) as exc:
        fail(str(exc))
    typer.echo(f"scan written to {path} (truth in {path / 'truth'})")
