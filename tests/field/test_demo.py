"""field.demo: the demo's wiring as library functions (the CLI only prints and maps errors)."""

from __future__ import annotations

from field.demo import DEMO_DATA, demo_options, prepare_demo


def test_prepare_demo_makes_key_and_limits_and_replaces_the_old_record(tmp_path):
    old = tmp_path / "trial"
    old.mkdir()
    (old / "record.json").write_text("{}")
    setup = prepare_demo(tmp_path, "can://virtual/x")
    assert not old.exists() and setup.record_dir == old
    sign = setup.signing_key_path
    keys = f"secoc_key={setup.key_path}&crane_key={sign}.pub&signing_key={sign}"
    assert setup.key_path.is_file() and sign.is_file() and setup.link_url == f"can://virtual/x?{keys}"
    assert prepare_demo(tmp_path, "can://virtual/x?a=1").link_url.endswith(f"?a=1&{keys}")
    assert setup.max_pile_age_s > setup.scan_age_s > 0  # the bundled scan is old: the limit is raised past it
    key = setup.key_path.read_bytes()
    assert prepare_demo(tmp_path, "can://virtual/x").key_path.read_bytes() == key  # made once, kept
    assert demo_options(setup, None).verify_k > 0 and demo_options(setup, None, verify=False).verify_k == 0
    assert (DEMO_DATA / "truth" / "pile.json").is_file()
