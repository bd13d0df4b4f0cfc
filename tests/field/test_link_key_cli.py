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
