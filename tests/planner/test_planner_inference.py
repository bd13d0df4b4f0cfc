import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from planner.checkpoint import load_checkpoint, save_checkpoint
from planner.constraints import Constraints
from planner.errors import CheckpointError, ObservationError
from planner.inference import Objective, Planner, plan
from planner.model import UNetConfig, build_unet, prepare_for_inference
from planner.subsets import SubsetPolicy, all_subsets, choose_subsets, feasible_subsets
from synth.geometry.frames import OrthoGrid
from synth.geometry.grasp import Grasp
from planner_helpers import bar_pile, observation

TINY = UNetConfig.tiny()


def _planner(cfg=TINY, precision="fp32"):
    torch.manual_seed(0)
    return Planner(build_unet(cfg), cfg, precision=precision)


class FakeNet:
    """Stands in for the network: hand-made outputs so selection can be checked exactly."""

    def __init__(self, fn):
        self.fn = fn


def _fixed_planner(out_fn, quality_smoothing_px: float = 0.0):
    p = _planner()
    p.predict = lambda x: out_fn(x)
    p.quality_smoothing_px = quality_smoothing_px  # single-pixel peaks below: score them raw
    return p


# -- subsets --------------------------------------------------------------------------------
def test_all_subsets_count_and_order():
    s = all_subsets([0, 1, 2, 3])
    assert len(s) == 15 and len(set(s)) == 15
    assert s[0] == (0,) and s[-1] == (0, 1, 2, 3)
    assert len(all_subsets(list(range(7)))) == 127
    assert all(len(t) <= 2 for t in all_subsets(list(range(5)), max_size=2))


def test_feasible_subsets_drop_far_apart_logs_and_are_monotone():
    size, grid = 64, OrthoGrid(64, 5.0)
    masks = {i: np.zeros((size, size), bool) for i in range(3)}
    masks[0][10:12, 10:40] = True
    masks[1][20:22, 10:40] = True  # 0.7 m from log 0
    masks[2][50:52, 10:40] = True  # ~3 m away
    subs, info = feasible_subsets(masks, grid.pixel_m)
    assert set(subs) == {(0,), (1,), (2,), (0, 1)}
    assert info["n_fit"] == 4
    # a tight opening keeps only singletons
    subs2, _ = feasible_subsets(masks, grid.pixel_m, SubsetPolicy(mode="fit", max_opening_m=0.1, rect_width_m=0.0))
    assert set(subs2) == {(0,), (1,), (2,)}


def test_feasible_subsets_never_drop_what_exhaustive_finds_feasible():
    rng = np.random.default_rng(1)
    size, grid = 64, OrthoGrid(64, 5.0)
    masks = {}
    for i in range(6):
        m = np.zeros((size, size), bool)
        r, c = rng.integers(5, 55, 2)
        m[r : r + 2, c : c + 8] = True
        masks[i] = m
    subs, _ = feasible_subsets(masks, grid.pixel_m, SubsetPolicy(mode="fit", max_subsets=10 ** 6))
    # brute force on the full grid
    from planner.subsets import distance_maps

    d = distance_maps(masks, grid.pixel_m)
    R = SubsetPolicy().fit_radius_m
    for s in all_subsets(list(range(6))):
        fits = np.max([d[i] for i in s], axis=0).min() <= R
        if fits:
            assert s in subs


def test_subset_cap_keeps_singletons_and_budget():
    inten, depth, inst, _ = bar_pile(12, 64)
    masks = {i: inst == i + 1 for i in range(12)}
    subs, info = choose_subsets(masks, 5.0 / 64, SubsetPolicy(max_subsets=40))
    assert info["selection"] == "fit" and len(subs) <= 40
    assert all((i,) in subs for i in range(12))
    with pytest.raises(ValueError, match="budget"):
        choose_subsets(masks, 5.0 / 64, SubsetPolicy(mode="exhaustive", max_subsets=127))


# -- objectives -------------------------------------------------------------------------------
def test_objectives():
    u, b = np.array([0.5, 0.9]), np.array([1.0, 0.5])
    np.testing.assert_allclose(Objective("f1").quality(u, 4, b), u)
    np.testing.assert_allclose(Objective("f2").quality(u, 8, b), u * 2.0, rtol=1e-6)
    q3 = Objective("f3").quality(u, 8, b)
    np.testing.assert_allclose(q3, u * 2.0 * np.exp(-((b - 1.0) ** 2) / 0.25 ** 2), rtol=1e-5)
    assert q3[1] < q3[0]  # unbalanced grasp penalised despite higher u
    with pytest.raises(ValueError):
        Objective("f4")


