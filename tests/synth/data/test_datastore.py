"""The committed data-set store: build, resume from another clone, materialise, refuse mixtures."""

import gzip
import json
import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from synth.data.shards import DatasetFormatError, DatasetIntegrityError, iter_samples
from synth.data.dataset import DatasetJob, DatasetJobError, build_dataset
from synth.data.datastore import build_store, chunk_path, materialize, open_store, read_store

TINY = dict(n_logs=2, obstacles_fraction=0.0, seed=3, size_px=32, n_renders=2, max_trials_per_subset=3)


def _fake_factory(pile, targets):
    """Deterministic stand-in for run_trial: grasps narrower than 0.75 m succeed."""
    def simulate(g):
        ok = g.width_m < 0.75
        return SimpleNamespace(success=ok, cos_beta=0.9 if ok else float("nan"), grasped=tuple(targets) if ok else (),
                               outcome=SimpleNamespace(value="success" if ok else "collision"))
    return simulate


def _job(n=2, **kw):
    return DatasetJob(n_piles=n, **{**TINY, **kw})


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    d = tmp_path_factory.mktemp("store")
    build_store(d, _job(2), simulate_factory=_fake_factory)
    return d


@pytest.fixture
def clone(store, tmp_path):
    """A copy of the store, as another machine's clone of the repository holds it."""
    d = tmp_path / "clone"
    shutil.copytree(store, d)
    return d


def test_store_records_piles_subsets_and_trials(store):
    rec = read_store(store)
    assert rec["summary"]["chunks_done"] == 2 and rec["summary"]["complete"]
    job, chunks, _ = open_store(store)
    assert job == _job(2)
    d = json.loads(gzip.decompress(chunk_path(store, 0).read_bytes()))
    sub = d["piles"][0]["subsets"]
    assert [s["targets"] for s in sub] == [[0], [1], [0, 1]]
    assert all(len(s["trials"]) >= len(s["accepted"]) for s in sub)
    assert any(t["o"] == "success" for s in sub for t in s["trials"])


def test_materialized_samples_equal_the_direct_data_set(store, tmp_path):
    direct = tmp_path / "direct"
    build_dataset(direct, n_piles=2, workers=1, simulate_factory=_fake_factory, **TINY)
    a = sorted(iter_samples(direct), key=lambda s: (s.pile_id, s.subset, s.render))
    b = sorted(iter_samples(materialize(store, tmp_path / "cache")), key=lambda s: (s.pile_id, s.subset, s.render))
    assert len(a) == len(b) > 0
    for x, y in zip(a, b):
        assert (x.pile_id, x.subset, x.render) == (y.pile_id, y.subset, y.render)
        for name in ("intensity", "depth", "target_mask", "maps", "grasps"):
            np.testing.assert_array_equal(getattr(x, name), getattr(y, name), err_msg=name)


def test_resume_in_a_fresh_clone_simulates_only_missing_chunks(store, clone):
    calls = []

    def counting(pile, targets):
        calls.append(targets)
        return _fake_factory(pile, targets)

    build_store(clone, _job(3), simulate_factory=counting)  # one more pile: only chunk 2 is simulated
    assert len(calls) == 3 and read_store(clone)["summary"]["chunks_done"] == 3
    assert chunk_path(clone, 0).read_bytes() == chunk_path(store, 0).read_bytes()


def test_resume_with_other_parameters_is_refused(clone):
    with pytest.raises(DatasetJobError, match="seed"):
        build_store(clone, _job(2, seed=4), simulate_factory=_fake_factory)


def test_chunk_from_another_trial_revision_is_not_mixed_in(clone, tmp_path, monkeypatch):
    other = tmp_path / "other"
    import synth.physics.trial_spec

    monkeypatch.setattr(synth.physics.trial_spec, "TRIAL_REVISION", synth.physics.trial_spec.TRIAL_REVISION + 1)
    build_store(other, _job(3), simulate_factory=_fake_factory)
    monkeypatch.undo()
    shutil.copy(chunk_path(other, 2), chunk_path(clone, 2))
    with pytest.raises(DatasetFormatError, match="trial-code revision"):
        open_store(clone)


def test_chunk_that_disagrees_with_the_store_listing(clone):
    shutil.copy(chunk_path(clone, 1), chunk_path(clone, 0))
    with pytest.raises(DatasetIntegrityError, match="differs from its entry"):
        open_store(clone)


def test_truncated_chunk_is_a_clear_error(clone):
    p = chunk_path(clone, 1)
    p.write_bytes(p.read_bytes()[:40])
    rec = json.loads((clone / "store.json").read_text())
    rec["chunks"] = [c for c in rec["chunks"] if c["chunk"] != 1]
    (clone / "store.json").write_text(json.dumps(rec))
    with pytest.raises(DatasetFormatError, match="truncated or corrupt"):
        open_store(clone)


def test_missing_listed_chunk(clone):
    chunk_path(clone, 1).unlink()
    with pytest.raises(DatasetIntegrityError, match="missing"):
        open_store(clone)


