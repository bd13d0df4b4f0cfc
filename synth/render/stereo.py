"""A ZED 2-like stereo pair rendered from a pile, with its calibration and ground-truth depth.

Camera frames follow OpenCV: x right, y down, z forward (the optical axis). ``T_pile_cam`` maps
left-camera coordinates to the pile frame. The right camera sits ``baseline_m`` along the left
camera's +x axis, with the same orientation, so in OpenCV's ``stereoCalibrate`` convention
(``x_right = R @ x_left + T``): ``R = I``, ``T = (-baseline_m, 0, 0)``.

Pixels follow the pinhole model exactly: pixel ``(u, v)`` (column, row, integers at pixel
centres) sees the ray through ``u = fx X/Z + cx``, ``v = fy Y/Z + cy``. The pybullet projection
matrix is built from the intrinsics for that, with each renderer's sampling convention (EGL
samples pixel centres, TinyRenderer integer positions; see :func:`projection_matrix`); the test
suite checks it against the segmentation of a box at sub-pixel precision.

Rendering happens in a private copy of the scene (a :class:`~synth.physics.world.World` built from
``world.settled_pile()``) owned by a :class:`StereoRenderer`: the textures and the EGL plugin
(which, once loaded in a client, serves every ``getCameraImage`` of that client and only draws
bodies created after it was loaded) never touch the caller's world.

Files (a :class:`StereoPair` folder, see :meth:`StereoPair.save`):

* ``left.png``, ``right.png``: RGB images (8-bit PNG);
* ``calibration.yaml``: OpenCV ``FileStorage`` YAML with ``K1 D1 K2 D2 R T image_size`` (what
  ``cv2.stereoRectify`` takes), plus ``baseline_m``, ``T_pile_cam`` and the format version;
* ``zed.conf``: the same calibration as a ZED ``SN<serial>.conf``-like INI file;
* ``depth_left.npz``: ground truth of the left image: ``depth_m`` (z along the optical axis, NaN
  where no surface) and ``instance`` (0 ground, ``i + 1`` log ``i``, ``1000 + j`` obstacle ``j``,
  -1 nothing);
* ``meta.json``: format name/version, rig and renderer.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from synth.common.closing import Closing
from synth.common.formats import VersionedJson
from synth.errors import OutputError, RenderError, SynthError
from synth.geometry.calibration import (FIX, StereoCalibration, StereoFormatError, read_calibration_yaml,
                                        write_calibration_yaml, write_zed_conf)
from synth.geometry.frames import invert_T, make_T
from synth.render.textures import TextureConfig
from synth.scene.pile import PileSpec

if TYPE_CHECKING:  # pragma: no cover
    from synth.physics.world import World

STEREO_FORMAT_NAME = "loggrasp.stereo"
STEREO_FORMAT_VERSION = "1.0"

RENDERERS = ("auto", "egl", "tiny")

STEREO_PAIR = VersionedJson(STEREO_FORMAT_NAME, STEREO_FORMAT_VERSION, "stereo pair", StereoFormatError, fix=FIX,
                            filename="meta.json")



# -- rig -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StereoRigConfig:
    """A ZED 2-like stereo rig and how it is rendered.

    The left camera's pose is ``T_pile_cam`` when given, otherwise it looks straight down from
    ``height_m`` above ``target_m`` with the baseline along pile +x and image up along pile +y
    (north-up), turned by ``yaw_deg`` about the vertical and tilted by ``tilt_deg`` about the
    camera's x axis (positive tilts the optical axis towards the image top).
    """

    width_px: int = 1280  # [px]
    height_px: int = 720  # [px]
    hfov_deg: float = 50.0  # horizontal field of view [deg]; square pixels, principal point centred
    baseline_m: float = 0.12  # left-to-right camera distance [m]
    height_m: float = 3.0  # default pose: camera height above target_m [m]
    target_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # default pose: point below the camera [m]
    yaw_deg: float = 0.0  # default pose: rig rotation about pile z [deg]
    tilt_deg: float = 0.0  # default pose: optical axis tilt about camera x [deg]
    T_pile_cam: tuple[tuple[float, ...], ...] | None = None  # explicit left-camera pose (4x4)
    near_m: float = 0.5  # near clipping plane [m]; keep it large: EGL depth precision scales with it
    far_m: float = 20.0  # far clipping plane [m]
    renderer: str = "auto"  # "egl", "tiny" or "auto" (EGL when it works, else TinyRenderer)
    shadow: bool = False  # cast shadows (both renderers) [-]
    textures: TextureConfig = field(default_factory=TextureConfig)

    def __post_init__(self) -> None:
        if not (16 <= self.width_px <= 8192 and 16 <= self.height_px <= 8192):
            raise ValueError(f"image size must be within 16..8192 px, got {self.width_px}x{self.height_px}")
        if not 5.0 <= self.hfov_deg <= 150.0:
            raise ValueError(f"hfov_deg must be in [5, 150] deg, got {self.hfov_deg}")
        if not 0.01 <= self.baseline_m <= 2.0:
            raise ValueError(f"baseline_m must be in [0.01, 2] m, got {self.baseline_m}")
        if not 0.2 <= self.height_m <= 100.0:
            raise ValueError(f"height_m must be in [0.2, 100] m, got {self.height_m}")
        if not -60.0 <= self.tilt_deg <= 60.0:
            raise ValueError(f"tilt_deg must be in [-60, 60] deg, got {self.tilt_deg}")
        if not 0 < self.near_m < self.far_m <= 1000.0:
            raise ValueError(f"need 0 < near_m < far_m <= 1000 m, got {self.near_m}, {self.far_m}")
        if self.renderer not in RENDERERS:
            raise ValueError(f"renderer must be one of {RENDERERS}, got {self.renderer!r}")
        if self.T_pile_cam is not None:
            T = np.asarray(self.T_pile_cam, dtype=float)
            if T.shape != (4, 4) or not np.allclose(T[3], (0, 0, 0, 1)):
                raise ValueError("T_pile_cam must be a 4x4 homogeneous transform")
            if not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6):
                raise ValueError("T_pile_cam's rotation part must be orthonormal")

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) [px], OpenCV's order."""
        return (self.width_px, self.height_px)

    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix: square pixels, principal point at the image centre."""
        fx = (self.width_px / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)
        return np.array([[fx, 0.0, (self.width_px - 1) / 2.0],
                         [0.0, fx, (self.height_px - 1) / 2.0],
                         [0.0, 0.0, 1.0]])

    def camera_pose(self) -> np.ndarray:
        """``T_pile_cam`` of the left camera (4x4, OpenCV camera axes)."""
        if self.T_pile_cam is not None:
            return np.asarray(self.T_pile_cam, dtype=np.float64)
        # straight down: x_cam = +x_pile, y_cam = -y_pile, z_cam = -z_pile
        R_down = np.diag([1.0, -1.0, -1.0])
        cy, sy = math.cos(math.radians(self.yaw_deg)), math.sin(math.radians(self.yaw_deg))
        R_yaw = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        t = math.radians(self.tilt_deg)
        # rotation about camera x moving the optical axis (z) towards -y_cam (the image top)
        R_tilt = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(t), -math.sin(t)], [0.0, math.sin(t), math.cos(t)]])
        R = R_yaw @ R_down @ R_tilt
        pos = np.asarray(self.target_m, dtype=float) + np.array([0.0, 0.0, self.height_m])
        return make_T(R, pos)

    def calibration(self) -> "StereoCalibration":
        K = self.K()
        return StereoCalibration(
            K_left=K, K_right=K.copy(), D_left=np.zeros(5), D_right=np.zeros(5), R=np.eye(3),
            T=np.array([-self.baseline_m, 0.0, 0.0]), image_size=self.image_size,
            T_pile_cam=self.camera_pose(),
        )

    def to_dict(self) -> dict:
        d = asdict(self)
        d["T_pile_cam"] = None if self.T_pile_cam is None else [list(r) for r in self.T_pile_cam]
        return d


# -- projection ------------------------------------------------------------------------------
#: Where each renderer samples pixel (u, v) in OpenGL window coordinates, as (du, dv) added to
#: (u, H - 1 - v): EGL (OpenGL rasterisation) samples pixel centres; TinyRenderer integer corners.
#: Measured by ``tests/synth/render/test_stereo.py::test_projection_matches_pinhole``.
_SAMPLE_OFFSET = {"egl": (0.5, 0.5), "tiny": (0.0, 0.0)}


def projection_matrix(K: np.ndarray, size: tuple[int, int], near_m: float, far_m: float,
                      renderer: str) -> np.ndarray:
    """OpenGL projection (4x4, row-major) for pinhole ``K``, so pixel (u, v) of pybullet's
    image sees ``u = fx X/Z + cx``, ``v = fy Y/Z + cy`` (camera frame: x right, y down, z fwd).

    pybullet's image row 0 is the top (window y = H - 1 - v); a renderer sampling pixel
    (u, v) at window position (u + du, H - 1 - v + dv) needs
    ``ndc_x = 2 (u + du) / W - 1`` and ``ndc_y = 2 (H - 1 - v + dv) / H - 1``.
    """
    W, H = size
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    du, dv = _SAMPLE_OFFSET[renderer]
    n, f = near_m, far_m
    # eye (GL) coords: x_e = X, y_e = -Y, z_e = -Z; clip w = -z_e = Z
    # ndc_x * Z = 2 fx / W * x_e + (2 (cx + du) / W - 1) * Z
    # ndc_y * Z = 2 fy / H * y_e + (2 (H - 1 - cy + dv) / H - 1) * Z
    return np.array([
        [2 * fx / W, 0.0, -(2 * (cx + du) / W - 1), 0.0],
        [0.0, 2 * fy / H, -(2 * (H - 1 - cy + dv) / H - 1), 0.0],
        [0.0, 0.0, -(f + n) / (f - n), -2 * f * n / (f - n)],
        [0.0, 0.0, -1.0, 0.0],
    ])


def view_matrix(T_pile_cam: np.ndarray) -> np.ndarray:
    """OpenGL view matrix (4x4, row-major): pile frame -> GL eye (x right, y up, z backward)."""
    return np.diag([1.0, -1.0, -1.0, 1.0]) @ invert_T(T_pile_cam)


def linearise_depth(buf: np.ndarray, near_m: float, far_m: float) -> np.ndarray:
    """pybullet depth buffer [0, 1] -> distance along the optical axis [m]."""
    buf = np.asarray(buf, dtype=np.float64)
    return far_m * near_m / (far_m - (far_m - near_m) * buf)


# -- renderer --------------------------------------------------------------------------------
_EGL_STATE: dict[str, Any] = {}


def egl_plugin_path() -> str | None:
    """File of pybullet's EGL renderer plugin, or None when it is not installed."""
    import pkgutil

    loader = pkgutil.get_loader("eglRenderer")
    return None if loader is None else loader.get_filename()