# -- model / checkpoint -------------------------------------------------------------------------
def test_model_sizes_and_variants():
    from planner.model import count_parameters

    assert 3.9e6 < count_parameters(build_unet(UNetConfig())) < 4.2e6  # the paper's ~4.1 M
    m2 = build_unet(UNetConfig.tiny(in_channels=2))
    y = m2(torch.rand(2, 2, 32, 32))
    assert y.shape == (2, 5, 32, 32)
    assert (y[:, 2] >= 0.30).all() and (y[:, 2] <= 1.55).all() and (y[:, :2].abs() <= 1).all()
    late = build_unet(UNetConfig.tiny(mask_injection="decoder")).eval()
    x = torch.rand(3, 3, 32, 32)
    with torch.no_grad():
        torch.testing.assert_close(late(x[:1].expand(3, -1, -1, -1).clone().copy_(
            torch.cat([x[:1, :2].expand(3, -1, -1, -1), x[:, 2:]], 1))),
            late.forward_shared(x[:1, :2], x[:, 2:]))
    with pytest.raises(ValueError):
        UNetConfig(size_px=100)  # not divisible by 16


def test_inference_copy_matches_training_model():
    torch.manual_seed(0)
    m = build_unet(TINY)
    m.train()
    m(torch.rand(4, 3, 32, 32))  # move BatchNorm statistics away from the defaults
    m.eval()
    x = torch.rand(2, 3, 32, 32)
    with torch.no_grad():
        ref = m(x)
        f32 = prepare_for_inference(m, "fp32")(x.contiguous(memory_format=torch.channels_last))
        bf = prepare_for_inference(m, "bf16")(x.to(torch.bfloat16).contiguous(memory_format=torch.channels_last))
    torch.testing.assert_close(f32, ref, atol=1e-4, rtol=1e-4)
    assert (bf - ref).abs().max() < 0.1


def test_checkpoint_round_trip_and_errors(tmp_path):
    torch.manual_seed(0)
    m = build_unet(TINY)
    path = save_checkpoint(tmp_path / "m.safetensors", m, TINY, {"epoch": 3})
    m2, cfg, meta = load_checkpoint(path)
    assert cfg == TINY and meta == {"epoch": 3}
    for k, v in m.state_dict().items():
        torch.testing.assert_close(v, m2.state_dict()[k])
    with pytest.raises(CheckpointError, match="does not exist"):
        load_checkpoint(tmp_path / "nope.safetensors")
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])
    with pytest.raises(CheckpointError, match="corrupt"):
        load_checkpoint(bad)
    with pytest.raises(CheckpointError, match="input channels"):
        load_checkpoint(path, in_channels=2)
    with pytest.raises(CheckpointError, match="32 px"):
        load_checkpoint(path, size_px=128)
    # weights that do not fit the stored architecture
    from planner.checkpoint import save_tensors

    hdr = {"format": "loggrasp.planner.checkpoint", "format_version": "1.0",
           "model_config": UNetConfig.tiny(base_channels=8).to_dict(), "meta": {}}
    save_tensors(tmp_path / "mismatch.safetensors", m.state_dict(), hdr)
    with pytest.raises(CheckpointError, match="do not fit"):
        load_checkpoint(tmp_path / "mismatch.safetensors")
    save_tensors(tmp_path / "v9.safetensors", m.state_dict(), {**hdr, "format_version": "9.0"})
    with pytest.raises(CheckpointError, match="version"):
        load_checkpoint(tmp_path / "v9.safetensors")


# -- planning -------------------------------------------------------------------------------------
def _peak_output(peaks):
    """Network stand-in: for subset k (batch order) put u = peaks[k][2] at pixel peaks[k][:2]."""
    def fn(x):
        n = len(x)
        out = np.zeros((n, 5, 32, 32), np.float32)
        out[:, 0] = -1.0  # C = cos 2phi = -1 -> phi = pi/2
        out[:, 2] = 0.8
        out[:, 3] = -10.0
        out[:, 4] = 1.0
        for k in range(n):
            r, c, u = peaks[k % len(peaks)]
            out[k, 3, r, c] = math.log(u / (1 - u))
        return out
    return fn