def test_export_trains_on_a_machine_without_pybullet(store, tmp_path):
    """The export is what a lent GPU machine gets (torch, no pybullet): in a process where
    ``import pybullet`` fails, the planner lists it, streams it and trains a step on it."""
    import subprocess
    import sys
    import textwrap

    from synth.data.datastore import export_training

    out, size = export_training(store, tmp_path / "export")
    assert 0 < size < 2 ** 20 and (out / "manifest.json").exists()
    code = textwrap.dedent(f"""
        import sys
        sys.modules["pybullet"] = None  # any import of pybullet now raises ImportError
        from planner.data import DataConfig, list_shards
        from planner.model import UNetConfig
        from planner.train import TrainConfig, train
        shards, grid = list_shards({str(out)!r})
        assert len(shards) == 2 and grid["size_px"] == 32, (shards, grid)
        cfg = TrainConfig(model=UNetConfig.tiny(), epochs=1, batch_size=2, precision="fp32",
                          max_steps_per_epoch=1, max_val_batches=1,
                          data=DataConfig(val_fraction=0.0, shuffle_buffer=4))
        res = train({str(out)!r}, {str(tmp_path / "run")!r}, cfg)
        assert res.model_path.exists()
        assert "pybullet" not in [m for m in sys.modules if sys.modules[m] is not None]
        print("trained without pybullet")
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "trained without pybullet" in r.stdout, r.stderr[-2000:]


def test_export_over_the_device_budget_is_refused(store, tmp_path):
    from synth.data.datastore import export_training

    with pytest.raises(DatasetJobError, match="over the 0 MiB a device machine takes"):
        export_training(store, tmp_path / "export", max_bytes=1000)
    assert (tmp_path / "export" / "manifest.json").exists()  # the complete export stays


def test_materialized_samples_carry_each_subsets_candidate_count(store, tmp_path):
    """``Sample.n_candidates`` is the store's count for that subset (what --skip-no-candidates reads)."""
    want = {}
    for k in (0, 1):
        d = json.loads(gzip.decompress(chunk_path(store, k).read_bytes()))
        for p in d["piles"]:
            for s in p["subsets"]:
                want[(p["pile_id"], tuple(s["targets"]))] = s["candidates"]
    got = {(s.pile_id, tuple(s.subset)): s.n_candidates for s in iter_samples(materialize(store, tmp_path / "c"))}
    assert got == want and all(v is not None for v in got.values())


# -- piles of several sizes, a cap on the subsets simulated per pile ---------------------------------
def test_piles_cycle_over_the_log_range_and_the_subset_cap_samples_every_size():
    job = DatasetJob(n_piles=8, n_logs=2, max_logs=5, max_subsets=9, seed=4)
    assert [job.pile_logs(k) for k in range(8)] == [2, 3, 4, 5, 2, 3, 4, 5]
    for k in range(8):
        n = job.pile_logs(k)
        subsets = job.pile_subsets(k, n)
        assert subsets == job.pile_subsets(k, n)  # a pure function of (seed, k)
        assert len(subsets) == min(9, 2 ** n - 1) and len(set(subsets)) == len(subsets)
        assert [t for t in subsets if len(t) == 1] == [(i,) for i in range(n)]  # every single log
        assert {len(t) for t in subsets} == set(range(1, n + 1))  # and every size up to the whole pile
        assert subsets == sorted(subsets, key=lambda t: (len(t), t))
    assert job.pile_subsets(3, 5) != DatasetJob(n_piles=8, n_logs=2, max_logs=5, max_subsets=9, seed=5).pile_subsets(3, 5)
    with pytest.raises(ValueError, match="max_logs"):
        DatasetJob(n_piles=1, n_logs=4, max_logs=3)
    with pytest.raises(ValueError, match="max_subsets"):
        DatasetJob(n_piles=1, max_subsets=0)


def test_a_store_of_mixed_pile_sizes_records_each_piles_chosen_subsets(tmp_path):
    job = _job(3, n_logs=2, max_logs=4, max_subsets=5)
    build_store(tmp_path / "s", job, simulate_factory=_fake_factory)
    for k in range(3):
        pile = json.loads(gzip.decompress(chunk_path(tmp_path / "s", k).read_bytes()))["piles"][0]
        n = len(pile["pile"]["logs"])
        assert n == job.pile_logs(k) == 2 + k
        assert [tuple(s["targets"]) for s in pile["subsets"]] == job.pile_subsets(k, n)
    samples = list(iter_samples(materialize(tmp_path / "s", tmp_path / "cache")))  # what training reads
    want = {(f"pile_{k:05d}", t) for k in range(3) for t in job.pile_subsets(k, job.pile_logs(k))}
    assert {(x.pile_id, x.subset) for x in samples} == want and len(samples) == len(want) * TINY["n_renders"]
    assert {x.n_logs for x in samples} == {2, 3, 4}


def test_the_new_job_fields_leave_older_stores_parameters_as_they_were():
    """A job at the defaults records no max_logs / max_subsets, so the committed store (made before
    they existed) still resumes: its parameter hash is the default job's."""
    from pathlib import Path

    from synth.data.datastore import params_sha256

    store = json.loads((Path(__file__).resolve().parents[3] / "data" / "paper-v4" / "store.json").read_text())
    job = DatasetJob(n_piles=604, n_logs=4, obstacles_fraction=0.33, seed=0)
    assert "max_logs" not in job.params() and "max_subsets" not in job.params()
    assert params_sha256(job.params()) == store["params_sha256"]
    assert "max_logs" in _job(1, n_logs=2, max_logs=3).params()
