"""``loggrasp link-key``: --help, and a real run (a new 0600 key, never overwritten, never shown)."""

from __future__ import annotations

import os

from typer.testing import CliRunner

from field.cli import app


def test_link_key_help():
    res = CliRunner().invoke(app, ["link-key", "--help"])
    assert res.exit_code == 0 and "secoc_key" in res.output


def test_link_key_writes_a_private_key_once(tmp_path):
    path = tmp_path / "keys" / "crane1.key"
    res = CliRunner().invoke(app, ["link-key", str(path)])
    assert res.exit_code == 0, res.output
    assert os.stat(path).st_mode & 0o777 == 0o600
    assert path.read_text().strip() not in res.output  # the key is never printed
    again = CliRunner().invoke(app, ["link-key", str(path)])
    assert again.exit_code != 0 and "never overwritten" in again.output
