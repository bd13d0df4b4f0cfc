"""reconstruct.scan.calibration: a pair's calibration from calibration.yaml and/or the camera's ZED
SN*.conf (the section of the images' resolution); disagreeing files and corrupt ones are one-line
errors naming the file."""

from __future__ import annotations

import configparser
import io
from pathlib import Path

import numpy as np
import pytest

from reconstruct.scan.calibration import pair_pose_present, read_pair_calibration
from reconstruct.errors import CalibrationError, ScanError
from reconstruct.scan.stereo import read_pair

HD = (1280, 720)


def _calib(fx: float = 1372.5, baseline_m: float = 0.12, size=HD, pose=None):
    from synth.geometry.calibration import StereoCalibration

    w, h = size
    K = np.array([[fx, 0, w / 2 - 3.5], [0, fx, h / 2 + 2.25], [0, 0, 1.0]])
    D = np.array([-0.04, 0.012, 0.0002, -0.0001, 0.0])
    return StereoCalibration(K, K.copy(), D, D.copy(), np.eye(3), np.array([-baseline_m, 0.0, 0.0]), size,
                             np.eye(4) if pose is None else pose)


def _factory_conf(hd_fx: float = 1372.5) -> str:
    """A ZED factory SN<serial>.conf: every resolution, no [LOGGRASP] section, no pose."""
    from synth.geometry.calibration import zed_conf_text

    text = zed_conf_text(_calib(fx=hd_fx))
    src = configparser.ConfigParser()
    src.optionxform = str
    src.read_string(text)
    out = configparser.ConfigParser()
    out.optionxform = str
    for res, scale in (("2K", 1.725), ("FHD", 1.5), ("HD", 1.0), ("VGA", 0.525)):
        for side in ("LEFT", "RIGHT"):
            sec = dict(src[f"{side}_CAM_HD"])
            for k in ("fx", "fy", "cx", "cy"):
                sec[k] = repr(float(sec[k]) * scale)
            out[f"{side}_CAM_{res}"] = sec
    st = {"Baseline": src["STEREO"]["Baseline"]}
    for res in ("2K", "FHD", "HD", "VGA"):
        for k in ("TY", "TZ", "CV", "RX", "RZ"):
            st[f"{k}_{res}"] = src["STEREO"][f"{k}_HD"]
    out["STEREO"] = st
    out["MISC"] = {"Sensor_ID": "1"}
    buf = io.StringIO()
    out.write(buf)
    return buf.getvalue()


_IMAGES: dict[Path, Path] = {}


def _images(folder: Path) -> Path:
    """A pair folder with two HD images (written once per test's tmp root, then copied)."""
    import shutil

    import cv2

    root = folder.parent
    if root not in _IMAGES:
        src = root / "_images"
        src.mkdir(parents=True, exist_ok=True)
        img = np.full((HD[1], HD[0], 3), 128, np.uint8)  # flat: cheap to write, calibration is all that is read
        cv2.imwrite(str(src / "left.png"), img)
        _IMAGES[root] = src
    folder.mkdir(parents=True, exist_ok=True)
    for name in ("left.png", "right.png"):
        shutil.copyfile(_IMAGES[root] / "left.png", folder / name)
    return folder


def test_a_zed_factory_file_alone_is_read_at_the_images_resolution(tmp_path):
    p = _images(tmp_path / "pair")
    (p / "SN28475961.conf").write_text(_factory_conf(hd_fx=1372.5))
    calib, source = read_pair_calibration(p, HD)
    assert source == "SN28475961.conf"
    assert calib.K_left[0, 0] == pytest.approx(1372.5)  # the HD section, not 2K (2367.6) or FHD (2058.8)
    assert calib.image_size == HD
    assert calib.baseline_m == pytest.approx(0.12)
    assert not pair_pose_present(p)
    pair = read_pair(p)  # the whole pair reads with it
    assert pair.calibration.K_left[0, 0] == pytest.approx(1372.5)
    # a size the file has no section for is named with the sizes it has
    with pytest.raises(CalibrationError, match=r"no calibration for 1000x500 px.*HD \(1280x720\)"):
        read_pair_calibration(p, (1000, 500))


