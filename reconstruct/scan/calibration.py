"""A stereo pair's calibration, from whichever file the pair folder holds.

A pair folder may hold

* ``calibration.yaml``: OpenCV FileStorage (``K1 D1 K2 D2 R T image_size``, optionally the left
  camera's pose ``T_pile_cam``; :func:`synth.geometry.calibration.read_calibration_yaml`);
* a ZED calibration: the factory ``SN<serial>.conf`` that ZED cameras come with, or ``zed.conf``
  (the same INI layout; the twin writes one with a ``[LOGGRASP]`` section holding the pose;
  :func:`synth.geometry.calibration.read_zed_conf`). A ZED file describes every resolution the camera has
  (``[LEFT_CAM_HD]``, ``[LEFT_CAM_FHD]``...): the section matching the images' size is read
  (1280x720 is ``HD``, 1920x1080 ``FHD``, 2208x1242 ``2K``, 672x376 ``VGA``; a ``[LOGGRASP]``
  section names its own).

Either alone is enough. When both are there they must agree (intrinsics, distortion, the
rotation and baseline between the cameras, and the pose when both carry one): a disagreement is a
:class:`~reconstruct.errors.CalibrationError` naming both values, because the reconstruction
cannot know which one is right. Every unreadable or corrupt file is a one-line
:class:`~reconstruct.errors.CalibrationError` naming the file and what is wrong with it.
"""

from __future__ import annotations

import configparser
from pathlib import Path

import numpy as np

from reconstruct.errors import CalibrationError

YAML_NAME = "calibration.yaml"
ZED_NAMES = ("zed.conf",)
ZED_PATTERN = "SN*.conf"

#: how closely the two calibrations of a pair must agree: pixels (focal lengths, principal
#: points), distortion coefficients, radians (the rotation between the cameras), metres (the
#: baseline and the pose's translation) and the pose's rotation entries
TOLERANCE = {"px": 0.05, "dist": 1e-4, "rad": 1e-5, "m": 5e-5, "rot": 1e-5}


def zed_files(folder: str | Path) -> list[Path]:
    """The ZED calibration files of a pair folder (``SN*.conf``, ``zed.conf``), sorted by name."""
    folder = Path(folder)
    found = {p for p in folder.glob(ZED_PATTERN) if p.is_file()}
    found |= {folder / n for n in ZED_NAMES if (folder / n).is_file()}
    return sorted(found)


def _one_line(exc: BaseException) -> str:
    """An exception's message on one line (OpenCV's span several, with the source file)."""
    text = " ".join(str(exc).split())
    if "error: (" in text:  # "OpenCV(5.0) /path/file.cpp:123: error: (-212:Parsing error) what in function 'f'"
        text = text[text.index("error: (") + len("error: "):]
    return text or type(exc).__name__


def read_yaml(path: str | Path) -> object:
    """``calibration.yaml`` as a :class:`synth.geometry.calibration.StereoCalibration`; every problem with the file a
    one-line :class:`CalibrationError` naming it."""
    import cv2

    from synth.geometry.calibration import StereoFormatError, read_calibration_yaml

    path = Path(path)
    try:
        return read_calibration_yaml(path)
    except (StereoFormatError, ValueError, KeyError, TypeError, IndexError, AttributeError, OSError, SystemError,
            cv2.error) as exc:
        # a truncated or non-YAML file raises cv2.error (several lines), a binary one UnicodeDecodeError
        msg = _one_line(exc)
        if str(path) not in msg:
            msg = f"{path}: {msg}"
        raise CalibrationError(f"corrupt calibration {msg}; re-export it (OpenCV FileStorage YAML with "
                               "K1 D1 K2 D2 R T image_size)") from exc