def test_plan_output_format_ranking_and_decoding():
    obs = observation(3)
    pl = _fixed_planner(_peak_output([(10, 10, 0.6), (16, 16, 0.9), (20, 12, 0.7)]))
    p = plan(obs, pl)
    assert p.subsets_evaluated == 7
    d = json.loads(p.to_json())
    assert set(d) >= {"grasps", "subsets_evaluated", "elapsed_s"}
    g0 = d["grasps"][0]
    assert set(g0) >= {"x_m", "y_m", "phi_rad", "width_m", "quality", "graspability", "balance", "targets"}
    qs = [g["quality"] for g in d["grasps"]]
    assert qs == sorted(qs, reverse=True) and len(qs) == 7
    assert g0["quality"] == pytest.approx(0.9, abs=1e-4)
    x, y = OrthoGrid(32, 5.0).pixel_to_pile(16, 16)
    assert (g0["x_m"], g0["y_m"]) == pytest.approx((float(x), float(y)))
    assert abs(abs(g0["phi_rad"]) - math.pi / 2) < 1e-6 and g0["width_m"] == pytest.approx(0.8)
    assert len(plan(obs, pl, top_k=2).grasps) == 2


def test_u_at_scores_a_grasp_as_planning_scored_it():
    """u_at (another model's grasps scored by this network) gives each planned grasp the U the plan
    reported for it, on its own subset's maps; a grasp moved off its pixel scores differently."""
    from planner.inference import u_at

    def fn(x):  # U peaks at a pixel that depends on the subset (its mask's size)
        out = np.zeros((len(x), 5, 32, 32), np.float32)
        out[:, 0], out[:, 2], out[:, 3], out[:, 4] = -1.0, 0.8, -3.0, 1.0
        for k in range(len(x)):
            n = int(x[k, -1].sum())
            out[k, 3, 4 + n % 24:7 + n % 24, 8:11] = 1.0 + (n % 7) / 3.0
        return out

    obs, pl = observation(3), _fixed_planner(fn, 1.0)
    got = plan(obs, pl).grasps
    gs, ts = [g.grasp for g in got], [g.targets for g in got]
    assert len({round(g.graspability, 4) for g in got}) > 1
    assert u_at(obs, pl, gs, ts) == pytest.approx([g.graspability for g in got], abs=1e-6)
    assert u_at(obs, pl, gs[::-1], ts[::-1]) == pytest.approx([g.graspability for g in got][::-1], abs=1e-6)
    moved = [Grasp(g.x_m + 0.8, g.y_m, g.phi_rad, g.width_m) for g in gs]
    assert all(m < g.graspability - 0.1 for m, g in zip(u_at(obs, pl, moved, ts), got))
    with pytest.raises(ObservationError, match="target subsets"):
        u_at(obs, pl, gs, ts[:-1])


def test_maps_at_gives_each_grasp_the_balance_the_plan_reported():
    """maps_at's b is the plan's balance of each planned grasp (its own subset's B map, smoothed as
    planning smooths it), and its U is u_at's."""
    from planner.inference import maps_at, u_at

    def fn(x):  # U peaks at a subset-dependent pixel; B differs per subset and across the image
        out = np.zeros((len(x), 5, 32, 32), np.float32)
        out[:, 0], out[:, 2], out[:, 3] = -1.0, 0.8, -3.0
        for k in range(len(x)):
            n = int(x[k, -1].sum())
            out[k, 3, 4 + n % 24:7 + n % 24, 8:11] = 1.0 + (n % 7) / 3.0
            out[k, 4] = 0.9 + 0.1 * np.linspace(0, 1, 32)[None, :] * (n % 5) / 4
        return out

    obs, pl = observation(3), _fixed_planner(fn, 1.0)
    got = plan(obs, pl).grasps
    gs, ts = [g.grasp for g in got], [g.targets for g in got]
    u, b = maps_at(obs, pl, gs, ts)
    assert len({round(g.balance, 4) for g in got}) > 1
    assert b == pytest.approx([g.balance for g in got], abs=1e-6)
    assert u == pytest.approx(u_at(obs, pl, gs, ts), abs=1e-9)


