"""The stereo calibration formats, read by reconstruction and written by the simulator's stereo
renderer (:mod:`synth.render.stereo`): :class:`StereoCalibration` (OpenCV conventions, metres),
``calibration.yaml`` (OpenCV ``FileStorage``: ``K1 D1 K2 D2 R T image_size``, plus ``baseline_m``,
``T_pile_cam`` and the format version) and a ZED ``SN<serial>.conf``-like INI file.

Camera frames follow OpenCV: x right, y down, z forward. ``T_pile_cam`` maps left-camera
coordinates to the pile frame; ``x_right = R @ x_left + T``. Nothing here imports the simulator.
"""

from __future__ import annotations

import configparser
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from synth.common.files import atomic_write_bytes
from synth.common.formats import VersionedJson
from synth.errors import SynthError
from synth.geometry.frames import apply_T, invert_T, make_T

CALIB_FORMAT_NAME = "loggrasp.stereo_calibration"
CALIB_FORMAT_VERSION = "1.0"

#: ZED resolution names by image size (width, height); other sizes are written as "CUSTOM".
ZED_RESOLUTIONS = {(2208, 1242): "2K", (1920, 1080): "FHD", (1280, 720): "HD", (672, 376): "VGA"}


class StereoFormatError(SynthError):
    """A stereo pair folder or calibration file is missing, malformed or of an unsupported version."""


FIX = "upgrade loggrasp or re-export the file"  # what a reader of a too-new file says to do
CALIBRATION = VersionedJson(CALIB_FORMAT_NAME, CALIB_FORMAT_VERSION, "stereo calibration", StereoFormatError,
                            fix=FIX)
ZED_CALIBRATION = VersionedJson(CALIB_FORMAT_NAME + ".zed", CALIB_FORMAT_VERSION, "ZED calibration",
                                StereoFormatError, fix=FIX)