class StereoRenderer(Closing):
    """Renders stereo pairs in a private pybullet client (EGL when available, else TinyRenderer).

    Keep one for many renders of a pile (the scene is kept while the pile and the texture config
    stay the same); use as a context manager. ``backend``: "egl", "tiny" or "auto". Every other
    pile gets a fresh client: each pile has its own textures (``synth.render.textures``), and pybullet
    never frees textures on ``resetSimulation`` (+23 MB per rebuilt scene was measured with EGL)
    and restarts texture ids there while the EGL plugin keeps its old images. Closing the client
    frees them; an EGL start costs ~1 s.
    """

    def __init__(self, backend: str = "auto") -> None:
        if backend not in RENDERERS:
            raise ValueError(f"backend must be one of {RENDERERS}, got {backend!r}")
        self.requested = backend
        self.backend: str | None = None  # resolved on first render
        self._world: "World | None" = None
        self._key: tuple | None = None
        self._closed = False

    # scene ----------------------------------------------------------------------------------
    def _ensure_scene(self, pile: PileSpec, textures: TextureConfig) -> "World":
        from synth.render.textures import apply_textures
        from synth.physics.world import World

        if self._closed:
            raise RenderError("this StereoRenderer is closed; create a new one")
        key = (pile, textures)
        if self._world is not None and self._key == key:
            return self._world
        if self._world is not None:
            self._world.close()  # frees the previous pile's textures
            self._world = None
        self._world = World(pile, ground_uv_m=textures.ground_uv_m)
        self.backend = self._attach_backend(self._world)
        # EGL only draws bodies created after its plugin was loaded: rebuild once
        if self.backend == "egl":
            self._world._build()
        apply_textures(self._world, textures)
        if self.backend == "egl":
            # the first EGL frame after a (re)build differs slightly from every later one
            # (measured: a sliver of ~1 % of pixels); a tiny warm-up frame makes renders repeatable
            p = self._world.p
            for flags in (0, p.ER_NO_SEGMENTATION_MASK):
                self._world.client.getCameraImage(16, 16, renderer=p.ER_BULLET_HARDWARE_OPENGL, flags=flags)
        self._key = key
        return self._world

    def _attach_backend(self, world: "World") -> str:
        if self.requested == "tiny":
            return "tiny"
        path = egl_plugin_path()
        err = "the eglRenderer plugin is not installed with pybullet"
        if path is not None:
            plugin = world.client.loadPlugin(path, "_eglRendererPlugin")
            if plugin >= 0:
                return "egl"
            err = "pybullet could not load the EGL renderer plugin (no EGL display/driver?)"
        if self.requested == "egl":
            raise RenderError(f"EGL rendering requested but {err}; use renderer='tiny'")
        return "tiny"

    # rendering ------------------------------------------------------------------------------
    def _camera(self, T_pile_cam: np.ndarray, K: np.ndarray, rig: StereoRigConfig, pile: PileSpec,
                segmentation: bool) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        p = self._world.p
        c = self._world.client
        W, H = rig.image_size
        view = view_matrix(T_pile_cam)
        proj = projection_matrix(K, rig.image_size, rig.near_m, rig.far_m, self.backend)
        light = pile.lighting
        flags = 0 if segmentation else p.ER_NO_SEGMENTATION_MASK
        out = c.getCameraImage(
            W, H, viewMatrix=view.T.reshape(-1).tolist(), projectionMatrix=proj.T.reshape(-1).tolist(),
            lightDirection=list(light.direction), lightAmbientCoeff=light.ambient,
            lightDiffuseCoeff=light.diffuse, lightSpecularCoeff=light.specular,
            shadow=int(rig.shadow), flags=flags,
            renderer=p.ER_TINY_RENDERER if self.backend == "tiny" else p.ER_BULLET_HARDWARE_OPENGL,
        )
        rgba = np.asarray(out[2], dtype=np.uint8).reshape(H, W, 4)
        rgb = np.ascontiguousarray(rgba[..., :3])
        if not segmentation:
            return rgb, None, None
        depth = np.asarray(out[3], dtype=np.float32).reshape(H, W)
        seg = np.asarray(out[4], dtype=np.int32).reshape(H, W)
        return rgb, depth, seg

    def render(self, scene: "World | PileSpec", rig: StereoRigConfig | None = None,
               textures: TextureConfig | None = None) -> "StereoPair":
        """Render the stereo pair of ``scene`` (a world at its current poses, or a pile).

        ``textures`` overrides ``rig.textures``. The first render fixes the backend: later rigs'
        ``renderer`` field is ignored (a client cannot unload the EGL plugin)."""
        from synth.physics.world import World

        rig = rig or StereoRigConfig()
        if rig.renderer != "auto" and self.requested == "auto" and self._world is None:
            self.requested = rig.renderer
        pile = scene.settled_pile() if isinstance(scene, World) else scene
        if not isinstance(pile, PileSpec):
            raise TypeError(f"render needs a World or a PileSpec, got {type(scene).__name__}")
        t0 = time.perf_counter()
        world = self._ensure_scene(pile, rig.textures if textures is None else textures)
        t1 = time.perf_counter()
        calib = rig.calibration()
        try:
            left, depth_buf, seg = self._camera(calib.T_pile_cam, calib.K_left, rig, pile, True)
            right, _, _ = self._camera(calib.T_pile_right, calib.K_right, rig, pile, False)
        except SynthError:
            raise
        except Exception as exc:  # pybullet raises plain errors
            raise RenderError(f"pybullet could not render the stereo pair: {exc}") from exc
        t2 = time.perf_counter()
        depth = linearise_depth(depth_buf, rig.near_m, rig.far_m).astype(np.float32)
        lut = np.full(max(world.instance_of_body) + 2, -1, dtype=np.int16)  # body id + 1 -> code
        for b, code in world.instance_of_body.items():
            lut[b + 1] = code
        instance = lut[np.clip(seg, -1, lut.size - 2) + 1]
        depth[instance < 0] = np.nan
        meta = {"renderer": self.backend, "rig": rig.to_dict(), "scene_s": t1 - t0, "render_s": t2 - t1,
                "n_logs": pile.n_logs, "n_obstacles": pile.n_obstacles}
        return StereoPair(left=left, right=right, depth_left=depth, instance_left=instance,
                          calibration=calib, meta=meta)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            if self._world is not None:
                self._world.close()
                self._world = None