def test_f3_with_the_hang_model_prefers_the_grasp_over_the_load_s_centre():
    """Objective(balance="hang"): with U and the B map flat, f3 grasps each subset where its load hangs
    level (across the mask's centroid, along its principal axis) and reports that balance; the network's
    flat B leaves the first pixel."""
    from planner.balance import HangModel, principal_axis

    def fn(x):
        out = np.zeros((len(x), 5, 32, 32), np.float32)
        out[:, 0], out[:, 2], out[:, 3], out[:, 4] = -1.0, 0.8, 2.0, 1.0
        return out

    obs, pl = observation(3), _fixed_planner(fn, 0.0)
    hang = plan(obs, pl, Objective("f3", balance="hang", sigma_b=0.05)).grasps
    flat = plan(obs, pl, Objective("f3")).grasps
    for g in hang:
        rr, cc = np.nonzero(np.isin(obs.instance, [i + 1 for i in g.targets]))
        ar, ac = principal_axis(rr, cc)
        assert abs((g.pixel[0] - rr.mean()) * ar + (g.pixel[1] - cc.mean()) * ac) < 1.0, (g.targets, g.pixel)
        assert g.balance == pytest.approx(1.0, abs=1e-3)
    assert {g.pixel for g in flat} == {(0, 0)} and all(g.balance == 1.0 for g in flat)
    with pytest.raises(ValueError, match="balance"):
        Objective("f3", balance="guess")
    assert HangModel().lever_m(100.0) > HangModel().lever_m(200.0)


def test_quality_smoothing_prefers_a_zone_over_a_spike():
    def fn(x):
        out = np.zeros((len(x), 5, 32, 32), np.float32)
        out[:, 0], out[:, 2], out[:, 3], out[:, 4] = -1.0, 0.8, -10.0, 1.0
        out[:, 3, 5, 5] = math.log(0.95 / 0.05)  # a lone spike
        out[:, 3, 19:24, 19:24] = math.log(0.8 / 0.2)  # a grasp zone
        return out

    obs = observation(3)
    assert plan(obs, _fixed_planner(fn, 0.0)).best.pixel == (5, 5)
    smooth = plan(obs, _fixed_planner(fn, 1.0)).best
    assert smooth.pixel == (21, 21) and 0.6 < smooth.graspability < 0.8
    with pytest.raises(ValueError, match="smoothing"):
        Planner(_planner().model, _planner().config, quality_smoothing_px=-1.0)


def test_f2_prefers_more_logs():
    obs = observation(3)
    peaks = [(10, 10, 0.8)] * 3 + [(12, 12, 0.7)] * 4  # singletons 0.8, pairs/triple 0.7
    pl = _fixed_planner(_peak_output(peaks))
    assert len(plan(obs, pl, Objective("f1")).best.targets) == 1
    assert len(plan(obs, pl, Objective("f2")).best.targets) >= 2


def test_constraints_reach_capacity_keep_out():
    obs = observation(3)
    grid = OrthoGrid(32, 5.0)
    pl = _fixed_planner(_peak_output([(16, 16, 0.9)]))
    free = plan(obs, pl)
    gx, gy = free.best.grasp.x_m, free.best.grasp.y_m
    # reach: base far away, max reach excludes the peak
    c = Constraints(crane_base_xy_m=(gx + 3.0, gy), min_reach_m=0.0, max_reach_m=2.5)
    p = plan(obs, pl, constraints=c)
    assert all(math.hypot(g.grasp.x_m - gx - 3.0, g.grasp.y_m - gy) <= 2.5 + 1e-9 for g in p.grasps)
    assert any(r["constraint"] == "reach" and r["action"] == "moved" for r in p.rejected)
    far = plan(obs, pl, constraints=Constraints(crane_base_xy_m=(50.0, 0.0), max_reach_m=10.0))
    assert far.grasps == [] and all(r["action"] == "removed" for r in far.rejected) and len(far.rejected) == 7
    # lift capacity from the masks: singles pass, the triple does not
    masses = Constraints().log_masses_kg({i: int((obs.instance == i + 1).sum()) for i in range(3)}, grid.pixel_m)
    cap = Constraints(lift_capacity_kg=2.5 * masses[0])
    p = plan(obs, pl, constraints=cap)
    assert p.subsets_evaluated == 6 and all(len(g.targets) <= 2 for g in p.grasps)
    assert any(r["constraint"] == "lift_capacity" and r["targets"] == [0, 1, 2] for r in p.rejected)
    # keep-out polygon around the best pixel: every grasp rectangle avoids it
    zone = ((gx - 0.3, gy - 0.3), (gx + 0.3, gy - 0.3), (gx + 0.3, gy + 0.3), (gx - 0.3, gy + 0.3))
    p = plan(obs, pl, constraints=Constraints(keep_out_zones=(zone,)))
    from planner.constraints import polygon_raster

    zr = polygon_raster(grid, np.array(zone))
    for g in p.grasps:
        assert not (polygon_raster(grid, g.grasp.rectangle()) & zr).any()
    assert any(r["constraint"] == "keep_out" for r in p.rejected)


