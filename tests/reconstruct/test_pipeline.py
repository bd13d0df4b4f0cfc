"""reconstruct.scan.stereo / pipeline / compare: bad inputs fail loudly and by name; a twin scan is
reconstructed end to end and measured against its ground truth."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from reconstruct.compare import compare_piles, simulate_scan
from reconstruct.errors import GnssFormatError, ReconstructError, RegistrationError, ScanError
from reconstruct.fitting.fit import FitConfig
from reconstruct.config import ReconstructConfig, logs_direction, patch_extent
from reconstruct.report import read_report
from reconstruct.pipeline import reconstruct
from reconstruct.scan.stereo import find_pairs, read_pair, scan_cloud
from synth.geometry.frames import apply_T, make_T, rot_z
from synth.scene.pile import LogSpec, read_pile
from synth.render.ortho import OrthoObservation


# -- scan folders ----------------------------------------------------------------------------
def _write_pair(folder: Path, size=(320, 180), right_size=None, calib_size=None) -> Path:
    import cv2

    from synth.geometry.calibration import write_calibration_yaml

    from synth.render.stereo import StereoRigConfig

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    w, h = size
    img = (rng.random((h, w, 3)) * 255).astype(np.uint8)
    cv2.imwrite(str(folder / "left.png"), img)
    rw, rh = right_size or size
    cv2.imwrite(str(folder / "right.png"), np.roll(img, -8, axis=1)[:rh, :rw] if (rw, rh) == size
                else (rng.random((rh, rw, 3)) * 255).astype(np.uint8))
    cw, ch = calib_size or size
    write_calibration_yaml(StereoRigConfig(width_px=cw, height_px=ch).calibration(), folder / "calibration.yaml")
    return folder


def test_missing_unreadable_and_mismatched_inputs(tmp_path):
    with pytest.raises(ScanError, match="does not exist"):
        find_pairs(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ScanError, match="holds no stereo pair"):
        find_pairs(tmp_path / "empty")
    p = _write_pair(tmp_path / "ok")
    assert read_pair(p).left.shape == (180, 320, 3)
    (p / "right.png").unlink()
    with pytest.raises(ScanError, match=r"right\.png is missing"):
        read_pair(p)
    p = _write_pair(tmp_path / "corrupt")
    (p / "left.png").write_bytes(b"not a png at all")
    with pytest.raises(ScanError, match=r"left\.png cannot be read"):
        read_pair(p)
    p = _write_pair(tmp_path / "sizes", right_size=(300, 180))
    with pytest.raises(ScanError, match="same size"):
        read_pair(p)
    p = _write_pair(tmp_path / "calib", calib_size=(640, 360))
    with pytest.raises(ScanError, match=r"calibration\.yaml is for 640x360"):
        read_pair(p)
    p = _write_pair(tmp_path / "nocalib")
    (p / "calibration.yaml").unlink()
    with pytest.raises(ScanError, match=r"has no calibration: every pair needs calibration\.yaml"):
        read_pair(p)
    # a pair of unrelated noise images: no depth -> a clear error, not an empty pile
    p = tmp_path / "noise"
    _write_pair(p)
    import cv2

    cv2.imwrite(str(p / "right.png"), (np.random.default_rng(9).random((180, 320, 3)) * 255).astype(np.uint8))
    with pytest.raises(ScanError, match="found depth for only"):
        scan_cloud(p)


def test_compare_is_order_and_direction_independent(crossed):
    same = compare_piles(crossed, crossed, size_px=64)
    s = same["summary"]
    assert s["n_matched"] == 3 and s["endpoint_err_m"]["max"] < 1e-9
    assert s["abs_diameter_err_m"]["max"] < 1e-12 and s["mask_iou"]["min"] == pytest.approx(1.0)
    # reversed order, swapped ends, one log 2 cm thicker and shifted 5 cm
    logs = [LogSpec.from_endpoints(*reversed(l.endpoints_m()), l.diameter_m) for l in reversed(crossed.logs)]
    b0, b1 = logs[2].endpoints_m()
    logs[2] = LogSpec.from_endpoints(b0 + [0, 0.05, 0.02], b1 + [0, 0.05, 0.02], logs[2].diameter_m + 0.02)
    other = replace(crossed, logs=tuple(logs))
    c = compare_piles(crossed, other, size_px=64)
    match = {e["truth_index"]: e for e in c["logs"]}
    assert [match[i]["recon_index"] for i in range(3)] == [2, 1, 0]
    assert all(e["ends_swapped"] for e in c["logs"])
    assert match[0]["diameter_err_m"] == pytest.approx(0.02)
    assert match[0]["endpoint_err_m"] == pytest.approx(math.hypot(0.05, 0.02))
    assert match[0]["mask_iou"] < 0.95 and match[1]["mask_iou"] == pytest.approx(1.0)
    json.dumps(c)  # serialisable


# -- the whole pipeline on a twin scan --------------------------------------------------------
@pytest.fixture(scope="module")
def small_scan(tmp_path_factory, crossed):
    """One pair over a small pile of short logs, its scan pose and an RTK survey."""
    logs = tuple(LogSpec.from_endpoints(*(e * [0.6, 0.6, 1.0] for e in l.endpoints_m()), l.diameter_m)
                 for l in crossed.logs)
    pile = replace(crossed, logs=logs)
    d = tmp_path_factory.mktemp("small")
    scan, gnss, truth = simulate_scan(pile, d, seed=4)
    return scan, gnss, truth, d


def test_reconstruct_a_single_pair(small_scan):
    scan, gnss, truth, d = small_scan
    res = reconstruct(scan, gnss, d / "out", ReconstructConfig())
    for name in ("pile.json", "ortho.npz", "preview.png", "compare.png", "report.json"):
        assert (d / "out" / name).exists(), name
    back = read_pile(d / "out" / "pile.json")
    assert back.source == "reconstructed" and back.georef is not None and back.n_logs == 3
    rep = read_report(d / "out")
    assert [lg["log_id"] for lg in rep["logs"]] == ["log0", "log1", "log2"]
    c = compare_piles(truth, res.pile)
    s = c["summary"]
    assert s["n_matched"] == 3
    assert s["abs_diameter_err_m"]["median"] < 0.015, c["logs"]
    assert s["endpoint_err_m"]["median"] < 0.05, c["logs"]
    assert s["mask_iou"]["median"] > 0.8, c["logs"]
    obs = OrthoObservation.load(d / "out" / "ortho.npz")  # the training images' pitch
    assert obs.extent_m / obs.depth.shape[0] == pytest.approx(5.0 / 128)
    # the result carries the observation it wrote, so the field trial plans on it without reading it back
    mem = res.observation
    assert mem is not None and mem.meta == obs.meta and (mem.extent_m, mem.n_logs) == (obs.extent_m, obs.n_logs)
    for name in ("intensity", "depth", "instance"):
        a, b = getattr(mem, name), getattr(obs, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    # the pile frame turned so the logs lie at 45 deg: the same logs on Earth, the same errors
    turned = reconstruct(scan, gnss, d / "turned", ReconstructConfig(log_direction_deg=45.0)).pile
    ends = {i: lg.endpoints_m() for i, lg in enumerate(turned.logs)}
    assert math.degrees(logs_direction(ends)) == pytest.approx(45.0, abs=2.0)  # fitted, not surveyed, ends
    T_site_turned = np.asarray(turned.georef.T_site_pile)
    assert abs(math.degrees(math.atan2(T_site_turned[1, 0], T_site_turned[0, 0]))) > 1.0  # really turned
    for a, b in zip(res.pile.logs, turned.logs):
        for p, q in zip(a.endpoints_m(), b.endpoints_m()):
            site_p = apply_T(np.asarray(res.pile.georef.T_site_pile), p)
            assert np.linalg.norm(site_p - apply_T(T_site_turned, q)) < 0.02
    s2 = compare_piles(truth, turned)["summary"]
    assert s2["n_matched"] == 3 and s2["endpoint_err_m"]["median"] < 0.05 and s2["mask_iou"]["median"] > 0.8


def test_logs_direction_is_the_length_weighted_axial_mean():
    deg = math.radians
    one = {"a": ((0, 0, 0), (math.cos(deg(30)), math.sin(deg(30)), 0))}
    assert math.degrees(logs_direction(one)) == pytest.approx(30.0)
    flipped = {"a": (one["a"][1], one["a"][0])}  # which end was surveyed first does not matter
    assert math.degrees(logs_direction(flipped)) == pytest.approx(30.0)
    # 170 deg and 10 deg are 20 deg apart: their mean is 0 deg (mod 180), not 90
    two = {"a": ((0, 0, 0), (math.cos(deg(170)), math.sin(deg(170)), 0)), "b": ((0, 0, 0), (math.cos(deg(10)), math.sin(deg(10)), 0))}
    assert abs(math.degrees(logs_direction(two))) == pytest.approx(0.0, abs=1e-9)
    long_short = {"a": ((0, 0, 0), (4, 0, 0)), "b": ((0, 0, 0), (0, 1, 0))}  # weighted by length
    assert abs(math.degrees(logs_direction(long_short))) < 20
    with pytest.raises(ValueError, match="log_direction_deg"):
        ReconstructConfig(log_direction_deg=200.0)


def test_patch_keeps_the_training_pitch():
    cfg = ReconstructConfig()  # 128 px over 5 m: 3.9 cm pixels
    assert patch_extent(3.0, cfg) == (5.0, 128)  # at least min_extent_m
    assert patch_extent(5.0, cfg) == (5.0, 128)
    assert patch_extent(5.01, cfg) == (5.625, 144)  # a wider pile: more pixels, the same pitch, 16 px steps
    assert patch_extent(7.3, cfg) == (7.5, 192)
    extent, px = patch_extent(7.3, replace(cfg, render_size_px=64))  # a smaller network's coarser pitch
    assert (extent, px) == (7.5, 96)
    with pytest.raises(RegistrationError, match="at most 100 m"):
        patch_extent(140.0, cfg)
    with pytest.raises(ValueError, match="multiple of 16"):
        ReconstructConfig(render_size_px=100)


def _rows(path: Path) -> list[str]:
    return path.read_text().splitlines()


def test_a_pile_the_twin_cannot_render_is_a_fit_error(small_scan, tmp_path, monkeypatch):
    """A reconstructed pile the twin cannot re-render (a render with holes) is a FitError naming
    the cause, and nothing is written: no pile.json that the planner could not use."""
    import synth.render.ortho
    from reconstruct.errors import FitError
    from synth.errors import RenderError

    def holes(*a, **k):
        raise RenderError("the orthographic render has holes (pixels that see nothing)")

    monkeypatch.setattr(synth.render.ortho, "render_ortho", holes)
    scan, gnss, truth, d = small_scan
    with pytest.raises(FitError, match="cannot be re-rendered .*holes"):
        reconstruct(scan, gnss, tmp_path / "o")
    assert not (tmp_path / "o").exists()


def test_survey_problems_are_named(small_scan, tmp_path):
    scan, gnss, truth, d = small_scan
    lines = _rows(gnss)
    data = [i for i, line in enumerate(lines) if line.startswith("log1,")]
    dup = tmp_path / "dup.csv"
    dup.write_text("\n".join(lines + [lines[data[0]]]) + "\n")
    with pytest.raises(GnssFormatError, match="log1.*measured twice"):
        reconstruct(scan, dup, tmp_path / "o1")
    missing = tmp_path / "missing.csv"
    missing.write_text("\n".join(line for i, line in enumerate(lines) if i != data[1]) + "\n")
    from reconstruct.survey.gnss import read_gnss

    with pytest.raises(GnssFormatError, match="log 'log1' has no end 'b'"):  # the reader alone is strict
        read_gnss(missing)
    # the reconstruction admits it (its other end comes from the scan: test_fusion.py) and says so
    survey = read_gnss(missing, require_both_ends=False)
    assert any("log1 (no end b)" in w for w in survey.warnings)


def test_endpoints_far_from_the_scan_are_named(small_scan, tmp_path):
    from reconstruct.survey.gnss import pile_endpoints_site, simulate_survey, write_gnss_csv

    scan, gnss, truth, d = small_scan
    ends = dict(zip(["log0", "log1", "log2"], pile_endpoints_site(truth)))
    ends["far"] = (ends["log0"][0] + [8.0, 0, 0], ends["log0"][1] + [8.0, 0, 0])
    survey = simulate_survey(ends, truth.georef, np.random.default_rng(0))
    path = write_gnss_csv(survey, tmp_path / "far.csv")
    with pytest.raises(RegistrationError, match="log 'far' end '[ab]'.*outside the scanned area"):
        reconstruct(scan, path, tmp_path / "o3")


def test_scan_without_pose_is_refused(small_scan, tmp_path):
    import shutil

    scan, gnss, truth, d = small_scan
    bare = tmp_path / "bare"
    shutil.copytree(scan, bare)
    (bare / "scan_pose.json").unlink()
    with pytest.raises(RegistrationError, match="no scan_pose.json"):
        reconstruct(bare, gnss, tmp_path / "o4")
    assert issubclass(RegistrationError, ReconstructError)


@pytest.mark.slow
def test_end_to_end_generated_pile(tmp_path):
    """A generated, settled pile with an obstacle, scanned by a 2x2 grid of pairs."""
    from synth.scene.generate import GenerationConfig, generate_pile

    pile, _ = generate_pile(3, GenerationConfig(n_logs=5, n_obstacles=2))
    scan, gnss, truth = simulate_scan(pile, tmp_path, grid=(2, 2), seed=3)
    # the geometry targets, in the site's axes
    res = reconstruct(scan, gnss, tmp_path / "out", ReconstructConfig(fit=FitConfig(), log_direction_deg=None))
    c = compare_piles(truth, res.pile)
    s = c["summary"]
    assert s["n_matched"] == 5
    assert s["abs_diameter_err_m"]["median"] <= 0.01, c["logs"]
    assert s["mask_iou"]["median"] >= 0.9, c["logs"]
    assert s["endpoint_err_m"]["median"] < 0.04, c["logs"]
    assert s["obstacles_detected"] >= 1
    # the default pile frame (logs at 45 deg, what the planner is given; the terrain grid lies
    # diagonal to the logs): the same targets. Before the ground under a log was held under its
    # underside between the grid samples too, this frame lifted three logs 1-2 cm (IoU 0.887). The
    # scan's fused cloud does not depend on the pile frame: the first run's, not matched again
    turned = reconstruct(scan, gnss, tmp_path / "turned", ReconstructConfig(fit=FitConfig()), cloud=res.cloud)
    c = compare_piles(truth, turned.pile)
    s = c["summary"]
    assert s["n_matched"] == 5 and s["obstacles_detected"] >= 1
    assert s["abs_diameter_err_m"]["median"] <= 0.01, c["logs"]
    assert s["mask_iou"]["median"] >= 0.9, c["logs"]
    assert s["endpoint_err_m"]["median"] < 0.04, c["logs"]
    assert not any("terrain" in m for m in turned.fit.moves), turned.fit.moves  # nothing lifted off the ground


def test_compare_across_site_origins(crossed):
    """Both piles georeferenced, at different site origins: compared through SWEREF 99."""
    from synth.geometry import geodesy
    from synth.scene.pile import Georeference

    T = make_T(rot_z(0.4), (3.0, -2.0, 0.5))
    g = Georeference(64.1, 20.0, 250.0, tuple(tuple(float(v) for v in r) for r in T))
    truth = replace(crossed, georef=g)
    lat, lon, h = geodesy.site_to_geodetic(g, np.array([10.0, 5.0, 0.0]))
    T2 = T.copy()
    T2[:3, 3] -= (10.0, 5.0, 0.0)
    other = replace(crossed, georef=Georeference(float(lat), float(lon), float(h), tuple(map(tuple, T2))))
    c = compare_piles(truth, other, size_px=64)
    assert c["frame"] == "through geodetic coordinates"
    assert c["summary"]["endpoint_err_m"]["max"] < 1e-3  # ENU frames 11 m apart: tilt ~2 µrad
    assert c["summary"]["mask_iou"]["min"] == pytest.approx(1.0)