def render_stereo(scene: "World | PileSpec", rig: StereoRigConfig | None = None,
                  renderer: StereoRenderer | None = None) -> "StereoPair":
    """Render a ZED 2-like stereo pair of ``scene`` (a :class:`World` at its current poses, or a
    :class:`PileSpec`). Pass a :class:`StereoRenderer` to reuse its client over many renders;
    otherwise a temporary one is made (and closed) for this call."""
    rig = rig or StereoRigConfig()
    if renderer is not None:
        return renderer.render(scene, rig)
    with StereoRenderer(rig.renderer) as r:
        return r.render(scene, rig)


# -- the pair and its folder -----------------------------------------------------------------
@dataclass
class StereoPair:
    """A rendered stereo pair: RGB images, left ground truth and the calibration."""

    left: np.ndarray  # (H, W, 3) uint8 RGB
    right: np.ndarray  # (H, W, 3) uint8 RGB
    depth_left: np.ndarray  # (H, W) float32 [m] along the optical axis; NaN where nothing is seen
    instance_left: np.ndarray  # (H, W) int16: 0 ground, i + 1 log i, 1000 + j obstacle j, -1 nothing
    calibration: StereoCalibration
    meta: dict = field(default_factory=dict)

    FILES = ("left.png", "right.png", "calibration.yaml", "zed.conf", "depth_left.npz", "meta.json")

    def save(self, folder: str | Path) -> Path:
        """Write the pair folder atomically (built beside it, then renamed into place)."""
        import cv2

        folder = Path(folder)
        parent = folder.parent
        try:
            parent.mkdir(parents=True, exist_ok=True)
            tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".tmp", dir=parent))
            from synth.common.files import apply_umask

            apply_umask(tmp, directory=True)
        except OSError as exc:
            raise OutputError(f"cannot create {folder}: {exc.strerror or exc}; check the path and permissions") from exc
        try:
            for name, img in (("left.png", self.left), ("right.png", self.right)):
                ok, buf = cv2.imencode(".png", np.ascontiguousarray(img[..., ::-1]))
                if not ok:
                    raise OutputError(f"OpenCV could not encode {name}")
                (tmp / name).write_bytes(buf.tobytes())
            write_calibration_yaml(self.calibration, tmp / "calibration.yaml")
            write_zed_conf(self.calibration, tmp / "zed.conf")
            with open(tmp / "depth_left.npz", "wb") as f:
                np.savez_compressed(f, depth_m=self.depth_left.astype(np.float32),
                                    instance=self.instance_left.astype(np.int16),
                                    format_version=np.array(STEREO_FORMAT_VERSION))
            (tmp / "meta.json").write_text(STEREO_PAIR.dumps(self.meta, default=_json_default))
            old = None
            if folder.exists():
                old = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".old", dir=parent))
                os.replace(folder, old / "x")
            os.replace(tmp, folder)
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
        except OSError as exc:
            shutil.rmtree(tmp, ignore_errors=True)
            raise OutputError(f"cannot write the stereo pair to {folder}: {exc.strerror or exc}") from exc
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return folder

    @staticmethod
    def load(folder: str | Path) -> "StereoPair":
        """Read a folder written by :meth:`save`. Raises :class:`StereoFormatError`."""
        import cv2

        folder = Path(folder)
        meta = STEREO_PAIR.read(folder / "meta.json")
        imgs = []
        for name in ("left.png", "right.png"):
            img = cv2.imread(str(folder / name), cv2.IMREAD_COLOR)
            if img is None:
                raise StereoFormatError(f"cannot read {folder / name}")
            imgs.append(np.ascontiguousarray(img[..., ::-1]))
        calib = read_calibration_yaml(folder / "calibration.yaml")
        try:
            with np.load(folder / "depth_left.npz") as z:
                depth, inst = z["depth_m"], z["instance"]
        except (OSError, KeyError, ValueError) as exc:
            raise StereoFormatError(f"cannot read {folder / 'depth_left.npz'}: {exc}") from exc
        meta = {k: v for k, v in meta.items() if k not in ("format", "format_version")}
        return StereoPair(imgs[0], imgs[1], depth, inst, calib, meta)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    raise TypeError(f"cannot serialise {type(o).__name__}")