def zed_resolution(path: Path, cfg: configparser.ConfigParser, image_size: tuple[int, int]) -> str:
    """The resolution section of a ZED file that matches ``image_size`` (width, height) [px]."""
    from synth.geometry.calibration import ZED_RESOLUTIONS

    have = sorted(s[len("LEFT_CAM_"):] for s in cfg.sections() if s.startswith("LEFT_CAM_"))
    if cfg.has_section("LOGGRASP"):
        ours = cfg["LOGGRASP"]
        try:
            size = (int(ours.get("image_width", "-1")), int(ours.get("image_height", "-1")))
        except ValueError as exc:
            raise CalibrationError(f"corrupt ZED calibration {path}: [LOGGRASP] image size: {exc}") from exc
        if size == tuple(image_size) and ours.get("resolution"):
            return ours["resolution"]
    res = ZED_RESOLUTIONS.get(tuple(image_size))
    if res is None or res not in have:
        sizes = {v: k for k, v in ZED_RESOLUTIONS.items()}
        listing = ", ".join(f"{r} ({sizes[r][0]}x{sizes[r][1]})" if r in sizes else r for r in have) or "none"
        raise CalibrationError(
            f"{path} has no calibration for {image_size[0]}x{image_size[1]} px images (its resolutions: {listing}); "
            "use the images at one of those sizes, or the ZED file of this camera")
    return res


def read_zed(path: str | Path, image_size: tuple[int, int]) -> object:
    """A ZED ``SN*.conf`` / ``zed.conf`` at the resolution of ``image_size`` (width, height) [px], as a
    :class:`synth.geometry.calibration.StereoCalibration` (identity pose when the file has none); every problem a
    one-line :class:`CalibrationError` naming the file."""
    import cv2

    from synth.geometry.calibration import StereoFormatError, read_zed_conf

    path = Path(path)
    cfg = configparser.ConfigParser()
    cfg.optionxform = str
    try:
        cfg.read_string(path.read_text())
    except (OSError, UnicodeError, configparser.Error) as exc:
        raise CalibrationError(f"corrupt ZED calibration {path}: {_one_line(exc)}; it must be the camera's "
                               "SN<serial>.conf INI file") from exc
    res = zed_resolution(path, cfg, image_size)
    if not cfg.has_section("STEREO"):
        raise CalibrationError(f"corrupt ZED calibration {path}: no [STEREO] section (Baseline, TY, TZ, RX, CV, RZ)")
    try:
        calib = read_zed_conf(path, resolution=res, image_size=tuple(image_size))
    except (StereoFormatError, ValueError, KeyError, TypeError, IndexError, AttributeError, OSError,
            cv2.error) as exc:
        msg = _one_line(exc)
        raise CalibrationError(f"corrupt ZED calibration {msg if str(path) in msg else f'{path}: {msg}'}") from exc
    for name, v in (("K", calib.K_left), ("K", calib.K_right), ("distortion", calib.D_left),
                    ("distortion", calib.D_right), ("baseline", calib.T)):
        if not np.all(np.isfinite(v)):
            raise CalibrationError(f"corrupt ZED calibration {path}: a non-finite {name} value in [{res}]")
    return calib


def _differences(a: object, b: object) -> list[str]:
    """What differs between two calibrations beyond :data:`TOLERANCE`, as 'what: value vs value'."""
    import cv2

    out = []
    for side, Ka, Kb in (("left", a.K_left, b.K_left), ("right", a.K_right, b.K_right)):
        for name, (i, j) in (("fx", (0, 0)), ("fy", (1, 1)), ("cx", (0, 2)), ("cy", (1, 2))):
            if abs(Ka[i, j] - Kb[i, j]) > TOLERANCE["px"]:
                out.append(f"{side} {name} {Ka[i, j]:.2f} px vs {Kb[i, j]:.2f} px")
    for side, Da, Db in (("left", a.D_left, b.D_left), ("right", a.D_right, b.D_right)):
        for name, va, vb in zip(("k1", "k2", "p1", "p2", "k3"), Da, Db):
            if abs(va - vb) > TOLERANCE["dist"]:
                out.append(f"{side} {name} {va:.5f} vs {vb:.5f}")
    if abs(a.baseline_m - b.baseline_m) > TOLERANCE["m"]:
        out.append(f"baseline {a.baseline_m * 1000:.2f} mm vs {b.baseline_m * 1000:.2f} mm")
    elif np.max(np.abs(a.T - b.T)) > TOLERANCE["m"]:
        out.append(f"T {np.round(a.T * 1000, 2).tolist()} mm vs {np.round(b.T * 1000, 2).tolist()} mm")
    ra, rb = cv2.Rodrigues(a.R)[0].ravel(), cv2.Rodrigues(b.R)[0].ravel()
    if np.max(np.abs(ra - rb)) > TOLERANCE["rad"]:
        out.append(f"R (Rodrigues) {np.round(ra, 6).tolist()} rad vs {np.round(rb, 6).tolist()} rad")
    return out