def test_capacity_uses_pile_volumes_when_known():
    c = Constraints()
    fake_log = SimpleNamespace(volume_m3=lambda: 0.1)
    m = c.log_masses_kg({0: 10}, 0.1, pile=SimpleNamespace(logs=[fake_log]))
    assert m[0] == pytest.approx(90.0)


def test_bad_observations_raise_clear_errors():
    pl = _planner()
    obs = observation(3)
    empty = observation(3)
    empty.instance = np.where(empty.instance < 1000, 0, empty.instance).astype(np.int16)
    with pytest.raises(ObservationError, match="no logs"):
        plan(empty, pl)
    nan = observation(3)
    nan.depth = nan.depth.copy()
    nan.depth[3, 3] = np.nan
    with pytest.raises(ObservationError, match="NaN"):
        plan(nan, pl)
    with pytest.raises(ObservationError, match=r"15.62 cm pixels \(32 px over 5 m\).*look larger"):
        plan(observation(3, size=64), pl)  # 5 m at 64 px: another pitch than the network's
    with pytest.raises(ObservationError, match=r"trained on 15.62 cm.*look smaller.*\(35 px over 5.5 m\)"):
        plan(observation(3, size=32, extent=5.5), pl)
    with pytest.raises(ObservationError, match="multiple of 4"):
        plan(observation(3, size=34, extent=34 * 5.0 / 32), pl)
    bigger = plan(observation(3, size=64, extent=10.0), pl)  # the network's pitch on a larger patch
    assert bigger.best is not None and max(abs(bigger.best.grasp.x_m), abs(bigger.best.grasp.y_m)) <= 5.0
    many = observation(8)
    with pytest.raises(ObservationError, match="budget"):
        plan(many, pl, subsets=SubsetPolicy(mode="exhaustive"))
    p = plan(many, pl)  # auto: pre-selects
    assert p.info["selection"] == "fit" and 0 < p.subsets_evaluated <= 127
    assert plan(obs, pl).best is not None


def test_obstacles_are_never_targets():
    pl = _planner()
    p = plan(observation(2, n_obstacles=2), pl)
    assert p.subsets_evaluated == 3
    assert all(set(g.targets) <= {0, 1} for g in p.grasps)


def test_real_network_bf16_plan_runs():
    p = plan(observation(3), _planner(precision="bf16"))
    assert p.subsets_evaluated == 7 and len(p.grasps) == 7
    assert all(0.30 <= g.grasp.width_m <= 1.55 and 0 <= g.graspability <= 1 for g in p.grasps)


def test_no_depth_ablation_and_decoder_injection_plan():
    for cfg in (UNetConfig.tiny(in_channels=2), UNetConfig.tiny(mask_injection="decoder")):
        p = plan(observation(3), _planner(cfg, precision="bf16"))
        assert p.subsets_evaluated == 7 and len(p.grasps) == 7