# -- a reference matcher, to check that renders support stereo -------------------------------
@dataclass(frozen=True)
class SGBMConfig:
    """OpenCV semi-global matching settings for :func:`sgbm_depth` (a check, not the pipeline)."""

    z_min_m: float = 1.5  # nearest depth searched [m]
    z_max_m: float = 4.0  # farthest depth searched [m]
    block_size: int = 5  # matching block side [px], odd
    uniqueness: int = 5  # [%]
    speckle_window: int = 100  # [px]
    speckle_range: int = 2  # [disparity units]
    disp12_max_diff: int = 1  # left-right check [px]

    def __post_init__(self) -> None:
        if not 0 < self.z_min_m < self.z_max_m:
            raise ValueError(f"need 0 < z_min_m < z_max_m, got {self.z_min_m}, {self.z_max_m}")
        if self.block_size < 1 or self.block_size % 2 == 0:
            raise ValueError(f"block_size must be odd and >= 1, got {self.block_size}")


@dataclass
class Matched:
    """What :func:`rectify_and_match` returns (rectified-left image frame)."""

    disparity_px: np.ndarray  # (H, W) float32 [px]
    valid: np.ndarray  # (H, W) bool: matched pixels
    left_rectified: np.ndarray  # (H, W, 3) uint8 RGB, rectified left image
    Q: np.ndarray  # 4x4 disparity-to-depth matrix (cv2.reprojectImageTo3D)
    R1: np.ndarray  # 3x3 rotation original left camera -> rectified left camera
    d_min: int  # smallest disparity searched [px]


