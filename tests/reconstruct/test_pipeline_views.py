"""The pipeline hands the joint end model the scan's pairs (reconstruct.fitting.joint_view; what
JointConfig.view_test, off by default, reads): in the pile frame, each looking at the pile. The demo scan,
reconstructed with the joint estimator, the view test on and off."""

from __future__ import annotations

import numpy as np

import reconstruct.pipeline as pipeline
from reconstruct.config import ReconstructConfig
from reconstruct.fitting.joint_config import JointConfig
from tests.cli_helpers import GNSS, SCAN


def test_the_joint_end_placer_gets_the_pairs_in_the_pile_frame(tmp_path, monkeypatch):
    got = []

    class Spy(pipeline.JointEndPlacer):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            got.append(self.views)

    monkeypatch.setattr(pipeline, "JointEndPlacer", Spy)
    res = pipeline.reconstruct(SCAN, GNSS, tmp_path / "j",
                               ReconstructConfig(estimator="joint", joint=JointConfig(view_test=True)))
    assert len(got) == 1 and got[0]
    middle = np.array([[log.centre_m[0], log.centre_m[1], log.centre_m[2]] for log in res.pile.logs])
    assert all(v.sees(middle, 0.0).any() for v in got[0])  # each pair looks at the pile's logs


def test_without_the_view_test_the_pairs_are_not_read(tmp_path, monkeypatch):
    monkeypatch.setattr(pipeline, "scan_views", lambda *a, **k: (_ for _ in ()).throw(AssertionError("read")))
    pipeline.reconstruct(SCAN, GNSS, tmp_path / "j", ReconstructConfig(estimator="joint"))