@dataclass
class StereoCalibration:
    """Pinhole calibration of a stereo pair (OpenCV conventions, metres).

    ``x_right = R @ x_left + T`` for a point in left- and right-camera coordinates.
    """

    K_left: np.ndarray  # 3x3 [px]
    K_right: np.ndarray  # 3x3 [px]
    D_left: np.ndarray  # (5,) k1 k2 p1 p2 k3 [-]
    D_right: np.ndarray  # (5,) [-]
    R: np.ndarray  # 3x3 rotation left -> right
    T: np.ndarray  # (3,) [m] translation left -> right
    image_size: tuple[int, int]  # (width, height) [px]
    T_pile_cam: np.ndarray = field(default_factory=lambda: np.eye(4))  # left camera pose (4x4)

    def __post_init__(self) -> None:
        self.K_left = np.asarray(self.K_left, dtype=np.float64).reshape(3, 3)
        self.K_right = np.asarray(self.K_right, dtype=np.float64).reshape(3, 3)
        self.D_left = np.asarray(self.D_left, dtype=np.float64).reshape(-1)
        self.D_right = np.asarray(self.D_right, dtype=np.float64).reshape(-1)
        self.R = np.asarray(self.R, dtype=np.float64).reshape(3, 3)
        self.T = np.asarray(self.T, dtype=np.float64).reshape(3)
        self.T_pile_cam = np.asarray(self.T_pile_cam, dtype=np.float64).reshape(4, 4)
        self.image_size = (int(self.image_size[0]), int(self.image_size[1]))
        if self.D_left.shape != (5,) or self.D_right.shape != (5,):
            raise ValueError("distortion must have 5 coefficients (k1 k2 p1 p2 k3)")
        if not np.allclose(self.R @ self.R.T, np.eye(3), atol=1e-6):
            raise ValueError("R must be a rotation matrix")

    @property
    def baseline_m(self) -> float:
        return float(np.linalg.norm(self.T))

    @property
    def T_pile_right(self) -> np.ndarray:
        """Pose of the right camera in the pile frame (4x4)."""
        return self.T_pile_cam @ invert_T(make_T(self.R, self.T))

    def project(self, points_pile: np.ndarray, camera: str = "left") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pinhole projection (no distortion) of (N, 3) pile-frame points: (u, v, z) arrays."""
        T_pile = self.T_pile_cam if camera == "left" else self.T_pile_right
        K = self.K_left if camera == "left" else self.K_right
        p = apply_T(invert_T(T_pile), np.atleast_2d(points_pile))
        z = p[:, 2]
        return K[0, 0] * p[:, 0] / z + K[0, 2], K[1, 1] * p[:, 1] / z + K[1, 2], z

    def allclose(self, other: "StereoCalibration", atol: float = 1e-9) -> bool:
        return (self.image_size == other.image_size and all(
            np.allclose(getattr(self, k), getattr(other, k), atol=atol)
            for k in ("K_left", "K_right", "D_left", "D_right", "R", "T", "T_pile_cam")))


def calibration_yaml_text(calib: StereoCalibration) -> str:
    """The calibration as OpenCV FileStorage YAML (K1 D1 K2 D2 R T image_size, ...)."""
    import cv2

    fs = cv2.FileStorage("calibration.yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    fs.write("format", CALIB_FORMAT_NAME)
    fs.write("format_version", CALIB_FORMAT_VERSION)
    fs.write("image_size", np.array(calib.image_size, dtype=np.int32).reshape(1, 2))
    fs.write("K1", calib.K_left)
    fs.write("D1", calib.D_left.reshape(1, 5))
    fs.write("K2", calib.K_right)
    fs.write("D2", calib.D_right.reshape(1, 5))
    fs.write("R", calib.R)
    fs.write("T", calib.T.reshape(3, 1))
    fs.write("baseline_m", calib.baseline_m)
    fs.write("T_pile_cam", calib.T_pile_cam)
    return fs.releaseAndGetString()


def write_calibration_yaml(calib: StereoCalibration, path: str | Path) -> Path:
    """Write ``calibration.yaml`` (OpenCV FileStorage; atomically). Returns the path."""
    path = Path(path)
    atomic_write_bytes(path, calibration_yaml_text(calib).encode())
    return path


def read_calibration_yaml(path: str | Path) -> StereoCalibration:
    """Read a calibration YAML written by :func:`write_calibration_yaml` (or any OpenCV YAML
    holding ``K1 D1 K2 D2 R T image_size``; the format version is checked when present)."""
    import cv2

    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise StereoFormatError(f"cannot read calibration {path}: {exc.strerror or exc}") from exc
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except cv2.error as exc:
        raise StereoFormatError(f"{path} is not an OpenCV FileStorage YAML: {exc}") from exc
    try:
        version = fs.getNode("format_version")
        if not version.empty():
            CALIBRATION.check_version(version.string(), path)
        mats = {}
        for key in ("K1", "D1", "K2", "D2", "R", "T", "image_size"):
            m = fs.getNode(key).mat()
            if m is None:
                raise StereoFormatError(f"calibration {path} has no {key}; it needs K1 D1 K2 D2 R T image_size")
            mats[key] = m
        node = fs.getNode("T_pile_cam")
        T_pile_cam = np.eye(4) if node.empty() else node.mat()
        size = mats["image_size"].reshape(-1)
        d1, d2 = np.zeros(5), np.zeros(5)
        d1[: min(5, mats["D1"].size)] = mats["D1"].reshape(-1)[:5]
        d2[: min(5, mats["D2"].size)] = mats["D2"].reshape(-1)[:5]
        return StereoCalibration(mats["K1"], mats["K2"], d1, d2, mats["R"], mats["T"],
                                 (int(size[0]), int(size[1])), T_pile_cam)
    except ValueError as exc:
        raise StereoFormatError(f"malformed calibration {path}: {exc}") from exc
    finally:
        fs.release()


def zed_conf_text(calib: StereoCalibration, serial: int = 0) -> str:
    """The calibration as a ZED ``SN<serial>.conf``-like INI text.

    Sections ``[LEFT_CAM_<RES>]``/``[RIGHT_CAM_<RES>]`` hold ``fx fy cx cy k1 k2 p1 p2 k3`` [px, -];
    ``[STEREO]`` holds ``Baseline`` [mm] (positive: the right camera is ``Baseline`` along the
    left camera's +x), ``TY_<RES>``/``TZ_<RES>`` [mm] and the Rodrigues rotation ``RX_<RES>``,
    ``CV_<RES>`` (about y), ``RZ_<RES>`` [rad]. ``<RES>`` is the ZED resolution name of the image
    size (HD = 1280x720; "CUSTOM" otherwise). Conversion used by :func:`read_zed_conf`:
    ``T = (-Baseline, -TY, -TZ) / 1000`` (a right camera displaced by ``d`` in left
    coordinates gives ``T = -R @ d``; for ``R = I``), ``R = Rodrigues(RX, CV, RZ)``.
    ``[LOGGRASP]`` adds the format version, the image size and ``T_pile_cam``.
    """
    import cv2

    res = ZED_RESOLUTIONS.get(calib.image_size, "CUSTOM")
    cfg = configparser.ConfigParser()
    cfg.optionxform = str  # keep the case of ZED keys
    for side, K, D in (("LEFT", calib.K_left, calib.D_left), ("RIGHT", calib.K_right, calib.D_right)):
        cfg[f"{side}_CAM_{res}"] = {
            "fx": repr(float(K[0, 0])), "fy": repr(float(K[1, 1])), "cx": repr(float(K[0, 2])),
            "cy": repr(float(K[1, 2])), "k1": repr(float(D[0])), "k2": repr(float(D[1])),
            "p1": repr(float(D[2])), "p2": repr(float(D[3])), "k3": repr(float(D[4])),
        }
    d = -calib.R.T @ calib.T  # right camera centre in left coordinates [m]
    rvec = cv2.Rodrigues(calib.R)[0].reshape(3)
    cfg["STEREO"] = {
        "Baseline": repr(float(d[0] * 1000.0)), f"TY_{res}": repr(float(d[1] * 1000.0)),
        f"TZ_{res}": repr(float(d[2] * 1000.0)), f"RX_{res}": repr(float(rvec[0])),
        f"CV_{res}": repr(float(rvec[1])), f"RZ_{res}": repr(float(rvec[2])),
    }
    cfg["MISC"] = {"Sensor_ID": "1"}
    cfg["LOGGRASP"] = {
        "format": CALIB_FORMAT_NAME + ".zed", "format_version": CALIB_FORMAT_VERSION,
        "serial": str(int(serial)), "resolution": res,
        "image_width": str(calib.image_size[0]), "image_height": str(calib.image_size[1]),
        "T_pile_cam": " ".join(repr(float(v)) for v in calib.T_pile_cam.reshape(-1)),
    }
    buf = io.StringIO()
    cfg.write(buf)
    return buf.getvalue()


def write_zed_conf(calib: StereoCalibration, path: str | Path, serial: int = 0) -> Path:
    """Write the ZED-style INI (see :func:`zed_conf_text`) atomically. Returns the path."""
    path = Path(path)
    atomic_write_bytes(path, zed_conf_text(calib, serial).encode())
    return path


def read_zed_conf(path: str | Path, resolution: str | None = None,
                  image_size: tuple[int, int] | None = None) -> StereoCalibration:
    """Read a ZED-style INI (ours or a ZED ``SN<serial>.conf``) at one resolution.

    ``resolution`` ("2K", "FHD", "HD", "VGA", "CUSTOM") defaults to the one in ``[LOGGRASP]``,
    else "HD". ``image_size`` defaults to ``[LOGGRASP]``'s, else the ZED size of the resolution.
    A ZED factory file has no ``T_pile_cam``: identity is returned for it.
    """
    import cv2

    path = Path(path)
    cfg = configparser.ConfigParser()
    cfg.optionxform = str
    try:
        text = path.read_text()
        cfg.read_string(text)
    except OSError as exc:
        raise StereoFormatError(f"cannot read ZED calibration {path}: {exc.strerror or exc}") from exc
    except configparser.Error as exc:
        raise StereoFormatError(f"{path} is not an INI file: {exc}") from exc
    ours = cfg["LOGGRASP"] if cfg.has_section("LOGGRASP") else None
    try:
        if ours is not None:
            ZED_CALIBRATION.check_version(ours.get("format_version", ""), path)
        res = resolution or (ours.get("resolution") if ours is not None else None) or "HD"
        if image_size is None:
            if ours is not None and "image_width" in ours:
                image_size = (int(ours["image_width"]), int(ours["image_height"]))
            else:
                sizes = {v: k for k, v in ZED_RESOLUTIONS.items()}
                if res not in sizes:
                    raise StereoFormatError(f"{path}: give image_size for resolution {res!r}")
                image_size = sizes[res]

        def cam(side: str) -> tuple[np.ndarray, np.ndarray]:
            sec = f"{side}_CAM_{res}"
            if not cfg.has_section(sec):
                raise StereoFormatError(f"{path} has no [{sec}] section; pick another resolution")
            s = cfg[sec]
            K = np.array([[float(s["fx"]), 0, float(s["cx"])], [0, float(s["fy"]), float(s["cy"])], [0, 0, 1]])
            D = np.array([float(s.get(k, 0.0)) for k in ("k1", "k2", "p1", "p2", "k3")])
            return K, D

        K1, D1 = cam("LEFT")
        K2, D2 = cam("RIGHT")
        st = cfg["STEREO"]
        # ZED files spell it "Baseline" or "BaseLine"
        base = next((st[k] for k in st if k.lower() == "baseline"), None)
        if base is None:
            raise StereoFormatError(f"{path} has no [STEREO] Baseline")
        d = np.array([float(base), float(st.get(f"TY_{res}", 0.0)), float(st.get(f"TZ_{res}", 0.0))]) / 1000.0
        rvec = np.array([float(st.get(f"RX_{res}", 0.0)), float(st.get(f"CV_{res}", 0.0)),
                         float(st.get(f"RZ_{res}", 0.0))])
        R = cv2.Rodrigues(rvec)[0]
        T_pile_cam = np.eye(4)
        if ours is not None and "T_pile_cam" in ours:
            T_pile_cam = np.array([float(v) for v in ours["T_pile_cam"].split()]).reshape(4, 4)
        return StereoCalibration(K1, K2, D1, D2, R, -R @ d, image_size, T_pile_cam)
    except (KeyError, ValueError) as exc:
        raise StereoFormatError(f"malformed ZED calibration {path}: {exc}") from exc
