"""RH 2000 heights without the SWEN17_RH2000 geoid grid are refused, on every machine.

The refusal is exercised in a fresh interpreter whose PROJ sees no grid whatever this machine has
installed: its data folder holds only ``proj.db``, its user folder (where ``projsync`` puts
grids, searched first) is empty, and network access is off. The same set-up with a stand-in grid
in the user folder computes heights, so it is the missing grid, not a broken PROJ, that refuses.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from geoid_stand_in import write_stand_in_geoid

REPO = Path(__file__).resolve().parents[3]

_PROBE = r"""
import json, sys
import pyproj.datadir, pyproj.network
pyproj.datadir.set_data_dir(sys.argv[1])
pyproj.network.set_network_enabled(False)
from synth.geometry import geodesy as G
from synth.scene.pile import Georeference
out = {"available": G.rh2000_available(), "user_dir": pyproj.datadir.get_user_data_dir()}
for name, call in (("height", lambda: float(G.ellipsoidal_to_rh2000(64.1, 20.0, 250.0))),
                   ("pile", lambda: float(G.pile_to_sweref_tm(Georeference(64.1, 20.0, 250.0), [0.0, 0.0, 0.0],
                                                              height="rh2000")[2]))):
    try:
        out[name] = call()
    except G.GridUnavailableError as exc:
        out[name + "_error"] = str(exc)
print(json.dumps(out))
"""


def _probe(tmp_path: Path, grid: bool) -> dict:
    import pyproj.datadir

    data = tmp_path / "proj-data"
    data.mkdir()
    (data / "proj.db").symlink_to(Path(pyproj.datadir.get_data_dir()) / "proj.db")
    user = tmp_path / "proj-user"
    user.mkdir()
    if grid:
        write_stand_in_geoid(user)
    env = {k: v for k, v in os.environ.items() if k not in ("PROJ_DATA", "PROJ_LIB", "PROJ_NETWORK")}
    env.update(PROJ_USER_WRITABLE_DIRECTORY=str(user), PROJ_NETWORK="OFF",
               PYTHONPATH=os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, "-c", _PROBE, str(data)], capture_output=True, text=True, env=env,
                       cwd=REPO, timeout=120)
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert Path(out["user_dir"]) == user  # PROJ looked where this test put (or did not put) the grid
    return out


def test_rh2000_is_refused_without_the_geoid_grid(tmp_path):
    out = _probe(tmp_path, grid=False)
    assert "height" not in out, f"an RH 2000 height without the geoid grid: {out['height']} m"
    assert "SWEN17_RH2000" in out["height_error"] and "ellipsoidal" in out["height_error"]
    assert "pile" not in out and "SWEN17_RH2000" in out["pile_error"]
    assert out["available"] is False


def test_the_same_set_up_with_a_grid_computes_heights(tmp_path):
    out = _probe(tmp_path, grid=True)
    assert out["available"] is True, out
    assert out["height"] == pytest.approx(250.0 - 30.0, abs=1e-6)  # the stand-in's constant geoid
    assert out["pile"] == pytest.approx(250.0 - 30.0, abs=1e-3)
