"""Case studies: the four figures, their records and README from a tiny untrained network on tiny piles."""

import json

import numpy as np
import pytest

from experiments.case_studies import (
    CaseStudyConfig, CaseStudyError, place_obstacle_near, read_results, run_case_studies, spread_logs,
)
from planner.inference import Planner
from planner.model import UNetConfig, build_unet
from synth.scene.generate import GenerationConfig, generate_pile
from synth.geometry.grasp import Grasp

OUTCOMES = {"success", "more_than_intended", "fewer_or_other", "collision", "not_closed", "dropped"}


@pytest.fixture(scope="module")
def tiny_planner():
    import torch

    torch.manual_seed(0)
    cfg = UNetConfig.tiny()
    return Planner(build_unet(cfg), cfg, precision="fp32")


def test_all_case_studies_write_pictures_records_and_readme(tmp_path, tiny_planner):
    import cv2

    cfg = CaseStudyConfig.tiny()
    model = {"path": "tiny.safetensors", "sha256": "ab" * 32}
    res = run_case_studies(tiny_planner, tmp_path, cfg, model=model, command="pytest")
    for name in ("ranking", "obstacle", "packed", "logs"):
        img = cv2.imread(str(tmp_path / f"{name}.png"))
        assert img is not None and img.shape[0] > 64 and img.shape[1] > 64, name
    recs = res["records"]
    assert {r["outcome"] for r in recs} <= OUTCOMES
    # ranking: every subset of the 2-log pile once per objective, best q first
    for obj in ("f1", "f3"):
        ranked = [r for r in recs if r["case"] == "ranking" and r["objective"] == obj]
        assert sorted(tuple(r["targets"]) for r in ranked) == [(0,), (0, 1), (1,)]
        assert [r["q"] for r in ranked] == sorted((r["q"] for r in ranked), reverse=True)
    # obstacle: without, with, first grasp retried with it; the obstacle scene differs
    ob = [r for r in recs if r["case"] == "obstacle"]
    assert [r["panel"] for r in ob] == ["without", "with rock", "first grasp, with rock"]
    assert ob[0]["grasp"] == ob[2]["grasp"]
    # packed: the packed pile and its spread version, free choice and one log each
    assert len([r for r in recs if r["case"] == "packed"]) == 4
    assert len([r for r in recs if r["case"] == "logs"]) == 2
    # versioned record read back; README names command, model hash and every trial
    back = read_results(tmp_path)
    assert back["records"] == json.loads(json.dumps(recs)) and back["model"]["sha256"] == "ab" * 32
    readme = (tmp_path / "README.md").read_text()
    assert "`pytest`" in readme and "ab" * 32 in readme
    assert sum(line.startswith("| f1 #") for line in readme.splitlines()) == 3


def test_newer_results_version_is_refused(tmp_path):
    (tmp_path / "results.json").write_text(json.dumps({"format": "loggrasp.case-studies", "format_version": "2.0"}))
    with pytest.raises(CaseStudyError, match="not supported"):
        read_results(tmp_path)
    with pytest.raises(CaseStudyError, match="cannot read"):
        read_results(tmp_path / "none.json")


def test_obstacle_lands_by_the_claw_without_touching_logs_and_gaps_open():
    pile, _ = generate_pile(5, GenerationConfig(n_logs=2))
    c = np.mean([log.centre_m for log in pile.logs], axis=0)
    g = Grasp(float(c[0]), float(c[1]), 0.3, 1.0)
    edited, (x, y) = place_obstacle_near(pile, g, "rock")
    assert len(edited.rocks) == len(pile.rocks) + 1 and edited.logs == pile.logs
    claws = [np.array([g.x_m, g.y_m]) + s * g.closing_axis() * g.width_m / 2 for s in (1, -1)]
    assert min(np.linalg.norm(np.array([x, y]) - p) for p in claws) < 1.5

    packed, _ = generate_pile(7, GenerationConfig(n_logs=2, packed=True))
    spread = spread_logs(packed, 0.15)
    gap = lambda p: np.linalg.norm(np.subtract(p.logs[0].centre_m[:2], p.logs[1].centre_m[:2]))  # noqa: E731
    assert gap(spread) > gap(packed) + 0.08


def test_bad_config():
    with pytest.raises(ValueError, match="obstacle_kinds"):
        CaseStudyConfig(obstacle_kinds=("boulder",))
    with pytest.raises(ValueError, match="ranking_logs"):
        CaseStudyConfig(ranking_logs=9)
    with pytest.raises(ValueError, match="unknown case"):
        run_case_studies(None, "/nonexistent-not-written", cases=("ranking", "mystery"))