def test_calibration_yaml_and_zed_conf_that_disagree_name_both_values(tmp_path):
    from synth.geometry.calibration import write_calibration_yaml

    p = _images(tmp_path / "pair")
    write_calibration_yaml(_calib(fx=1372.5), p / "calibration.yaml")
    (p / "SN1.conf").write_text(_factory_conf(hd_fx=1372.5))
    calib, source = read_pair_calibration(p, HD)  # agreeing: fine, both named
    assert source == "calibration.yaml + SN1.conf"
    (p / "SN1.conf").write_text(_factory_conf(hd_fx=1390.0))
    with pytest.raises(CalibrationError, match=r"calibration\.yaml and SN1\.conf disagree: left fx 1372\.50 px vs "
                                               r"1390\.00 px"):
        read_pair_calibration(p, HD)
    write_calibration_yaml(_calib(fx=1390.0, baseline_m=0.119), p / "calibration.yaml")
    with pytest.raises(CalibrationError, match=r"baseline 119\.00 mm vs 120\.00 mm"):
        read_pair_calibration(p, HD)
    (p / "zed.conf").write_text(_factory_conf())
    with pytest.raises(CalibrationError, match=r"2 ZED calibrations \(SN1\.conf, zed\.conf\)"):
        read_pair_calibration(p, HD)


def test_a_pose_in_the_twins_zed_conf_is_found(tmp_path):
    from synth.geometry.calibration import write_zed_conf

    pose = np.eye(4)
    pose[:3, 3] = (0.5, -0.25, 3.0)
    p = _images(tmp_path / "pair")
    write_zed_conf(_calib(pose=pose), p / "zed.conf")
    calib, _ = read_pair_calibration(p, HD)
    assert pair_pose_present(p)
    assert np.allclose(calib.T_pile_cam, pose)


def _corruptions(tmp_path: Path) -> dict[str, tuple[str, bytes]]:
    from synth.geometry.calibration import calibration_yaml_text

    yaml = calibration_yaml_text(_calib())
    conf = _factory_conf()
    return {
        "truncated yaml": ("calibration.yaml", yaml[: len(yaml) // 2].encode()),
        "not yaml": ("calibration.yaml", b"this is not a calibration { at all ]\n"),
        "binary": ("calibration.yaml", bytes(range(256)) * 4),
        "empty": ("calibration.yaml", b""),
        "no K1": ("calibration.yaml", yaml.replace("K1:", "K9:").encode()),
        "short image_size": ("calibration.yaml", yaml.replace("image_size", "image_size_old").replace(
            "K2:", "image_size: [ 1280 ]\nK2:").encode()),
        "K not 3x3": ("calibration.yaml", yaml.replace("rows: 3\n   cols: 3\n   dt: d\n   data: [ 1372.5, 0., 636.5,",
                                                       "rows: 2\n   cols: 3\n   dt: d\n   data: [", 1).encode()),
        "R not a rotation": ("calibration.yaml", yaml.replace("data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]",
                                                              "data: [ 2., 0., 0., 0., 1., 0., 0., 0., 1. ]", 1).encode()),
        "zed binary": ("SN5.conf", bytes(range(256)) * 4),
        "zed not ini": ("SN5.conf", b"fx = 1\n"),
        "zed no stereo": ("SN5.conf", conf.split("[STEREO]")[0].encode()),
        "zed bad number": ("SN5.conf", conf.replace("[LEFT_CAM_HD]\nfx = ", "[LEFT_CAM_HD]\nfx = abc", 1).encode()),
        "zed no fx": ("SN5.conf", "\n".join(ln for ln in conf.splitlines() if not ln.startswith("fx")).encode()),
        "zed duplicate section": ("SN5.conf", (conf + "\n[STEREO]\nBaseline = 1\n").encode()),
    }


def test_every_corrupt_calibration_is_a_one_line_error_naming_the_file(tmp_path):
    for k, (name, data) in enumerate(_corruptions(tmp_path).items()):
        p = _images(tmp_path / f"pair{k}")
        fname, content = data
        (p / fname).write_bytes(content)
        with pytest.raises(ScanError) as info:  # CalibrationError is a ScanError: the CLI's one-line error
            read_pair(p)
            pytest.fail(f"{name}: read without an error")
        msg = str(info.value)
        assert isinstance(info.value, CalibrationError), (name, type(info.value), msg)
        assert "\n" not in msg and fname in msg, (name, msg)
        assert "Traceback" not in msg and len(msg) < 400, (name, msg)
