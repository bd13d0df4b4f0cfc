"""Resuming a data-set job re-checks every finished shard's checksum: a shard corrupted on disk
(same size, other bytes: bit rot, a bad copy) is redone, not kept."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from synth.data.shards import DatasetIntegrityError, iter_samples, read_manifest, verify_dataset
from synth.data.dataset import build_dataset

TINY = dict(n_logs=2, obstacles_fraction=0.0, seed=3, size_px=32, n_renders=2, max_trials_per_subset=3)


def _factory(calls: list):
    """A stand-in for run_trial that records which subsets it simulates: narrow grasps succeed."""
    def make(pile, targets):
        calls.append(tuple(targets))

        def simulate(g):
            ok = g.width_m < 0.75
            return SimpleNamespace(success=ok, cos_beta=0.9 if ok else float("nan"),
                                   outcome=SimpleNamespace(value="success" if ok else "collision"))
        return simulate
    return make


def test_resume_redoes_a_finished_shard_whose_bytes_changed(tmp_path):
    first: list = []
    man = build_dataset(tmp_path, n_piles=2, workers=1, simulate_factory=_factory(first), **TINY)
    assert man.summary["complete"] and len(man.shards) == 2 and len(first) == 2 * 3
    kept, hit = (tmp_path / s.file for s in man.shards)
    kept_bytes, good = kept.read_bytes(), hit.read_bytes()
    bad = bytearray(good)
    bad[len(bad) // 2] ^= 0xFF  # same size: only the checksum can tell
    hit.write_bytes(bytes(bad))
    with pytest.raises(DatasetIntegrityError, match="sha256"):
        verify_dataset(tmp_path)

    again: list = []
    man2 = build_dataset(tmp_path, n_piles=2, workers=1, simulate_factory=_factory(again), **TINY)
    assert len(again) == 3, f"resume should redo the corrupted chunk (3 subsets), simulated {len(again)}"
    assert man2.summary["complete"] and len(man2.shards) == 2
    verify_dataset(tmp_path)  # every listed shard matches its checksum again
    assert kept.read_bytes() == kept_bytes  # the intact shard was kept as it was
    redone = tmp_path / next(s.file for s in read_manifest(tmp_path).shards if s.chunk == 1)
    assert redone.read_bytes() != bytes(bad)
    assert len(list(iter_samples(tmp_path))) == 2 * 3 * 2

