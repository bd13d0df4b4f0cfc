"""Stereo pair renders: calibration files, exact pinhole projection, SGBM depth, textures, files."""

from __future__ import annotations

import configparser
import json
import math

import numpy as np
import pytest

from synth.scene.pile import LogSpec, PileSpec, RockSpec, TerrainSpec, quat_from_euler, quat_to_matrix
from synth.geometry.calibration import (
    StereoCalibration,
    StereoFormatError,
    read_calibration_yaml,
    read_zed_conf,
    write_calibration_yaml,
    write_zed_conf,
)
from synth.render.stereo import (
    SGBMConfig,
    StereoPair,
    StereoRenderer,
    StereoRigConfig,
    egl_plugin_path,
    log_depth_errors,
    render_stereo,
    sgbm_depth,
)
from synth.render.textures import TextureConfig, make_texture, pile_texture_files, texture_file


def _egl_works() -> bool:
    if egl_plugin_path() is None:
        return False
    try:
        with StereoRenderer("egl") as r:
            r.render(_pile(), StereoRigConfig(width_px=32, height_px=32, renderer="egl"))
        return True
    except Exception:
        return False


_EGL = None


def egl_ok() -> bool:
    global _EGL
    if _EGL is None:
        _EGL = _egl_works()
    return _EGL


BACKENDS = [
    "tiny",
    pytest.param("egl", marks=pytest.mark.skipif("not egl_ok()", reason="EGL plugin unavailable here")),
]


def _pile(with_box: bool = False) -> PileSpec:
    """Three logs on flat ground (two crossing under a third), optionally a box-shaped rock."""
    logs = (
        LogSpec.from_endpoints((-1.2, -0.5, 0.15), (1.2, -0.3, 0.15), 0.30, 0.26),
        LogSpec.from_endpoints((-1.0, 0.35, 0.13), (1.1, 0.55, 0.13), 0.26),
        LogSpec.from_endpoints((-0.35, -1.2, 0.43), (0.45, 1.2, 0.43), 0.22),
    )
    rocks = ()
    if with_box:
        verts = tuple((sx * 0.25, sy * 0.15, sz * 0.1) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1))
        rocks = (RockSpec(position_m=(1.0, -1.1, 0.2), orientation=quat_from_euler(0.0, 0.0, 0.4), vertices_m=verts),)
    return PileSpec(terrain=TerrainSpec(seed=3, amplitude_m=0.0), logs=logs, rocks=rocks)


# textures for tests that compare renders with each other (not depth): a sixteenth of the default
# texels, each pile's own textures all the same
SMALL_TEXTURES = TextureConfig(bark_px=128, rock_px=128, ground_px=1024)


def _small_rig(renderer: str, **kw) -> StereoRigConfig:
    base = dict(width_px=640, height_px=360, hfov_deg=30.0, height_m=3.0, renderer=renderer)
    base.update(kw)
    return StereoRigConfig(**base)


# -- rig and calibration files -----------------------------------------------------------
def test_rig_validation_and_default_pose():
    with pytest.raises(ValueError, match="hfov_deg"):
        StereoRigConfig(hfov_deg=1.0)
    with pytest.raises(ValueError, match="renderer"):
        StereoRigConfig(renderer="vulkan")
    with pytest.raises(ValueError, match="T_pile_cam"):
        StereoRigConfig(T_pile_cam=((1, 0, 0, 0),) * 4)
    rig = StereoRigConfig(height_m=3.5, target_m=(0.2, -0.1, 0.0))
    T = rig.camera_pose()
    np.testing.assert_allclose(T[:3, 3], (0.2, -0.1, 3.5))
    np.testing.assert_allclose(T[:3, 2], (0, 0, -1), atol=1e-12)  # optical axis straight down
    np.testing.assert_allclose(T[:3, 0], (1, 0, 0), atol=1e-12)  # baseline along pile +x
    calib = rig.calibration()
    np.testing.assert_allclose(calib.T_pile_right[:3, 3], (0.32, -0.1, 3.5))
    assert calib.baseline_m == pytest.approx(0.12)
    fx = calib.K_left[0, 0]
    assert 2 * math.degrees(math.atan(640 / fx)) == pytest.approx(50.0)
    tilted = StereoRigConfig(tilt_deg=10.0).camera_pose()
    # a positive tilt looks towards the image top, i.e. pile +y
    assert tilted[1, 2] > 0 and tilted[2, 2] == pytest.approx(-math.cos(math.radians(10)))


