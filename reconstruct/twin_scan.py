"""Field scans made by the twin, with known truth: ``loggrasp synth scan``.

A scan folder looks exactly like what an operator brings back from the field, with the truth
kept apart::

    DIR/scan/pair_NNN/left.png, right.png   ZED 2-like stereo pairs over the pile (a grid; procedural textures)
    DIR/scan/pair_NNN/calibration.yaml      OpenCV stereo calibration (K1 D1 K2 D2 R T, T_pile_cam)
    DIR/scan/pair_NNN/zed.conf              the same in ZED's SN*.conf form
    DIR/scan/pair_NNN/meta.json             pair format version, capture time (captured_utc)
    DIR/scan/scan_pose.json                 the scan frame in the site frame (the crane's RTK/IMU
                                            camera pose), with a realistic error
    DIR/gnss.csv                            RTK endpoints (SWEREF 99), realistic noise, a few float fixes
    DIR/truth/pile.json                     the ground-truth pile (georeferenced)
    DIR/truth/pair_NNN_depth.npz            ground-truth depth and instances of each left image
    DIR/scan.json                           what was made, and how

It lives in :mod:`reconstruct` (not :mod:`synth`) because the GNSS CSV format is this package's.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from synth.frames import make_T, rot_z
from synth.pile import Georeference, PileSpec, atomic_write_bytes, write_pile

SCAN_FORMAT_VERSION = "1.0"
DEFAULT_SITE = (64.1, 20.0, 250.0)  # near Umeå inland: lat [deg], lon [deg], ellipsoidal h [m]


def georeference_pile(pile: PileSpec, site: tuple[float, float, float], rng: np.random.Generator) -> PileSpec:
    """Place the pile on Earth: site origin at ``site`` (SWEREF 99 lat/lon/h), pile frame turned by a
    random yaw and shifted a few metres from the origin (the pile frame is arbitrary in the field)."""
    yaw = float(rng.uniform(-math.pi, math.pi))
    t = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), 0.0])
    T = make_T(rot_z(yaw), t)
    return replace(pile, georef=Georeference(origin_lat_deg=site[0], origin_lon_deg=site[1], origin_h_m=site[2],
                                             T_site_pile=tuple(tuple(float(v) for v in row) for row in T)))


def _rig_over_pile(pile: PileSpec, height_m: float, hfov_deg: float):
    from synth.stereo import StereoRigConfig

    ends = np.array([e for log in pile.logs for e in log.endpoints_m()])
    centre = ends.mean(axis=0)
    # long image side along the logs' mean direction
    axes = np.array([log.axis()[:2] for log in pile.logs])
    axes *= np.sign(axes @ axes[0])[:, None]
    yaw = math.degrees(math.atan2(axes[:, 1].mean(), axes[:, 0].mean()))
    return StereoRigConfig(height_m=height_m, hfov_deg=hfov_deg,
                           target_m=(float(centre[0]), float(centre[1]), float(pile.terrain.height_at(*centre[:2]))),
                           yaw_deg=yaw)


def make_twin_scan(out_dir: str | Path, seed: int, logs: tuple[int, int] = (3, 5), obstacles: tuple[int, int] = (0, 2),
                   packed: bool = False, site: tuple[float, float, float] = DEFAULT_SITE,
                   n_float: int = 2, height_m: float = 3.0, hfov_deg: float = 50.0,
                   grid: tuple[int, int] = (2, 2), spacing_m: tuple[float, float] = (1.4, 1.0),
                   pose_error_m: float = 0.03, pose_error_deg: float = 0.5) -> Path:
    """Generate a pile, render its stereo pair and survey its log ends; write a scan folder.

    Written into a temporary sibling folder and renamed into place (never half-written)."""
    from reconstruct.gnss import pile_endpoints_site, simulate_survey, write_gnss_csv
    from synth.generate import GenerationConfig, generate_pile
    from synth.geodesy import check_geodetic

    check_geodetic(site[0], site[1], "--site")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5CA7]))
    n_logs = int(rng.integers(logs[0], logs[1] + 1))
    n_obst = int(rng.integers(obstacles[0], obstacles[1] + 1))
    pile, _ = generate_pile(seed, GenerationConfig(n_logs=n_logs, n_obstacles=n_obst, packed=packed))
    pile = georeference_pile(pile, site, rng)

    out = Path(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        (tmp / "truth").mkdir()
        write_pile(pile, tmp / "truth" / "pile.json")
        import datetime as dt

        from reconstruct.pipeline import ScanPose, write_scan_pose
        from synth.stereo import StereoRenderer

        captured = dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds").replace("+00:00", "Z")
        rig0 = _rig_over_pile(pile, height_m, hfov_deg)
        yaw = math.radians(rig0.yaw_deg)
        along, across = np.array([math.cos(yaw), math.sin(yaw)]), np.array([-math.sin(yaw), math.cos(yaw)])
        nx, ny = grid
        centre = np.asarray(rig0.target_m[:2])
        with StereoRenderer(rig0.renderer) as renderer:
            for iy in range(ny):
                for ix in range(nx):
                    k = iy * nx + ix
                    xy = centre + along * (ix - (nx - 1) / 2) * spacing_m[0] + across * (iy - (ny - 1) / 2) * spacing_m[1]
                    rig = replace(rig0, target_m=(float(xy[0]), float(xy[1]), float(pile.terrain.height_at(*xy))))
                    pair = renderer.render(pile, rig)
                    pair.meta.update({"camera": "ZED 2 (twin)", "captured_utc": captured})
                    pair_dir = pair.save(tmp / "scan" / f"pair_{k:03d}")
                    os.replace(pair_dir / "depth_left.npz", tmp / "truth" / f"pair_{k:03d}_depth.npz")
        # the scan frame is the pile frame (the calibration's T_pile_cam); the crane knows where its
        # camera is only to a few centimetres / a fraction of a degree: perturb the true pose
        err_yaw = math.radians(rng.normal(0, pose_error_deg))
        err_t = np.array([*rng.normal(0, pose_error_m, 2), rng.normal(0, pose_error_m / 2)])
        T_site_scan = make_T(rot_z(err_yaw), err_t) @ pile.georef.matrix()
        write_scan_pose(ScanPose(site[0], site[1], site[2], tuple(tuple(float(v) for v in r) for r in T_site_scan)),
                        tmp / "scan" / "scan_pose.json")
        survey = simulate_survey(pile_endpoints_site(pile), pile.georef, rng, n_float=n_float)
        write_gnss_csv(survey, tmp / "gnss.csv")
        info = {"format": "loggrasp.twin-scan", "format_version": SCAN_FORMAT_VERSION, "seed": seed,
                "n_logs": n_logs, "n_obstacles": n_obst, "packed": packed, "site": list(site),
                "n_float": n_float, "rig": rig0.to_dict(), "pairs": nx * ny, "spacing_m": list(spacing_m),
                "pose_error": {"sigma_m": pose_error_m, "sigma_deg": pose_error_deg}}
        atomic_write_bytes(tmp / "scan.json", json.dumps(info, indent=1, default=str).encode())
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