def disparity_range(f_baseline_px_m: float, z_min_m: float, z_max_m: float) -> tuple[int, int]:
    """(smallest disparity, number of disparities) [px] the matcher searches for depths ``z_min_m`` ..
    ``z_max_m`` of a pair with focal length x baseline ``f_baseline_px_m``: OpenCV's numDisparities is a
    multiple of 16. The left image's first ``d_min + n_disp`` columns get no depth (the right camera does
    not see them at every searched depth): a scan plan's footprint leaves them out."""
    d_min = max(0, int(math.floor(f_baseline_px_m / z_max_m)) - 1)
    n_disp = int(math.ceil((f_baseline_px_m / z_min_m - d_min + 1) / 16.0)) * 16
    return d_min, n_disp


def rectify_and_match(left: np.ndarray, right: np.ndarray, calib: StereoCalibration, cfg) -> Matched:
    """Rectify a pair (``cv2.stereoRectify`` + ``initUndistortRectifyMap``) and match it with
    OpenCV's 3-way semi-global matcher, searching the disparities of depths ``cfg.z_min_m`` ..
    ``cfg.z_max_m``. ``cfg`` needs ``z_min_m, z_max_m, block_size, uniqueness, speckle_window,
    speckle_range, disp12_max_diff`` (:class:`SGBMConfig`, ``reconstruct.scan.stereo.StereoConfig``).
    The one place loggrasp turns a stereo pair into disparities."""
    import cv2

    size = calib.image_size
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        calib.K_left, calib.D_left, calib.K_right, calib.D_right, size, calib.R, calib.T.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=0,
    )
    m1 = cv2.initUndistortRectifyMap(calib.K_left, calib.D_left, R1, P1, size, cv2.CV_32FC1)
    m2 = cv2.initUndistortRectifyMap(calib.K_right, calib.D_right, R2, P2, size, cv2.CV_32FC1)
    left_r = cv2.remap(left, *m1, cv2.INTER_LINEAR)
    gl = cv2.cvtColor(left_r, cv2.COLOR_RGB2GRAY)
    gr = cv2.cvtColor(cv2.remap(right, *m2, cv2.INTER_LINEAR), cv2.COLOR_RGB2GRAY)
    d_min, n_disp = disparity_range(abs(P2[0, 3]), cfg.z_min_m, cfg.z_max_m)
    bs = cfg.block_size
    matcher = cv2.StereoSGBM_create(
        minDisparity=d_min, numDisparities=n_disp, blockSize=bs, P1=8 * bs * bs, P2=32 * bs * bs,
        disp12MaxDiff=cfg.disp12_max_diff, uniquenessRatio=cfg.uniqueness,
        speckleWindowSize=cfg.speckle_window, speckleRange=cfg.speckle_range,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )
    disp = matcher.compute(gl, gr).astype(np.float32) / 16.0  # int16 x16 -> pixels
    return Matched(disp, disp > d_min - 0.5, left_r, Q, R1, d_min)