def _odd_calibration() -> StereoCalibration:
    import cv2

    K1 = np.array([[1001.5, 0, 641.25], [0, 1000.25, 359.75], [0, 0, 1]])
    K2 = np.array([[998.0, 0, 639.0], [0, 999.0, 361.0], [0, 0, 1]])
    R = cv2.Rodrigues(np.array([0.01, -0.02, 0.003]))[0]
    T = np.array([-0.1199, 0.0011, -0.0007])
    D = np.array([-0.17, 0.028, 0.0001, -0.0002, 0.0])
    pose = StereoRigConfig(tilt_deg=7.0, yaw_deg=30.0).camera_pose()
    return StereoCalibration(K1, K2, D, D * 0.9, R, T, (1280, 720), pose)


def test_calibration_yaml_round_trip_and_opencv_reads_it(tmp_path):
    import cv2

    calib = _odd_calibration()
    path = write_calibration_yaml(calib, tmp_path / "calibration.yaml")
    back = read_calibration_yaml(path)
    assert back.allclose(calib, atol=1e-12)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)  # a plain OpenCV reader sees the usual keys
    for key in ("K1", "D1", "K2", "D2", "R", "T"):
        assert fs.getNode(key).mat() is not None
    assert fs.getNode("format_version").string() == "1.0"
    fs.release()
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(back.K_left, back.D_left, back.K_right, back.D_right,
                                                 back.image_size, back.R, back.T.reshape(3, 1))
    assert abs(P2[0, 3] / P2[0, 0]) == pytest.approx(back.baseline_m, rel=1e-6)
    text = path.read_text().replace('format_version: "1.0"', 'format_version: "2.0"')
    (tmp_path / "v2.yaml").write_text(text)
    with pytest.raises(StereoFormatError, match="version"):
        read_calibration_yaml(tmp_path / "v2.yaml")


def test_zed_conf_round_trip_and_layout(tmp_path):
    calib = _odd_calibration()
    path = write_zed_conf(calib, tmp_path / "zed.conf")
    back = read_zed_conf(path)
    assert back.allclose(calib, atol=1e-9)
    cfg = configparser.ConfigParser()
    cfg.optionxform = str
    cfg.read(path)
    assert {"LEFT_CAM_HD", "RIGHT_CAM_HD", "STEREO"} <= set(cfg.sections())
    assert float(cfg["LEFT_CAM_HD"]["fx"]) == pytest.approx(1001.5)
    # the simple rig: baseline 120 mm along +x, no rotation
    rig_calib = StereoRigConfig().calibration()
    p = write_zed_conf(rig_calib, tmp_path / "rig.conf")
    cfg.read(p)
    assert float(cfg["STEREO"]["Baseline"]) == pytest.approx(120.0)
    assert read_zed_conf(p).allclose(rig_calib)
    # a ZED factory-like file (no [LOGGRASP] section) reads at a chosen resolution
    (tmp_path / "SN1.conf").write_text(
        "[LEFT_CAM_FHD]\nfx=1394.8\nfy=1394.8\ncx=932.4\ncy=559.9\nk1=0\nk2=0\np1=0\np2=0\nk3=0\n"
        "[RIGHT_CAM_FHD]\nfx=1395.0\nfy=1395.0\ncx=950.1\ncy=560.2\nk1=0\nk2=0\np1=0\np2=0\nk3=0\n"
        "[STEREO]\nBaseLine=120.009\nTY_FHD=0\nTZ_FHD=0\nCV_FHD=0\nRX_FHD=0\nRZ_FHD=0\n")
    z = read_zed_conf(tmp_path / "SN1.conf", resolution="FHD")
    assert z.image_size == (1920, 1080) and z.T[0] == pytest.approx(-0.120009)
    with pytest.raises(StereoFormatError, match="LEFT_CAM_HD"):
        read_zed_conf(tmp_path / "SN1.conf", resolution="HD")


# -- textures ------------------------------------------------------------------------------
def test_textures_deterministic_anisotropic_and_tileable():
    a, b = make_texture("bark", 3, 128), make_texture("bark", 3, 128)
    assert a.dtype == np.uint8 and a.shape == (128, 128, 3)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, make_texture("bark", 4, 128))
    g = a.astype(float).mean(axis=2)
    along_u = np.abs(np.diff(g, axis=1)).mean()  # across columns = along the log axis
    around = np.abs(np.diff(g, axis=0)).mean()
    assert along_u < 0.8 * around, "bark streaks should run along the log axis (texture u)"
    for kind in ("ground", "rock"):
        t = make_texture(kind, 1, 256).astype(float).mean(axis=2)
        interior = np.abs(np.diff(t, axis=1)).mean()
        seam = np.abs(t[:, 0] - t[:, -1]).mean()
        assert seam < 2.0 * interior, f"{kind} texture is not seamless"
        assert t.std() > 8, f"{kind} texture lacks contrast for stereo matching"
    p1, p2 = texture_file("rock", 5, 64), texture_file("rock", 5, 64)
    assert p1 == p2 and p1.endswith(".png")
    with pytest.raises(ValueError, match="kind"):
        make_texture("marble", 0, 64)