def test_eight_views_make_the_plan_independent_of_the_pictures_orientation():
    """The mean over the 8 dihedral views is equivariant: turning (or mirroring) the picture turns
    the maps and the decoded grasp with it, which one view alone does not do."""
    from planner.inference import _view, _view_back
    from planner.model import OUTPUT_NAMES

    rng = np.random.default_rng(3)
    x = rng.random((2, TINY.in_channels, TINY.size_px, TINY.size_px)).astype(np.float32)
    for cfg in (TINY, UNetConfig.tiny(mask_injection="decoder")):
        p1 = Planner(_planner(cfg).model, cfg, precision="fp32")
        p8 = Planner(p1.model, cfg, precision="fp32", views=8)
        y = p8.predict(x)
        assert y.shape == (2, len(OUTPUT_NAMES), TINY.size_px, TINY.size_px)
        for flip, k in ((False, 1), (True, 0), (True, 3)):
            # the maps of the turned picture, brought back, equal the maps of the picture
            back = _view_back(p8.predict(_view(x, flip, k)), flip, k)
            np.testing.assert_allclose(back, y, atol=2e-4)
            # one view is not equivariant (else the test could not fail)
            back1 = _view_back(p1.predict(_view(x, flip, k)), flip, k)
            assert np.abs(back1 - p1.predict(x)).max() > 1e-2
    # a grasp decoded from a quarter-turned picture is the turned grasp
    obs = observation(3, size=TINY.size_px)
    turned = SimpleNamespace(intensity=np.rot90(obs.intensity, 1, axes=(-2, -1)).copy(),
                             depth=np.rot90(obs.depth, 1).copy(), instance=np.rot90(obs.instance, 1).copy(),
                             extent_m=obs.extent_m, camera_height_m=obs.camera_height_m)
    p8 = Planner(_planner().model, TINY, precision="fp32", views=8)
    a = plan(obs, p8, top_k=1).best.grasp
    b = plan(turned, p8, top_k=1).best.grasp
    # a quarter turn counter-clockwise seen from above: (x, y) -> (-y, x), phi -> phi + 90 deg
    assert math.hypot(b.x_m + a.y_m, b.y_m - a.x_m) < 1e-6
    assert abs(math.remainder(b.phi_rad - a.phi_rad - math.pi / 2, math.pi)) < 1e-3
    assert abs(a.width_m - b.width_m) < 1e-4
    with pytest.raises(ValueError, match="views"):
        Planner(p8.model, TINY, views=3)


def test_view_spread_lowers_u_where_the_views_disagree():
    """``view_spread_k`` subtracts k x the standard deviation of the U logit over the views; the
    other maps are the plain mean."""
    from planner.inference import _view, _view_back, _view_list

    rng = np.random.default_rng(5)
    x = rng.random((2, TINY.in_channels, TINY.size_px, TINY.size_px)).astype(np.float32)
    model = _planner().model
    mean = Planner(model, TINY, precision="fp32", views=4).predict(x)
    lcb = Planner(model, TINY, precision="fp32", views=4, view_spread_k=2.0).predict(x)
    p1 = Planner(model, TINY, precision="fp32")
    ys = np.stack([_view_back(p1.predict(_view(x, f, k)), f, k) for f, k in _view_list(4)])
    np.testing.assert_allclose(mean, ys.mean(0), atol=1e-5)
    np.testing.assert_allclose(np.delete(lcb, 3, axis=1), np.delete(mean, 3, axis=1), atol=1e-6)
    np.testing.assert_allclose(lcb[:, 3], mean[:, 3] - 2.0 * ys[:, :, 3].std(0), atol=1e-4)
    assert (ys[:, :, 3].std(0) > 1e-3).mean() > 0.5  # the views do disagree: the bound moves U
    for bad in ({"views": 1, "view_spread_k": 1.0}, {"views": 8, "view_spread_k": -1.0}):
        with pytest.raises(ValueError, match="view_spread_k"):
            Planner(model, TINY, **bad)


def test_a_wider_pile_is_rendered_at_the_networks_pitch(tmp_path):
    from planner.cli import load_observation
    from synth.scene.pile import LogSpec, PileSpec, TerrainSpec, write_pile

    pile = PileSpec(terrain=TerrainSpec(seed=1, extent_m=10.0, resolution=32, amplitude_m=0.0),
                    logs=(LogSpec.from_endpoints((-4.0, 0.0, 0.15), (4.0, 0.0, 0.15), 0.3),))
    write_pile(pile, tmp_path / "pile.json")
    cfg = TINY  # 32 px over 5 m
    obs, spec = load_observation(tmp_path / "pile.json", cfg)
    assert obs.depth.shape == (64, 64) and obs.extent_m == 10.0 and spec is not None
    p = plan(obs, _planner(cfg))
    assert p.best is not None and p.best.targets == (0,)


