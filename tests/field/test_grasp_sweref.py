"""One grasp <-> SWEREF 99 TM conversion (field.geo.grasp_to_gnss / tm_to_grasp), used by the
field trial's command, GraspCommand.from_pile_grasp / to_pile_grasp and the controller twin.

``tests/data/grasp_sweref_golden.json`` holds what the conversions gave before they were made
one (20 random grasps on 4 georeferences, level, yawed and tilted): the field trial's command
fields (then built inline in field/trial.py from grasp_to_gnss), GraspCommand.from_pile_grasp
(then a two-point projection of its own), gnss_to_grasp, the controller twin's
command_to_grasp and GraspCommand.to_pile_grasp (then a two-point inverse of its own, up to
0.8 deg off on a tilted pile)."""

import ast
import json
import math
from dataclasses import asdict
from pathlib import Path

import pytest

from field import geo as G
from field.executor import command_to_grasp
from field.link.messages import GraspCommand
from synth.geometry.grasp import Grasp
from synth.scene.pile import Georeference

ROOT = Path(__file__).resolve().parents[2]
GOLDEN = json.loads((ROOT / "tests" / "data" / "grasp_sweref_golden.json").read_text())
GEOREFS = {k: Georeference(**{**v, "T_site_pile": tuple(map(tuple, v["T_site_pile"]))})
           for k, v in GOLDEN["georefs"].items()}
CASES = GOLDEN["cases"]
FIELDS = ("easting_mm", "northing_mm", "height_mm", "heading_cdeg", "opening_width_mm")


def case_id(c):
    return f"{c['georef']}-{c['grasp']}"


def grasp_of(c):
    x, y, phi, w, z = GOLDEN["grasps"][c["grasp"]]
    return Grasp(x, y, phi, w), z


def near(a, b, tol=1e-9):
    return all(abs(u - v) <= tol for u, v in zip(a, b))


def as_list(t):
    g, z = t
    return [g.x_m, g.y_m, g.phi_rad, g.width_m, z]


@pytest.mark.parametrize("c", CASES, ids=case_id)
def test_laptop_side_is_the_field_path_and_unchanged(c):
    g = GEOREFS[c["georef"]]
    grasp, z = grasp_of(c)
    geo = G.grasp_to_gnss(grasp, g, z)
    want = c["geo.grasp_to_gnss"]
    for k, v in geo.to_dict().items():
        assert v == pytest.approx(want[k], abs=1e-9) if isinstance(v, float) else v == want[k], k
    # what field.trial.prepare_trial sends (GraspCommand.from_grasp_geo of grasp_to_gnss) ...
    sent = {k: v for k, v in asdict(GraspCommand.from_grasp_geo(1, geo, 2, 0.0)).items() if k in FIELDS}
    assert sent == c["trial.command_fields"]
    # ... is what GraspCommand.from_pile_grasp gives, and what it gave before
    link = {k: v for k, v in asdict(GraspCommand.from_pile_grasp(1, grasp, z, g, 2, 0.0)).items() if k in FIELDS}
    assert link == sent == c["messages.from_pile_grasp"]


@pytest.mark.parametrize("c", CASES, ids=case_id)
def test_controller_side_uses_the_same_inverse(c):
    g = GEOREFS[c["georef"]]
    cmd = GraspCommand(command_id=1, target_log_count=2, plan_timestamp_ms=0, **c["trial.command_fields"])
    twin = as_list(command_to_grasp(cmd, g))
    assert near(twin, c["executor.command_to_grasp(trial cmd)"])  # the controller twin: unchanged
    assert near(as_list(cmd.to_pile_grasp(g)), twin)  # the laptop's inverse is now the same function
    assert near(as_list(G.tm_to_grasp(cmd.easting_mm / 1000, cmd.northing_mm / 1000, cmd.height_mm / 1000,
                                      cmd.heading_deg, cmd.opening_width_m, g)), twin)
    assert near(as_list(G.gnss_to_grasp(G.grasp_to_gnss(*grasp_of(c)[:1], g, grasp_of(c)[1]), g)),
                c["geo.gnss_to_grasp"])


@pytest.mark.parametrize("c", CASES, ids=case_id)
def test_round_trip_through_the_wire(c):
    g = GEOREFS[c["georef"]]
    grasp, z = grasp_of(c)
    back, z2 = GraspCommand.from_pile_grasp(1, grasp, z, g, 2, 0.0).to_pile_grasp(g)
    assert math.hypot(back.x_m - grasp.x_m, back.y_m - grasp.y_m) < 2e-3 and abs(z2 - z) < 2e-3
    d = (back.phi_rad - grasp.phi_rad + math.pi / 2) % math.pi - math.pi / 2
    assert abs(math.degrees(d)) < 0.02  # the wire's 0.01 deg heading resolution


#: a grasp conversion needs a heading: who may turn pile-frame angles into grid bearings and back
#: (points may be converted anywhere; grasps only through field.geo.grasp_to_gnss / tm_to_grasp)
CONVERSIONS = {"pile_angle_to_bearings", "grid_bearing_to_pile_angle"}
ALLOWED = {"synth/geometry/geodesy.py": "defines them", "field/geo.py": "the one grasp conversion"}


def test_no_other_grasp_sweref_conversion():
    bad = []
    for package in ("synth", "planner", "reconstruct", "field"):
        for f in sorted((ROOT / package).rglob("*.py")):
            rel = str(f.relative_to(ROOT))
            used = {n.attr if isinstance(n, ast.Attribute) else n.id
                    for n in ast.walk(ast.parse(f.read_text()))
                    if isinstance(n, (ast.Attribute, ast.Name))} & CONVERSIONS
            if used and rel not in ALLOWED:
                bad.append(f"{rel} uses {sorted(used)}")
    assert not bad, "convert grasps with field.geo.grasp_to_gnss / tm_to_grasp:\n" + "\n".join(bad)