def test_ground_texture_has_metric_uvs():
    """The terrain mesh maps pile (x, y) / ground_uv_m onto the soil texture: predict the render from it."""
    import cv2

    pile = _pile()
    rig = _small_rig("tiny", hfov_deg=40.0, height_m=2.0, target_m=(0.7, 1.6, 0.0))
    with StereoRenderer("tiny") as r:
        pair = r.render(pile, rig)
    cfg = rig.textures
    n = cfg.ground_px
    tex = cv2.imread(pile_texture_files(pile, cfg)["ground"], cv2.IMREAD_GRAYSCALE).astype(float)
    img = cv2.cvtColor(pair.left, cv2.COLOR_RGB2GRAY).astype(float)
    K, T = pair.calibration.K_left, pair.calibration.T_pile_cam
    v, u = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones(u.shape)], -1) @ T[:3, :3].T
    P = T[:3, 3] + rays * (-T[2, 3] / rays[..., 2])[..., None]
    col = (np.mod(P[..., 0] / cfg.ground_uv_m, 1.0) * n).astype(int) % n
    row = ((1.0 - np.mod(P[..., 1] / cfg.ground_uv_m, 1.0)) * n).astype(int) % n
    ground = pair.instance_left == 0
    assert ground.mean() > 0.9
    corr = np.corrcoef(tex[row, col][ground], img[ground])[0, 1]
    assert corr > 0.9


# -- rendering -------------------------------------------------------------------------------
@pytest.mark.parametrize("backend", BACKENDS)
def test_projection_matches_pinhole(backend):
    """Pixel (u, v) sees u = fx X/Z + cx exactly: a box's silhouette, log axes and depth."""
    import cv2

    pile = _pile(with_box=True)
    rig = _small_rig(backend, hfov_deg=45.0, target_m=(0.3, -0.9, 0.0), tilt_deg=6.0)
    with StereoRenderer(backend) as r:
        pair = r.render(pile, rig)
    assert pair.meta["renderer"] == backend
    calib = pair.calibration
    # box rock: its silhouette is the convex hull of its projected corners
    rock = pile.rocks[0]
    corners = np.asarray(rock.vertices_m) @ quat_to_matrix(rock.orientation).T + np.asarray(rock.position_m)
    u, v, _ = calib.project(corners)
    hull = cv2.convexHull(np.stack([u, v], 1).astype(np.float32))
    H, W = pair.instance_left.shape
    vv, uu = np.mgrid[0:H, 0:W]
    near = (uu > u.min() - 3) & (uu < u.max() + 3) & (vv > v.min() - 3) & (vv < v.max() + 3)
    dist = np.full((H, W), -99.0)
    for a, b in zip(uu[near], vv[near]):
        dist[b, a] = cv2.pointPolygonTest(hull, (float(a), float(b)), True)
    seen = pair.instance_left == 1000
    assert seen.sum() > 1000
    wrong = seen != (dist > 0)
    # a half-pixel error would flip every edge pixel (hundreds); allow rasteriser ties only
    assert wrong.sum() <= 3 and np.all(np.abs(dist[wrong]) < 0.05)
    # log axes: points on the top of each log land on that log, at the right depth
    checked = 0
    for i, log in enumerate(pile.logs):
        c = np.asarray(log.centre_m)
        for f in np.linspace(-0.45, 0.45, 7):
            d = log.diameter_m + (log.top_d_m - log.diameter_m) * (f + 0.5)  # tapered
            top = c + log.axis() * f * log.length_m + np.array([0.0, 0.0, 0.5 * d * 0.999])
            uu_, vv_, z = calib.project(top[None])
            pu, pv = int(round(uu_[0])), int(round(vv_[0]))
            if (i < 2 and abs(f) < 0.15) or not (0 <= pu < W and 0 <= pv < H):
                continue  # under the crossing log, or out of view
            assert pair.instance_left[pv, pu] == i + 1
            assert pair.depth_left[pv, pu] == pytest.approx(z[0], abs=0.003)
            checked += 1
    assert checked >= 4
    # the ground plane (z = 0) at known distance: exact depth
    ground = pair.instance_left == 0
    v_g, u_g = np.nonzero(ground)
    rays = np.stack([(u_g - calib.K_left[0, 2]) / calib.K_left[0, 0],
                     (v_g - calib.K_left[1, 2]) / calib.K_left[1, 1], np.ones(u_g.size)], -1)
    T = calib.T_pile_cam
    z_true = -T[2, 3] / (rays @ T[2, :3])
    err = np.abs(pair.depth_left[ground] - z_true)
    assert np.median(err) < 5e-4 and err.max() < 2e-3


