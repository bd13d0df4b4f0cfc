"""``loggrasp link-key``: --help, and a real run (a new 0600 key, never overwritten, never shown)."""

from __future__ import annotations

import os

import pytest
from typer.testing import CliRunner

from field.cli import app


def test_link_key_help():
    res = CliRunner().invoke(app, ["link-key", "--help"])
    assert res.exit_code == 0 and "secoc_key" in res.output


@pytest.mark.safety_case(keys="loggrasp link-key", link="both",
                         reaction="a new 32-byte key, mode 0600, never overwritten, never printed")
def test_link_key_writes_a_private_key_once(tmp_path, capsys):
    from field.cli import run
    from synth.common.cli import EXIT_INPUT

    path = tmp_path / "keys" / "crane1.key"
    code = run(["link-key", str(path)])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert os.stat(path).st_mode & 0o777 == 0o600
    assert path.read_text().strip() not in out + err  # the key is never printed
    again = run(["link-key", str(path)])  # errors are printed once, by field.cli.run
    out, err = capsys.readouterr()
    assert again == EXIT_INPUT and err.startswith("error: ") and "never overwritten" in err


def test_link_key_help_names_the_crane_signing_key_and_rotation():
    res = CliRunner().invoke(app, ["link-key", "--help"])
    assert res.exit_code == 0 and "--crane-signing" in res.output and "--add" in res.output


@pytest.mark.safety_case(keys="loggrasp link-key --crane-signing", link="both",
                         reaction="the crane's Ed25519 signing key (mode 0600, never overwritten, never printed) and "
                                  "its public key for laptops; the public key cannot sign")
def test_link_key_writes_the_crane_signing_pair_once(tmp_path, capsys):
    from field.cli import run
    from field.link.signing import load_public_key, load_signing_key
    from synth.common.cli import EXIT_INPUT

    sign = tmp_path / "crane1.sign"
    assert run(["link-key", "--crane-signing", str(sign)]) == 0
    out, err = capsys.readouterr()
    assert os.stat(sign).st_mode & 0o777 == 0o600 and sign.read_text() not in out + err
    load_signing_key(sign), load_public_key(tmp_path / "crane1.sign.pub")
    assert run(["link-key", "--crane-signing", str(sign)]) == EXIT_INPUT
    assert "never overwritten" in capsys.readouterr().err


def test_link_key_add_makes_a_second_key_line_for_rotation(tmp_path, capsys):
    from field.cli import run
    from field.link.secoc import load_keys

    path = tmp_path / "crane1.key"
    assert run(["link-key", str(path)]) == 0
    sending, before = load_keys(path)
    assert run(["link-key", str(path), "--add"]) == 0
    out, err = capsys.readouterr()
    sending_after, after = load_keys(path)
    assert sending_after == sending and after[sending] == before[sending]  # the sending key stays first
    assert sorted(after) == [0, 1] and os.stat(path).st_mode & 0o777 == 0o600
    assert after[1].hex() not in out + err


def _trial_args(tmp_path, url: str) -> list[str]:
    return ["trial", "--scan", str(tmp_path / "scan"), "--gnss", str(tmp_path / "g.csv"), "--link", url,
            "--record", str(tmp_path / "rec")]


@pytest.mark.safety_case(keys="a laptop link needs the crane's public key", link="both",
                         reaction="trial refuses a link with a SecOC key but no crane_key= (exit 3) unless "
                                  "--insecure-link; a wrong key file is a one-line error naming it (exit 2)")
def test_trial_refuses_a_link_without_the_crane_public_key_and_names_a_bad_key(tmp_path, capsys):
    from field.cli import run
    from field.link.secoc import generate_key_file
    from field.link.signing import generate_signing_key
    from synth.common.cli import EXIT_INPUT, EXIT_LINK

    key = generate_key_file(tmp_path / "k")
    sign, pub = generate_signing_key(tmp_path / "c.sign")
    base = f"can://virtual/x?secoc_key={key}"
    assert run(_trial_args(tmp_path, base)) == EXIT_LINK
    err = capsys.readouterr().err
    assert "no crane_key=CRANE.pub" in err and "--insecure-link" in err and len(err.strip().splitlines()) == 1
    cases = {f"{base}&crane_key={sign}": "PRIVATE signing key",  # the private key where the public one goes
             f"{base}&crane_key={tmp_path / 'missing.pub'}": "cannot be read",
             f"{base}&crane_key={key}": "not a PEM public key",
             f"{base}&crane_key={pub}&signing_key={sign}": "belongs on the crane only"}
    for url, why in cases.items():
        assert run(_trial_args(tmp_path, url)) == EXIT_INPUT, url
        err = capsys.readouterr().err
        assert why in err and "--link" in err and len(err.strip().splitlines()) == 1, err
    os.chmod(key, 0o644)
    assert run(_trial_args(tmp_path, f"{base}&crane_key={pub}")) == EXIT_INPUT
    err = capsys.readouterr().err
    assert "chmod 600" in err and "secoc_key=" in err


def test_crane_sim_needs_its_signing_key_and_refuses_a_public_one(tmp_path, capsys):
    from field.cli import run
    from field.link.secoc import generate_key_file
    from field.link.signing import generate_signing_key
    from synth.common.cli import EXIT_INPUT, EXIT_LINK

    key = generate_key_file(tmp_path / "k")
    _, pub = generate_signing_key(tmp_path / "c.sign")
    sim = ["crane-sim", "--pile", str(tmp_path / "pile.json"), "--no-journal", "--link"]
    assert run([*sim, f"can://virtual/x?secoc_key={key}"]) == EXIT_LINK
    assert "no signing_key=CRANE" in capsys.readouterr().err
    assert run([*sim, f"can://virtual/x?secoc_key={key}&signing_key={pub}"]) == EXIT_INPUT
    assert "is a public key" in capsys.readouterr().err
