"""The field trial's planning objective: f3 on the product's balance source by default
(planner.inference.PRODUCT_F3_BALANCE), the other on request, and a record made before the hang
model replayed with what it used then."""

from __future__ import annotations

import pytest

from field.trial import TrialOptions
from field.trial_record import recorded_options
from planner.inference import HANG_SIGMA_B, PRODUCT_F3_BALANCE, SIGMA_B, f3_sigma_b
from tests.cli_helpers import GNSS, SCAN, cli, fails


def test_the_trial_scores_f3_on_the_products_balance_by_default():
    obj = TrialOptions().objective_spec()
    assert (obj.kind, obj.balance, obj.sigma_b) == ("f3", PRODUCT_F3_BALANCE, f3_sigma_b(PRODUCT_F3_BALANCE))
    hang = TrialOptions(f3_balance="hang").objective_spec()
    assert (hang.balance, hang.sigma_b) == ("hang", HANG_SIGMA_B)
    net = TrialOptions(f3_balance="network").objective_spec()
    assert (net.balance, net.sigma_b) == ("network", SIGMA_B)
    assert TrialOptions(f3_sigma_b=0.1).objective_spec().sigma_b == 0.1
    assert TrialOptions(objective="f1").objective_spec().kind == "f1"


@pytest.mark.parametrize("bad", [dict(f3_sigma_b=0.0), dict(f3_sigma_b=-0.05), dict(f3_balance="guess")])
def test_a_bad_f3_setting_is_refused_when_the_options_are_made(bad):
    with pytest.raises(ValueError, match="sigma_b|balance"):
        TrialOptions(**bad)


def test_a_record_from_before_the_hang_model_replays_with_the_b_map():
    old = {"objective": "f3", "verify_k": 8, "rerank": True}
    assert recorded_options(old).objective_spec().balance == "network"
    assert recorded_options({**old, "f3_balance": "hang"}).objective_spec().balance == "hang"
    assert recorded_options({"objective": "f3"}).verify_k == 0  # a 1.0 record: unverified


def test_a_record_replays_in_the_number_format_its_trial_ran_in():
    """The record's model says the format the network ran in ("auto" resolved): a replay runs in it, on
    any machine; a record from before int8 could be chosen ran in the float format "auto" meant then."""
    from planner.inference import default_device
    from planner.runtime import default_precision

    assert recorded_options({"objective": "f3", "precision": "auto"}, "int8").precision == "int8"
    assert recorded_options({"objective": "f3"}, "bf16").precision == "bf16"
    assert recorded_options({"objective": "f3"}).precision == default_precision(default_device())
    assert recorded_options({"objective": "f3", "precision": "fp32"}).precision == "fp32"
    with pytest.raises(ValueError, match="precision must be one of"):
        TrialOptions(precision="int4")


def test_the_trial_flags_reach_the_options(capsys, work, monkeypatch):
    import field.trial_record as trial_record

    seen = []

    def stop(scan, gnss, link, record, opts, **kw):
        seen.append(opts)
        raise KeyboardInterrupt

    monkeypatch.setattr(trial_record, "run_trial_record", stop)
    for extra in ([], ["--f3-balance", "hang"], ["--f3-balance", "network", "--f3-sigma-b", "0.2", "--precision", "fp32",
                                                 "--grasp-over-obstacles"]):
        cli(capsys, "trial", "--scan", SCAN, "--gnss", GNSS, "--link", "twin://", "--record",
            work / f"t{len(seen)}", "--yes", *extra)
    assert [(o.f3_balance, o.objective_spec().sigma_b) for o in seen] == [
        (PRODUCT_F3_BALANCE, f3_sigma_b(PRODUCT_F3_BALANCE)), ("hang", HANG_SIGMA_B), ("network", 0.2)]
    assert [o.precision for o in seen] == ["auto", "auto", "fp32"]
    assert [o.clear_obstacles for o in seen] == [True, True, False]
    fails(cli(capsys, "trial", "--scan", SCAN, "--gnss", GNSS, "--link", "twin://", "--record", work / "t9",
              "--f3-sigma-b", "0"), 2, "--f3-sigma-b 0")


def test_the_trial_plans_in_the_precision_its_options_name(tmp_path):
    import shutil

    from field.trial import TrialAborted, _load_trial_planner
    from planner.checkpoint import DEFAULT_MODEL
    from planner.runtime import int8_kernels_available

    bare = shutil.copy(DEFAULT_MODEL, tmp_path / "bare.safetensors")  # no int8 calibration beside it
    assert _load_trial_planner(TrialOptions(precision="fp32", rerank=False))[0].precision == "fp32"
    if int8_kernels_available():
        assert _load_trial_planner(TrialOptions(precision="int8", rerank=False))[0].precision == "int8"
    with pytest.raises(TrialAborted, match="planning failed: ") as info:
        _load_trial_planner(TrialOptions(precision="int8" if int8_kernels_available() else "bf16", rerank=False,
                                         model=str(bare) if int8_kernels_available() else str(tmp_path / "none")))
    assert info.value.kind == "input"


def test_the_trial_plans_clear_of_obstacles_unless_the_operator_allows_them():
    """The default clears the claws of the obstacles the re-render shows; a record from before it replays
    as it planned then, over them."""
    from types import SimpleNamespace

    from field.trial import _constraints_for

    assert _constraints_for(SimpleNamespace(), TrialOptions()).clear_obstacles
    assert not _constraints_for(SimpleNamespace(), TrialOptions(clear_obstacles=False)).clear_obstacles
    assert recorded_options({"objective": "f3"}).clear_obstacles is False
    assert recorded_options({"objective": "f3", "clear_obstacles": True}).clear_obstacles is True
    with pytest.raises(ValueError, match="clear_obstacles is a switch"):
        TrialOptions(clear_obstacles=1)


def test_the_trial_tests_the_claws_footprint_and_an_older_record_the_openings():
    from types import SimpleNamespace

    from field.trial import _constraints_for
    from planner.constraints import Constraints
    from synth.geometry.grasp import RECT_WIDTH_M

    c = _constraints_for(SimpleNamespace(), TrialOptions())
    assert (c.claw_plate_m, c.claw_width_m) == (Constraints().claw_plate_m, Constraints().claw_width_m) != (0.0, RECT_WIDTH_M)
    c = _constraints_for(SimpleNamespace(), TrialOptions(claw_plate_m=0.1, claw_width_m=0.3))
    assert (c.claw_plate_m, c.claw_width_m) == (0.1, 0.3)
    old = recorded_options({"objective": "f3", "clear_obstacles": True})
    assert (old.claw_plate_m, old.claw_width_m) == (0.0, RECT_WIDTH_M)
    assert recorded_options({"objective": "f3", "claw_plate_m": 0.05, "claw_width_m": 0.22}).claw_plate_m == 0.05
    with pytest.raises(ValueError, match="claw_plate_m"):
        TrialOptions(claw_plate_m=-1.0)