def read_pair_calibration(folder: str | Path, image_size: tuple[int, int]) -> tuple[object, str]:
    """The calibration of the pair in ``folder`` whose images are ``image_size`` (width, height) [px],
    and the file(s) it came from (see the module docstring). Raises :class:`CalibrationError`."""
    folder = Path(folder)
    yaml = folder / YAML_NAME
    zeds = zed_files(folder)
    if len(zeds) > 1:
        raise CalibrationError(f"{folder} holds {len(zeds)} ZED calibrations ({', '.join(p.name for p in zeds)}): "
                               "keep the one of the camera that took this pair")
    zed = zeds[0] if zeds else None
    if not yaml.exists() and zed is None:
        raise CalibrationError(f"{folder} has no calibration: every pair needs {YAML_NAME} (K1 D1 K2 D2 R T "
                               "image_size) or the camera's ZED SN<serial>.conf")
    cal_yaml = read_yaml(yaml) if yaml.exists() else None
    cal_zed = read_zed(zed, image_size) if zed is not None else None
    if cal_yaml is None:
        return cal_zed, zed.name
    if cal_zed is None:
        return cal_yaml, yaml.name
    diffs = _differences(cal_yaml, cal_zed)
    pose_a, pose_b = cal_yaml.T_pile_cam, cal_zed.T_pile_cam
    if zed_has_pose(zed) and yaml_has_pose(yaml):
        dt = float(np.max(np.abs(pose_a[:3, 3] - pose_b[:3, 3])))
        dr = float(np.max(np.abs(pose_a[:3, :3] - pose_b[:3, :3])))
        if dt > TOLERANCE["m"] or dr > TOLERANCE["rot"]:
            diffs.append(f"T_pile_cam position {np.round(pose_a[:3, 3], 4).tolist()} m vs "
                         f"{np.round(pose_b[:3, 3], 4).tolist()} m" if dt > TOLERANCE["m"] else
                         f"T_pile_cam rotation differs by up to {dr:.2g}")
    if diffs:
        more = f" (and {len(diffs) - 3} more)" if len(diffs) > 3 else ""
        raise CalibrationError(
            f"{folder}: {yaml.name} and {zed.name} disagree: {'; '.join(diffs[:3])}{more} ({yaml.name} first); "
            f"keep the right one and delete or fix the other")
    return cal_yaml, f"{yaml.name} + {zed.name}"


def yaml_has_pose(path: str | Path) -> bool:
    """Whether a ``calibration.yaml`` holds the camera's pose (``T_pile_cam``)."""
    from reconstruct.scan.sfm import pair_has_pose

    return pair_has_pose(path)


def zed_has_pose(path: str | Path) -> bool:
    """Whether a ZED file holds the camera's pose (the twin's ``[LOGGRASP] T_pile_cam``)."""
    cfg = configparser.ConfigParser()
    cfg.optionxform = str
    try:
        cfg.read_string(Path(path).read_text())
    except (OSError, UnicodeError, configparser.Error):
        return False
    return cfg.has_section("LOGGRASP") and bool(cfg["LOGGRASP"].get("T_pile_cam", "").strip())


def pair_pose_present(folder: str | Path) -> bool:
    """Whether the calibration of the pair in ``folder`` carries its camera pose (``T_pile_cam``):
    ``calibration.yaml`` when there is one, else its ZED file."""
    folder = Path(folder)
    if (folder / YAML_NAME).exists():
        return yaml_has_pose(folder / YAML_NAME)
    zeds = zed_files(folder)
    return bool(zeds) and zed_has_pose(zeds[0])
