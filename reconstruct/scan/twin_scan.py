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
                                            (``n_float``), logs left out (``n_unsurveyed``: chosen among
                                            those the scan shows most of)
    DIR/truth/pile.json                     the ground-truth pile (georeferenced)
    DIR/truth/pair_NNN_depth.npz            ground-truth depth and instances of each left image
    DIR/truth/poses.json                    true left-camera pose of every pair (T_pile_cam)
    DIR/scan.json                           what was made, and how

An *unposed* scan (``unposed=True``, ``loggrasp synth scan --unposed``) is what a handheld or
boom-mounted camera with no pose sensor brings back: the rig moved between pairs (grid positions
jittered by ``jitter_m``, heights by ``jitter_height_m``, yaw by ``jitter_yaw_deg``, tilts about
both image axes by ``jitter_tilt_deg``), the calibrations carry no ``T_pile_cam`` (neither
``calibration.yaml`` nor ``zed.conf``; ``meta.json`` keeps the intrinsics only) and there is no
``scan_pose.json``: the reconstruction has to recover the pair poses (SfM) and the scan's place
in the site frame (from the GNSS end points). The truth keeps the true poses.

Other surveys of the same scan (:func:`write_twin_survey`: all fixed, or degraded: half the ends
float and a log left out) are drawn from the truth with their own random stream, for benchmarks
that compare survey conditions on the same images.

It lives in :mod:`reconstruct` (not :mod:`synth`) because the GNSS CSV format is this package's.
"""

from __future__ import annotations

import copy
import dataclasses
import io
import json
import math
import os
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from synth.geometry.frames import make_T, rot_z
from synth.common.files import apply_umask, atomic_write_bytes
from synth.scene.pile import Georeference, PileSpec, write_pile

if TYPE_CHECKING:
    from reconstruct.scan.plan import ScanPlan, ScanPlanConfig

#: 1.1: scan.json has ``plan`` (None: the grid was given, not planned from the survey)
SCAN_FORMAT_VERSION = "1.1"
DEFAULT_SITE = (64.1, 20.0, 250.0)  # near Umeå inland: lat [deg], lon [deg], ellipsoidal h [m]


def georeference_pile(pile: PileSpec, site: tuple[float, float, float], rng: np.random.Generator) -> PileSpec:
    """Place the pile on Earth: site origin at ``site`` (SWEREF 99 lat/lon/h), pile frame turned by a
    random yaw and shifted a few metres from the origin (the pile frame is arbitrary in the field)."""
    yaw = float(rng.uniform(-math.pi, math.pi))
    t = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), 0.0])
    T = make_T(rot_z(yaw), t)
    return replace(pile, georef=Georeference(origin_lat_deg=site[0], origin_lon_deg=site[1], origin_h_m=site[2],
                                             T_site_pile=tuple(tuple(float(v) for v in row) for row in T)))


def plan_twin_scan(pile: PileSpec, survey, cfg: "ScanPlanConfig") -> "ScanPlan":
    """The scan plan (:func:`reconstruct.scan.plan.plan_scan`) of a georeferenced twin pile from a survey
    of it (a :class:`reconstruct.survey.gnss.GnssSurvey`): its points in the pile frame, heights above the
    pile's terrain, each point's horizontal sigma its reported accuracy, the rig along the surveyed logs."""
    from reconstruct.fitting.survey_points import point_accuracy
    from reconstruct.scan.plan import plan_scan, survey_yaw

    ends = survey.ends_site(pile.georef)
    T_pile_site = np.linalg.inv(pile.georef.matrix())
    pts, sig, pairs = [], [], []
    for log_id, pair in ends.items():
        in_pile = []
        for end, p in zip("ab", pair):
            if p is None:
                in_pile.append(None)
                continue
            q = T_pile_site[:3, :3] @ np.asarray(p, dtype=float) + T_pile_site[:3, 3]
            q[2] -= pile.terrain.height_at(q[0], q[1])
            pts.append(q)
            sig.append(point_accuracy(survey.point(log_id, end))[0])
            in_pile.append(q)
        pairs.append(tuple(in_pile))
    return plan_scan(np.array(pts), np.array(sig), survey_yaw(pairs), cfg)


#: a planned pair is rendered when at least this share of its ground footprint lies on the twin's terrain
#: patch: beyond it the twin renders nothing to match (the field has ground there), and a pair with less
#: depth than StereoConfig.min_valid_fraction (0.3) of its pixels is refused; half leaves room for the
#: disparity band and the border [-]
TWIN_MIN_GROUND_SHARE = 0.5


def pairs_beyond_terrain(pile: PileSpec, planned: "ScanPlan", cfg: "ScanPlanConfig", n: int = 11) -> frozenset[int]:
    """Grid indices of a plan's pairs whose ground footprint (``n`` x ``n`` samples) lies less than
    :data:`TWIN_MIN_GROUND_SHARE` on the pile's terrain patch (a square of ``extent_m`` about the origin)."""
    lo_a, hi_a, lo_c, hi_c = cfg.footprint_slopes()
    a, c = np.meshgrid(np.linspace(lo_a, hi_a, n) * cfg.height_m, np.linspace(lo_c, hi_c, n) * cfg.height_m)
    offsets = np.column_stack([a.ravel(), c.ravel()]) @ planned.axes()
    half = pile.terrain.extent_m / 2
    out = set()
    for k, xy in enumerate(planned.pair_positions()):
        on = (np.abs(xy + offsets) <= half).all(axis=1).mean()
        if on < TWIN_MIN_GROUND_SHARE:
            out.add(k)
    return frozenset(out)