def _with_obstacle_at(obs, grasp, grid, code=1000):
    """``obs`` with a 2 x 2 px obstacle (instance ``code``) put where ``grasp``'s rectangle lies."""
    from planner.constraints import polygon_raster

    rect = np.argwhere(polygon_raster(grid, grasp.rectangle()))
    r, c = rect[len(rect) // 2]
    inst = obs.instance.copy()
    inst[r:r + 2, c:c + 2] = code
    return SimpleNamespace(**{**vars(obs), "instance": inst})


def test_clear_obstacles_moves_a_grasp_off_an_obstacle_the_observation_shows():
    from planner.constraints import polygon_raster

    obs, grid = observation(3), OrthoGrid(32, 5.0)
    pl = _fixed_planner(_peak_output([(16, 16, 0.9)]))
    over = Constraints(clear_obstacles=False)
    best = plan(obs, pl, constraints=over).best
    blocked = _with_obstacle_at(obs, best.grasp, grid)
    assert plan(blocked, pl, constraints=over).best == best  # the switch off: over the obstacle, as before
    p = plan(blocked, pl)  # on by default
    obstacle = blocked.instance >= 1000
    assert p.grasps and all(not (polygon_raster(grid, g.grasp.rectangle()).astype(bool) & obstacle).any()
                            for g in p.grasps)
    assert any(r["constraint"] == "obstacle" and r["action"] == "moved" for r in p.rejected)
    # an observation without obstacles plans exactly as without the switch
    clean = SimpleNamespace(**{**vars(obs), "instance": np.where(obs.instance >= 1000, 0, obs.instance)})
    assert plan(clean, pl).grasps == plan(clean, pl, constraints=over).grasps


def test_clear_obstacles_is_a_switch():
    with pytest.raises(ValueError, match="clear_obstacles is a switch"):
        Constraints(clear_obstacles="yes")


def _with_obstacle_near(obs, grasp, grid, along_m, across_m, code=1000):
    """``obs`` with a 1 px obstacle at ``along_m`` along ``grasp``'s closing axis and ``across_m`` across it."""
    a = grasp.closing_axis()
    x = grasp.x_m + a[0] * along_m - a[1] * across_m
    y = grasp.y_m + a[1] * along_m + a[0] * across_m
    r, c = (int(round(float(v))) for v in grid.pile_to_pixel(x, y))
    inst = obs.instance.copy()
    inst[r, c] = code
    return SimpleNamespace(**{**vars(obs), "instance": inst})


@pytest.mark.parametrize("where", ["beyond the opening's end", "beside the rectangle"])
def test_the_claws_footprint_blocks_an_obstacle_the_opening_alone_misses(where):
    from planner.constraints import polygon_raster

    from synth.geometry.grasp import RECT_WIDTH_M

    obs, grid = observation(3), OrthoGrid(32, 5.0)  # 0.16 m pixels
    pl = _fixed_planner(_peak_output([(16, 16, 0.9)]))
    opening = Constraints(claw_plate_m=0.0, claw_width_m=RECT_WIDTH_M)
    best = plan(obs, pl, constraints=opening).best
    g = best.grasp
    along, across = ((g.width_m / 2 + 0.25, 0.0) if where == "beyond the opening's end" else (0.0, 0.35))
    near = _with_obstacle_near(obs, g, grid, along, across)
    assert not (polygon_raster(grid, g.rectangle()).astype(bool) & (near.instance >= 1000)).any()
    assert plan(near, pl, constraints=opening).best == best  # the opening's rectangle misses it
    claws = Constraints(claw_plate_m=0.4, claw_width_m=0.9)
    p = plan(near, pl, constraints=claws)
    assert p.best != best and any(r["constraint"] == "obstacle" and r["action"] == "moved" for r in p.rejected)
    assert plan(near, pl, constraints=Constraints(claw_plate_m=0.4, claw_width_m=0.9, clear_obstacles=False)).best == best


def test_the_claws_footprint_is_the_grapples_by_default():
    from synth.physics.grapple import GrappleConfig

    c = Constraints()
    assert (c.claw_plate_m, c.claw_width_m) == (GrappleConfig().claw_thickness_m, GrappleConfig().claw_width_m)


def test_the_claws_footprint_is_checked():
    for bad in ({"claw_plate_m": -0.01}, {"claw_plate_m": float("nan")}, {"claw_width_m": 0.0}, {"claw_width_m": 2.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            Constraints(**bad)