def sgbm_depth(left: np.ndarray, right: np.ndarray, calib: StereoCalibration,
               config: SGBMConfig | None = None) -> np.ndarray:
    """Depth [m] along the left camera's optical axis, per left-image pixel, by OpenCV SGBM.

    Rectifies with ``cv2.stereoRectify`` / ``initUndistortRectifyMap``, matches with
    ``StereoSGBM`` (3-way), reprojects with ``Q`` and maps the points back into the original left
    image (nearest pixel, nearest surface). NaN where matching failed.
    """
    import cv2

    cfg = config or SGBMConfig()
    m = rectify_and_match(left, right, calib, cfg)
    disp, valid, Q, R1, size = m.disparity_px, m.valid, m.Q, m.R1, calib.image_size
    pts = cv2.reprojectImageTo3D(disp, Q)[valid]  # rectified-left frame
    pts = pts @ R1  # back to the original left camera frame (R1 maps original -> rectified)
    W, H = size
    depth = np.full((H, W), np.inf, dtype=np.float64)
    z = pts[:, 2]
    ok = z > 0
    K = calib.K_left
    u = np.rint(K[0, 0] * pts[ok, 0] / z[ok] + K[0, 2]).astype(np.int64)
    v = np.rint(K[1, 1] * pts[ok, 1] / z[ok] + K[1, 2]).astype(np.int64)
    inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    np.minimum.at(depth, (v[inside], u[inside]), z[ok][inside])
    depth[~np.isfinite(depth)] = np.nan
    return depth.astype(np.float32)