def _rig_over_pile(pile: PileSpec, height_m: float, hfov_deg: float,
                   image_size: tuple[int, int] = (1280, 720), planned: "ScanPlan | None" = None):
    """The rig of the grid's centre: over the true ends' centre, the long image side along the logs' mean
    direction; ``planned``: over the plan's centre, along its direction."""
    from synth.render.stereo import StereoRigConfig

    if planned is not None:
        centre = np.array([*planned.centre_xy, 0.0])
        yaw = math.degrees(planned.yaw_rad)
    else:
        ends = np.array([e for log in pile.logs for e in log.endpoints_m()])
        centre = ends.mean(axis=0)
        # long image side along the logs' mean direction
        axes = np.array([log.axis()[:2] for log in pile.logs])
        axes *= np.sign(axes @ axes[0])[:, None]
        yaw = math.degrees(math.atan2(axes[:, 1].mean(), axes[:, 0].mean()))
    return StereoRigConfig(width_px=int(image_size[0]), height_px=int(image_size[1]), height_m=height_m,
                           hfov_deg=hfov_deg,
                           target_m=(float(centre[0]), float(centre[1]), float(pile.terrain.height_at(*centre[:2]))),
                           yaw_deg=yaw)


def _handheld_pose(rig, rng: np.random.Generator, jitter_m: float, jitter_height_m: float,
                   jitter_yaw_deg: float, jitter_tilt_deg: float) -> np.ndarray:
    """``T_pile_cam`` of a rig held by hand / on a boom near ``rig``'s straight-down pose: moved
    horizontally (uniform within ``jitter_m``), up or down (``jitter_height_m``), turned about the
    vertical (``jitter_yaw_deg``) and tilted about both image axes (``jitter_tilt_deg``)."""
    from synth.geometry.frames import rot_z

    T = rig.camera_pose()
    ax, ay = np.radians(rng.uniform(-jitter_tilt_deg, jitter_tilt_deg, 2))
    Rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    Ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    R = rot_z(math.radians(rng.uniform(-jitter_yaw_deg, jitter_yaw_deg))) @ T[:3, :3] @ Rx @ Ry
    t = T[:3, 3] + np.array([*rng.uniform(-jitter_m, jitter_m, 2), rng.uniform(-jitter_height_m, jitter_height_m)])
    return make_T(R, t)