@pytest.mark.parametrize("backend", BACKENDS)
def test_sgbm_depth_on_logs(backend):
    rig = _small_rig(backend)
    pair = render_stereo(_pile(), rig)
    assert pair.left.shape == (360, 640, 3) and pair.left.dtype == np.uint8
    assert not np.array_equal(pair.left, pair.right)
    depth = sgbm_depth(pair.left, pair.right, pair.calibration, SGBMConfig(z_min_m=1.5, z_max_m=3.5))
    stats = log_depth_errors(pair, depth)
    assert stats["coverage"] > 0.7
    assert stats["median_m"] < 0.03, stats
    assert stats["p90_m"] < 0.08, stats
    # swapping the images destroys the depth: the check can fail
    bad = sgbm_depth(pair.right, pair.left, pair.calibration, SGBMConfig(z_min_m=1.5, z_max_m=3.5))
    bad_stats = log_depth_errors(pair, bad)
    assert not (bad_stats["coverage"] > 0.7 and bad_stats["median_m"] < 0.03)


@pytest.mark.parametrize("backend", BACKENDS)
def test_render_is_deterministic_and_leaves_the_world_alone(backend):
    from synth.physics.world import World

    rig = _small_rig(backend, width_px=320, height_px=180, textures=SMALL_TEXTURES)
    with World(_pile()) as world:
        world.step(30)
        before = world.client.getVisualShapeData(world.log_ids[0])
        a = render_stereo(world, rig)
        with StereoRenderer(backend) as r:
            b = r.render(world, rig)
            c = r.render(world, rig)  # reused scene
        assert world.client.getVisualShapeData(world.log_ids[0]) == before
    for x, y in ((a, b), (b, c)):
        np.testing.assert_array_equal(x.left, y.left)
        np.testing.assert_array_equal(x.right, y.right)
        np.testing.assert_array_equal(x.instance_left, y.instance_left)
        np.testing.assert_array_equal(x.depth_left, y.depth_left)
    assert set(np.unique(a.instance_left)) == {0, 1, 2, 3}


@pytest.mark.parametrize("backend", BACKENDS)
def test_renderer_rebuilds_and_recycles_scenes_faithfully(backend):
    """A renderer that has drawn other piles (each in a fresh client) draws a pile exactly as a
    fresh one does — textures included."""
    from dataclasses import replace

    rig = _small_rig(backend, width_px=320, height_px=180, textures=SMALL_TEXTURES)
    a = _pile()
    b = replace(a, terrain=replace(a.terrain, seed=9), logs=a.logs[1:])
    fresh = render_stereo(a, rig)
    with StereoRenderer(backend) as r:
        r.render(b, rig)
        redrawn = [r.render(a, rig)]
        r.render(b, rig)
        redrawn.append(r.render(a, rig))
    for x in redrawn:
        np.testing.assert_array_equal(x.left, fresh.left)
        np.testing.assert_array_equal(x.right, fresh.right)
        np.testing.assert_array_equal(x.instance_left, fresh.instance_left)


def test_stereo_pair_folder_round_trip(tmp_path):
    pair = render_stereo(_pile(), _small_rig("tiny", width_px=160, height_px=90,
                                             textures=TextureConfig(seed=2)))
    folder = pair.save(tmp_path / "pair")
    assert sorted(p.name for p in folder.iterdir()) == sorted(StereoPair.FILES)
    back = StereoPair.load(folder)
    np.testing.assert_array_equal(back.left, pair.left)
    np.testing.assert_array_equal(back.right, pair.right)
    np.testing.assert_array_equal(back.instance_left, pair.instance_left)
    np.testing.assert_array_equal(back.depth_left, pair.depth_left)
    assert back.calibration.allclose(pair.calibration)
    assert read_zed_conf(folder / "zed.conf").allclose(pair.calibration)
    assert back.meta["rig"]["width_px"] == 160
    # overwrite in place, leaving no temporary folders behind
    pair.save(folder)
    assert [p.name for p in tmp_path.iterdir()] == ["pair"]
    meta = json.loads((folder / "meta.json").read_text())
    meta["format_version"] = "9.0"
    (folder / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(StereoFormatError, match="version"):
        StereoPair.load(folder)
    with pytest.raises(StereoFormatError):
        StereoPair.load(tmp_path / "missing")


def test_auto_falls_back_to_tinyrenderer_without_egl(monkeypatch):
    import synth.render.stereo as stereo
    from synth.errors import RenderError

    monkeypatch.setattr(stereo, "egl_plugin_path", lambda: None)
    pair = render_stereo(_pile(), _small_rig("auto", width_px=64, height_px=36))
    assert pair.meta["renderer"] == "tiny"
    with pytest.raises(RenderError, match="EGL"):
        render_stereo(_pile(), _small_rig("egl", width_px=64, height_px=36))