def log_depth_errors(pair: StereoPair, depth: np.ndarray, erode_px: int = 0) -> dict[str, float]:
    """Error statistics [m] of ``depth`` against the ground truth on log pixels.

    Returns ``median_m``, ``p90_m``, ``mean_m`` of the absolute error and ``coverage`` (share of
    log pixels with a depth). ``erode_px`` shrinks each log's mask first (drops silhouette edges).
    """
    import cv2

    inst = pair.instance_left
    mask = (inst >= 1) & (inst < 1000)
    if erode_px > 0:
        k = np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8)
        m = np.zeros_like(mask)
        for code in np.unique(inst[mask]):
            m |= cv2.erode((inst == code).astype(np.uint8), k).astype(bool)
        mask = m
    n = int(mask.sum())
    if n == 0:
        raise RenderError("no log pixels in the left image; point the rig at the pile")
    est = depth[mask]
    ok = np.isfinite(est)
    err = np.abs(est[ok] - pair.depth_left[mask][ok])
    if err.size == 0:
        return {"median_m": float("nan"), "p90_m": float("nan"), "mean_m": float("nan"), "coverage": 0.0}
    return {"median_m": float(np.median(err)), "p90_m": float(np.percentile(err, 90)),
            "mean_m": float(err.mean()), "coverage": float(ok.mean())}