def _strip_pose(pair_dir: Path) -> None:
    """Make a saved pair look like one from a camera with no pose sensor: calibration.yaml and
    zed.conf without ``T_pile_cam``, meta.json without the rig's pose."""
    import configparser

    import cv2

    from synth.geometry.calibration import CALIB_FORMAT_NAME, CALIB_FORMAT_VERSION, read_calibration_yaml

    calib = read_calibration_yaml(pair_dir / "calibration.yaml")
    fs = cv2.FileStorage("calibration.yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    fs.write("format", CALIB_FORMAT_NAME)
    fs.write("format_version", CALIB_FORMAT_VERSION)
    fs.write("image_size", np.array(calib.image_size, dtype=np.int32).reshape(1, 2))
    for key, value in (("K1", calib.K_left), ("D1", calib.D_left.reshape(1, 5)), ("K2", calib.K_right),
                       ("D2", calib.D_right.reshape(1, 5)), ("R", calib.R), ("T", calib.T.reshape(3, 1))):
        fs.write(key, value)
    fs.write("baseline_m", calib.baseline_m)
    atomic_write_bytes(pair_dir / "calibration.yaml", fs.releaseAndGetString().encode())
    cfg = configparser.ConfigParser()
    cfg.optionxform = str
    cfg.read(pair_dir / "zed.conf")
    if cfg.has_section("LOGGRASP"):
        cfg.remove_option("LOGGRASP", "T_pile_cam")
    buf = io.StringIO()
    cfg.write(buf)
    atomic_write_bytes(pair_dir / "zed.conf", buf.getvalue().encode())
    meta = json.loads((pair_dir / "meta.json").read_text())
    rig = meta.get("rig", {})
    for key in ("height_m", "target_m", "yaw_deg", "tilt_deg", "T_pile_cam"):
        rig.pop(key, None)
    atomic_write_bytes(pair_dir / "meta.json", json.dumps(meta, indent=1).encode())


def make_twin_scan(out_dir: str | Path, seed: int, logs: tuple[int, int] = (3, 5), obstacles: tuple[int, int] = (0, 2),
                   packed: bool = False, site: tuple[float, float, float] = DEFAULT_SITE,
                   n_float: int = 2, height_m: float = 3.0, hfov_deg: float = 50.0,
                   n_unsurveyed: int = 0, pile_spread_m: float | None = None, yaw_spread_rad: float | None = None,
                   grid: tuple[int, int] = (2, 2), spacing_m: tuple[float, float] = (1.4, 1.0),
                   plan: "ScanPlanConfig | None" = None,
                   pose_error_m: float = 0.03, pose_error_deg: float = 0.5,
                   unposed: bool = False, handheld: bool | None = None,
                   image_size: tuple[int, int] = (1280, 720), jitter_m: float = 0.15,
                   jitter_height_m: float = 0.2, jitter_yaw_deg: float = 8.0, jitter_tilt_deg: float = 4.0,
                   progress: "Callable[[str], None] | None" = None) -> Path:
    """Generate a pile, render its stereo pairs and survey its log ends; write a scan folder.

    ``unposed``: calibrations without ``T_pile_cam`` and no ``scan_pose.json`` (see the module
    docstring). ``handheld`` (default: ``unposed``): the rig moves between pairs (``jitter_*``)
    instead of holding a straight-down grid; the same seed gives the same images with or without
    ``unposed``. ``image_size``: (width, height) [px]. ``pile_spread_m`` / ``yaw_spread_rad``: how far
    the dropped logs' centres and yaws scatter (None: the generator's defaults; larger: a loose pile). The pile, the survey and the scan pose
    error depend on ``seed`` only. ``n_float``: survey points with an RTK float fix;
    ``n_unsurveyed``: logs left out of the survey (among those the scan shows most of,
    :func:`visible_logs`; the other points are as without it).

    ``plan``: size the grid from the survey (:func:`reconstruct.scan.plan.plan_scan`) instead of ``grid``
    and ``spacing_m``: the smallest grid covering every surveyed end (the default survey of every log,
    drawn before the scan from the same stream: the written survey when ``n_unsurveyed`` is 0), centred on
    the survey and turned along its logs; ``plan.height_m`` / ``plan.hfov_deg`` / its image size replace
    ``height_m`` / ``hfov_deg`` / ``image_size``. ``scan.json`` records the plan. Without it the rig is aimed
    at the true ends' centre.

    Written into a temporary sibling folder and renamed into place (never half-written)."""
    from reconstruct.survey.gnss import pile_endpoints_site, simulate_survey, write_gnss_csv
    from synth.scene.generate import GenerationConfig, generate_pile
    from synth.geometry.geodesy import check_geodetic

    check_geodetic(site[0], site[1], "--site")
    say = progress or (lambda s: None)
    say("generating and settling the pile")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5CA7]))
    n_logs = int(rng.integers(logs[0], logs[1] + 1))
    n_obst = int(rng.integers(obstacles[0], obstacles[1] + 1))
    spread = {k: float(v) for k, v in (("pile_spread_m", pile_spread_m), ("yaw_spread_rad", yaw_spread_rad))
              if v is not None}
    pile, _ = generate_pile(seed, GenerationConfig(n_logs=n_logs, n_obstacles=n_obst, packed=packed, **spread))
    pile = georeference_pile(pile, site, rng)

    out = Path(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        apply_umask(tmp, directory=True)
        (tmp / "truth").mkdir()
        write_pile(pile, tmp / "truth" / "pile.json")
        from reconstruct.registration import ScanPose, write_scan_pose

        # the scan pose error is drawn before the survey (the order of the seed's stream): drawn here so a
        # plan can see the survey before the pairs are rendered; rendering draws from no stream
        err_yaw = math.radians(rng.normal(0, pose_error_deg))
        err_t = np.array([*rng.normal(0, pose_error_m, 2), rng.normal(0, pose_error_m / 2)])
        planned = None
        if plan is not None:
            planned = plan_twin_scan(pile, simulate_survey(pile_endpoints_site(pile), pile.georef, copy.deepcopy(rng),
                                                           n_float=n_float), plan)
            height_m, hfov_deg, grid, spacing_m = plan.height_m, plan.hfov_deg, planned.grid, planned.spacing_m
            image_size = (plan.width_px, plan.height_px)
            say(f"scan plan from the survey: {planned.describe()}")
        rig0 = _rig_over_pile(pile, height_m, hfov_deg, image_size, planned)
        moving = unposed if handheld is None else bool(handheld)
        # the rig's motion has its own stream: pile, survey and pose error do not depend on it
        jitter = (np.random.default_rng(np.random.SeedSequence([int(seed), 0x5CA7, 1])),
                  jitter_m, jitter_height_m, jitter_yaw_deg, jitter_tilt_deg) if moving else None
        beyond = frozenset() if planned is None else pairs_beyond_terrain(pile, planned, plan)
        if beyond:
            say(f"{len(beyond)} planned pair(s) over no terrain (the twin's {pile.terrain.extent_m:g} m patch) "
                "not rendered")
        poses = _render_pairs(tmp, pile, rig0, grid, spacing_m, jitter, unposed, say, beyond)
        atomic_write_bytes(tmp / "truth" / "poses.json", json.dumps(
            {"format": "loggrasp.twin-scan-poses", "format_version": SCAN_FORMAT_VERSION,
             "frame": "pile (truth/pile.json)", "T_pile_cam": poses}, indent=1).encode())
        # the scan frame is the pile frame (the calibration's T_pile_cam); the crane knows where its
        # camera is only to a few centimetres / a fraction of a degree: perturb the true pose
        T_site_scan = make_T(rot_z(err_yaw), err_t) @ pile.georef.matrix()
        if not unposed:
            write_scan_pose(ScanPose(site[0], site[1], site[2], tuple(tuple(float(v) for v in r) for r in T_site_scan)),
                            tmp / "scan" / "scan_pose.json")
        say("simulating the RTK survey of the log ends")
        omit = _unsurveyed(tmp, pile, n_unsurveyed, np.random.default_rng(np.random.SeedSequence([int(seed), 0x5CA7, 2])))
        survey = simulate_survey(pile_endpoints_site(pile), pile.georef, rng, n_float=n_float, omit=omit)
        write_gnss_csv(survey, tmp / "gnss.csv")
        info = {"format": "loggrasp.twin-scan", "format_version": SCAN_FORMAT_VERSION, "seed": seed,
                "n_logs": n_logs, "n_obstacles": n_obst, "packed": packed, "spread": spread, "site": list(site),
                "n_float": n_float, "unsurveyed": list(omit), "rig": rig0.to_dict(), "pairs": len(poses),
                "spacing_m": list(spacing_m),
                "pose_error": {"sigma_m": pose_error_m, "sigma_deg": pose_error_deg},
                "image_size": list(image_size), "unposed": bool(unposed), "handheld": bool(moving),
                "plan": None if planned is None else planned.to_dict() | {"config": dataclasses.asdict(plan),
                                                                          "beyond_terrain": sorted(beyond)},
                "jitter": ({"m": jitter_m, "height_m": jitter_height_m, "yaw_deg": jitter_yaw_deg,
                            "tilt_deg": jitter_tilt_deg} if moving else None)}
        atomic_write_bytes(tmp / "scan.json", json.dumps(info, indent=1, default=str).encode())
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def _render_pairs(tmp: Path, pile, rig0, grid: tuple[int, int], spacing_m: tuple[float, float], jitter,
                  unposed: bool, say: Callable[[str], None], skip: frozenset[int] = frozenset()) -> dict[str, list]:
    """Render the grid of stereo pairs over the pile into ``tmp/scan`` (their true depth and
    instance maps into ``tmp/truth``); ``jitter``: (rng, m, height m, yaw deg, tilt deg) of a rig
    that moves between pairs, or None for a straight-down grid; ``skip``: grid indices (along first)
    not rendered, the others numbered on. Returns each pair's true ``T_pile_cam``."""
    import datetime as dt

    from synth.render.stereo import StereoRenderer

    captured = dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds").replace("+00:00", "Z")
    yaw = math.radians(rig0.yaw_deg)
    along, across = np.array([math.cos(yaw), math.sin(yaw)]), np.array([-math.sin(yaw), math.cos(yaw)])
    nx, ny = grid
    centre = np.asarray(rig0.target_m[:2])
    poses = {}
    n_render = nx * ny - len(skip)
    with StereoRenderer(rig0.renderer) as renderer:
        for iy in range(ny):
            for ix in range(nx):
                if iy * nx + ix in skip:
                    continue
                k = len(poses)
                xy = centre + along * (ix - (nx - 1) / 2) * spacing_m[0] + across * (iy - (ny - 1) / 2) * spacing_m[1]
                rig = replace(rig0, target_m=(float(xy[0]), float(xy[1]), float(pile.terrain.height_at(*xy))))
                if jitter is not None:
                    T = _handheld_pose(rig, *jitter)
                    rig = replace(rig, T_pile_cam=tuple(tuple(float(v) for v in r) for r in T))
                say(f"rendering stereo pair {k + 1} of {n_render}")
                pair = renderer.render(pile, rig)
                pair.meta.update({"camera": "ZED 2 (twin)", "captured_utc": captured})
                pair_dir = pair.save(tmp / "scan" / f"pair_{k:03d}")
                os.replace(pair_dir / "depth_left.npz", tmp / "truth" / f"pair_{k:03d}_depth.npz")
                poses[f"pair_{k:03d}"] = pair.calibration.T_pile_cam.tolist()
                if unposed:
                    _strip_pose(pair_dir)
    return poses


def visible_logs(scan_root: str | Path, n_logs: int) -> np.ndarray:
    """How many left-image pixels show each log, over all pairs of a twin scan (its
    ``truth/pair_NNN_depth.npz`` instance maps), shape (n_logs,)."""
    counts = np.zeros(n_logs)
    for f in sorted((Path(scan_root) / "truth").glob("pair_*_depth.npz")):
        with np.load(f) as z:
            inst = z["instance"]
        c = np.bincount(np.clip(inst.ravel(), 0, n_logs + 1), minlength=n_logs + 2)
        counts += c[1:n_logs + 1]
    return counts


def _unsurveyed(scan_root: Path, pile: PileSpec, n: int, rng: np.random.Generator) -> list[str]:
    """Ids of ``n`` logs to leave out of a survey: chosen at random among those the scan shows at least
    half as much of as of the most visible log (a log clearly in the scan)."""
    if n <= 0:
        return []
    if n >= pile.n_logs:
        raise ValueError(f"n_unsurveyed must be below the number of logs ({pile.n_logs}), got {n}")
    seen = visible_logs(scan_root, pile.n_logs)
    pool = np.flatnonzero(seen >= 0.5 * seen.max())
    if len(pool) < n:
        pool = np.argsort(-seen)[:n]
    return [f"log{i}" for i in sorted(rng.choice(pool, size=n, replace=False).tolist())]


def write_twin_survey(scan_root: str | Path, path: str | Path, n_float: int = 0, n_unsurveyed: int = 0,
                      seed: int | None = None) -> Path:
    """Another survey of a twin scan's pile (``scan_root``: a :func:`make_twin_scan` folder): RTK noise
    as :func:`reconstruct.survey.gnss.simulate_survey` draws it, ``n_float`` float points (``-1``: half the
    surveyed ends), ``n_unsurveyed`` logs left out (:func:`visible_logs`). Drawn from its own random
    stream of (``seed``, default the scan's; ``n_float``; ``n_unsurveyed``). Returns the CSV path."""
    from reconstruct.survey.gnss import pile_endpoints_site, simulate_survey, write_gnss_csv
    from synth.scene.pile import read_pile

    root = Path(scan_root)
    pile = read_pile(root / "truth" / "pile.json")
    if seed is None:
        seed = int(json.loads((root / "scan.json").read_text())["seed"])
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5CA7, 3, int(n_float) + 1, int(n_unsurveyed)]))
    omit = _unsurveyed(root, pile, n_unsurveyed, rng)
    if n_float < 0:
        n_float = (2 * (pile.n_logs - len(omit))) // 2
    survey = simulate_survey(pile_endpoints_site(pile), pile.georef, rng, n_float=n_float, omit=omit)
    return write_gnss_csv(survey, path)
