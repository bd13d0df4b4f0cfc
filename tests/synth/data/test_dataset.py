import errno
import json

import numpy as np
import pytest

import synth.data.shards as shards
from synth.data.shards import (DatasetFormatError, DatasetIntegrityError, Manifest, Sample, ShardWriter, iter_samples,
                               load_shard, read_manifest, write_manifest)
from synth.geometry.frames import OrthoGrid
from synth.geometry.grasp import Grasp
from synth.data.maps import encode_grasps

GRID = OrthoGrid(32, 5.0)


def _samples(pile_id="pile_00000", n_renders=2):
    rng = np.random.default_rng(0)
    depth = rng.uniform(4.5, 5.0, (32, 32)).astype(np.float32)
    renders = [rng.uniform(0, 1, (32, 32)).astype(np.float32) for _ in range(n_renders)]
    out = []
    for subset, grasps in (((0,), [(Grasp(0.1, 0.2, 0.3, 0.5), 0.97)]), ((0, 1), []),
                           ((1,), [(Grasp(-0.5, 0.0, 1.0, 0.4), 0.9), (Grasp(0.5, 0.5, -1.0, 1.5), 0.8)])):
        maps = encode_grasps(GRID, [g for g, _ in grasps], [b for _, b in grasps])
        arr = np.array([[g.x_m, g.y_m, g.phi_rad, g.width_m, b] for g, b in grasps]).reshape(-1, 5)
        mask = np.zeros((32, 32), bool)
        mask[3 * subset[0]: 3 * subset[0] + 4] = True
        for r in range(n_renders):
            out.append(Sample(pile_id=pile_id, render=r, subset=subset, intensity=renders[r], depth=depth,
                              target_mask=mask, maps=maps, grasps=arr, negative=not grasps, n_logs=2))
    return out


def _write(tmp_path, chunks=(0,)):
    infos = []
    for c in chunks:
        w = ShardWriter(tmp_path, "w0", c)
        for s in _samples(f"pile_{c:05d}"):
            w.add(s)
        infos.append(w.close({"trials": 3}))
    man = Manifest(params={"seed": 1}, grid={"size_px": 32, "extent_m": 5.0, "camera_height_m": 5.0},
                   shards=infos, summary={"samples": sum(i.n_samples for i in infos)})
    write_manifest(tmp_path, man)
    return infos


def test_round_trip_shares_depth_and_maps_across_renders(tmp_path):
    infos = _write(tmp_path, chunks=(0, 1))
    assert infos[0].n_samples == 6 and infos[0].n_subsets == 3 and infos[0].n_grasps == 3
    assert (tmp_path / "shard_w0_00000.npz").exists() and (tmp_path / "shard_w0_00000.done.json").exists()
    got = list(iter_samples(tmp_path))
    want = _samples("pile_00000") + _samples("pile_00001")
    assert len(got) == len(want) == 12
    for a, b in zip(got, want):
        assert (a.pile_id, a.render, a.subset, a.negative, a.tau, a.n_logs) == (b.pile_id, b.render, b.subset, b.negative, b.tau, b.n_logs)
        for k in ("intensity", "depth", "target_mask", "maps", "grasps"):
            np.testing.assert_array_equal(getattr(a, k), getattr(b, k))
        assert a.intensity.dtype == np.float32 and a.target_mask.dtype == bool and a.maps.shape == (5, 32, 32)
    assert got[0].grasp_list()[0][0] == Grasp(0.1, 0.2, 0.3, 0.5)
    man = read_manifest(tmp_path)
    assert man.n_samples == 12 and man.shards[1].stats == {"trials": 3}


def test_missing_corrupted_and_mismatched_shards(tmp_path):
    _write(tmp_path, chunks=(0, 1))
    shard = tmp_path / "shard_w0_00001.npz"
    data = shard.read_bytes()
    shard.write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetIntegrityError, match="bytes"):
        list(iter_samples(tmp_path))
    with pytest.raises(DatasetFormatError, match="corrupted"):
        load_shard(shard)
    # same size, one byte flipped: caught by the checksum
    flipped = bytearray(data)
    flipped[len(data) // 2] ^= 0xFF
    shard.write_bytes(bytes(flipped))
    with pytest.raises(DatasetIntegrityError, match="sha256"):
        list(iter_samples(tmp_path))
    shard.unlink()
    with pytest.raises(DatasetIntegrityError, match="missing"):
        list(iter_samples(tmp_path))
    with pytest.raises(DatasetFormatError, match="does not exist"):
        load_shard(shard)


def test_manifest_errors(tmp_path):
    with pytest.raises(DatasetFormatError, match="missing"):
        read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps({"format": "loggrasp.grasp_dataset", "format_version": "2.0"}))
    with pytest.raises(DatasetFormatError, match="not supported"):
        read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_text("{not json")
    with pytest.raises(DatasetFormatError):
        read_manifest(tmp_path)


def test_full_disk_leaves_no_shard(tmp_path, monkeypatch):
    w = ShardWriter(tmp_path, "w0", 7)
    for s in _samples():
        w.add(s)

    def full(path, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(shards, "write_atomic", full)
    with pytest.raises(OSError):
        w.close()
    assert not list(tmp_path.glob("shard_*"))


@pytest.mark.parametrize("change", [
    {"negative": True},  # has grasps but flagged negative
    {"subset": (1, 0)},
    {"subset": (5,)},
    {"grasps": np.array([[0, 0, 0, 2.0, 1.0]])},
    {"grasps": np.array([[np.nan, 0, 0, 0.5, 1.0]])},
    {"maps": np.zeros((4, 32, 32), np.float32)},
    {"intensity": np.full((32, 32), 2.0, np.float32)},
    {"instance": np.zeros((16, 32), np.int16)},
])
def test_malformed_samples_are_refused(tmp_path, change):
    s = _samples()[0]
    for k, v in change.items():
        setattr(s, k, v)
    with pytest.raises(ValueError):
        ShardWriter(tmp_path, "w0", 0).add(s)


def test_bad_worker_label():
    with pytest.raises(ValueError, match="worker label"):
        ShardWriter("/tmp", "a/b", 0)


# ---------------------------------------------------------------------------------------------
# the data-set job
# ---------------------------------------------------------------------------------------------
from types import SimpleNamespace  # noqa: E402

from synth.data.dataset import DatasetJobError, build_dataset  # noqa: E402
from synth.data.shards import verify_dataset  # noqa: E402

TINY = dict(n_logs=2, obstacles_fraction=0.0, seed=3, size_px=32, n_renders=2, max_trials_per_subset=3)


def _fake_factory(pile, targets):
    """A deterministic stand-in for run_trial: grasps narrower than 0.75 m succeed."""
    def simulate(g):
        ok = g.width_m < 0.75
        return SimpleNamespace(success=ok, cos_beta=0.9 if ok else float("nan"),
                               outcome=SimpleNamespace(value="success" if ok else "collision"))
    return simulate


def _digest(path):
    return {p.name: p.read_bytes() for p in sorted(path.glob("shard_*"))}


def test_job_writes_consistent_samples(tmp_path):
    seen = []
    man = build_dataset(tmp_path, n_piles=2, workers=1, progress=seen.append, simulate_factory=_fake_factory, **TINY)
    assert [p.chunks_done for p in seen] == [1, 2] and seen[-1].trials == man.summary["trials"] > 0
    s = man.summary
    assert s["complete"] and s["piles"] == 2 and s["subsets"] == 6 and s["samples"] == 12
    assert s["samples"] == man.n_samples and s["grasps"] > 0
    assert man.grid == {"size_px": 32, "extent_m": 5.0, "camera_height_m": 5.0}
    assert 0 <= s["no_candidate_subsets"] <= s["negatives"]
    assert 0 <= s["negative_fraction"] <= 1 and s["outcomes"].get("success", 0) > 0
    samples = list(iter_samples(tmp_path))
    assert len(samples) == 12
    assert {x.subset for x in samples} == {(0,), (1,), (0, 1)} and {x.render for x in samples} == {0, 1}
    for x in samples:
        assert x.target_mask.any() and x.maps.shape == (5, 32, 32)
        want = encode_grasps(GRID, [g for g, _ in x.grasp_list()], [b for _, b in x.grasp_list()])
        np.testing.assert_array_equal(x.maps, want)
        assert all(g.width_m < 0.75 + 0.10 for g, _ in x.grasp_list())
        assert x.negative == (len(x.grasps) == 0)
    # both renders of a scene share depth and maps but differ in intensity
    a, b = [x for x in samples if x.pile_id == "pile_00000" and x.subset == (0,)]
    assert np.shares_memory(a.depth, b.depth) and np.shares_memory(a.maps, b.maps)
    assert not np.array_equal(a.intensity, b.intensity)
    assert (tmp_path / "piles" / "pile_00000.json").exists()
    # every sample carries its pile's instance map, and the target mask is made from it
    for x in samples:
        assert x.instance is not None and x.instance.dtype == np.int16
        np.testing.assert_array_equal(x.target_mask, np.isin(x.instance, [t + 1 for t in x.subset]))


def test_instance_maps_round_trip_once_per_pile(tmp_path):
    inst = np.zeros((32, 32), np.int16)
    inst[:4], inst[4:8], inst[20:24, 20:24] = 1, 2, 1000
    w = ShardWriter(tmp_path, "w0", 0)
    for s in _samples():
        s.instance = inst
        w.add(s)
    w.close()
    got = load_shard(tmp_path / "shard_w0_00000.npz")
    assert len(got) == 6 and all(np.array_equal(x.instance, inst) for x in got)
    assert np.shares_memory(got[0].instance, got[-1].instance)  # stored once for the pile
    assert all(x.instance is None for x in _samples())
    _write(tmp_path / "old")  # a shard written without them reads back without them
    assert all(x.instance is None for x in iter_samples(tmp_path / "old"))


def test_a_shard_refuses_piles_with_and_without_instance_maps(tmp_path):
    w = ShardWriter(tmp_path, "w0", 0)
    first = _samples("pile_00000")[0]
    first.instance = np.zeros((32, 32), np.int16)
    w.add(first)
    with pytest.raises(ValueError, match="instance map"):
        w.add(_samples("pile_00001")[0])


def test_job_with_real_trials_in_process(tmp_path):
    man = build_dataset(tmp_path, n_piles=1, workers=1, **{**TINY, "max_trials_per_subset": 1})
    assert man.summary["trials"] in (1, 2, 3) and sum(man.summary["outcomes"].values()) == man.summary["trials"]
    assert man.params["trial_preset"] == "fast" and "physics" in man.params["trial_config_values"]
    verify_dataset(tmp_path)


def test_resume_keeps_finished_shards_and_redoes_partial_ones(tmp_path):
    build_dataset(tmp_path, n_piles=2, workers=1, simulate_factory=_fake_factory, **TINY)
    before = _digest(tmp_path)
    first, second = sorted(tmp_path.glob("shard_*.done.json"))
    # a kill after the shard was renamed but before its done record: the shard is partial
    second.unlink()
    (tmp_path / ".shard_p1_00005.npz.abc.tmp").write_bytes(b"half")  # a kill mid-write
    (tmp_path / "piles" / ".pile_00001.json.abc.tmp").write_bytes(b"half")
    stray = tmp_path / "shard_p99_00007.npz"
    stray.write_bytes(b"partial")
    calls = []

    def counting(pile, targets):
        calls.append(tuple(targets))
        return _fake_factory(pile, targets)

    man = build_dataset(tmp_path, n_piles=3, workers=1, simulate_factory=counting, **TINY)
    assert len(calls) == 2 * 3  # chunks 1 and 2 redone, chunk 0 kept
    assert man.summary["complete"] and man.summary["piles"] == 3
    after = _digest(tmp_path)
    assert after[first.name] == before[first.name]
    assert after[first.name.replace(".done.json", ".npz")] == before[first.name.replace(".done.json", ".npz")]
    assert not stray.exists() and not list(tmp_path.glob(".shard_*")) and not list(tmp_path.glob("piles/.*"))
    verify_dataset(tmp_path)
    assert len(list(iter_samples(tmp_path))) == 3 * 3 * 2


def test_resume_with_other_parameters_is_refused(tmp_path):
    build_dataset(tmp_path, n_piles=1, workers=1, simulate_factory=_fake_factory, **TINY)
    with pytest.raises(DatasetJobError, match="other parameters.*seed"):
        build_dataset(tmp_path, n_piles=1, workers=1, simulate_factory=_fake_factory, **{**TINY, "seed": 4})


def test_full_disk_keeps_the_manifest_consistent(tmp_path, monkeypatch):
    real = shards.write_atomic

    def fill_after_first_shard(path, data):
        if path.name.endswith(".npz") and list(tmp_path.glob("shard_*.npz")):
            raise OSError(errno.ENOSPC, "No space left on device")
        real(path, data)

    monkeypatch.setattr(shards, "write_atomic", fill_after_first_shard)
    with pytest.raises(DatasetJobError, match="No space left.*1 of 2 chunks"):
        build_dataset(tmp_path, n_piles=2, workers=1, simulate_factory=_fake_factory, **TINY)
    man = verify_dataset(tmp_path)
    assert len(man.shards) == 1 and not man.summary["complete"]
    assert len(list(iter_samples(tmp_path))) == man.n_samples == 6
    monkeypatch.setattr(shards, "write_atomic", real)
    man = build_dataset(tmp_path, n_piles=2, workers=1, simulate_factory=_fake_factory, **TINY)
    assert man.summary["complete"] and man.n_samples == 12


def test_bad_inputs(tmp_path):
    with pytest.raises(ValueError, match="engine"):
        build_dataset(tmp_path, n_piles=1, engine="ray")
    with pytest.raises(ValueError, match="obstacles_fraction"):
        build_dataset(tmp_path, n_piles=1, obstacles_fraction=float("nan"))
    with pytest.raises(ValueError, match="n_piles"):
        build_dataset(tmp_path, n_piles=0)
    with pytest.raises(DatasetJobError, match="does not exist"):
        build_dataset(tmp_path / "out", n_piles=1, piles_dir=tmp_path / "nope")
    bad = tmp_path / "piles" / "pile_00000"
    bad.mkdir(parents=True)
    (bad / "pile.json").write_text("{broken")
    with pytest.raises(DatasetJobError, match="pile 0 cannot be loaded.*not valid JSON"):
        build_dataset(tmp_path / "out", n_piles=1, piles_dir=tmp_path / "piles", workers=1, **TINY)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(DatasetJobError, match="cannot write"):
        build_dataset(blocker / "sub", n_piles=1, workers=1)


def test_piles_from_a_piles_job(tmp_path):
    from synth.data.jobs import PileJob, run_pile_job

    run_pile_job(tmp_path / "piles", PileJob(count=1, logs=(2, 2), size_px=32, n_renders=2, seed=2), workers=1)
    man = build_dataset(tmp_path / "ds", n_piles=1, workers=1, piles_dir=tmp_path / "piles",
                        simulate_factory=_fake_factory, **TINY)
    samples = list(iter_samples(tmp_path / "ds"))
    assert man.n_samples == 6 and samples[0].pile_id == "pile_00000"
    from synth.render.ortho import OrthoObservation

    obs = OrthoObservation.load(tmp_path / "piles" / "pile_00000")
    np.testing.assert_array_equal(samples[0].depth, obs.depth)


@pytest.mark.slow
def test_dead_worker_is_reported_and_the_job_resumes(tmp_path):
    import multiprocessing as mp
    import os
    import signal

    def kill_pool_workers(p):
        for child in mp.active_children():  # the pool's processes, started by this job
            os.kill(child.pid, signal.SIGKILL)

    from synth.data.robust import RobustLabels

    # the paper's labels (no perturbed repeats of each success): what is killed and resumed is the
    # same job either way, at half the trials
    kw = {**TINY, "max_trials_per_subset": 1, "n_renders": 1, "robust_labels": RobustLabels(repeats=0)}
    with pytest.raises(DatasetJobError, match="worker died"):
        build_dataset(tmp_path, n_piles=4, workers=2, progress=kill_pool_workers, **kw)
    man = verify_dataset(tmp_path)
    assert len(man.shards) in (1, 2, 3)
    man = build_dataset(tmp_path, n_piles=4, workers=1, **kw)
    assert man.summary["complete"] and man.summary["piles"] == 4


def test_job_failures_say_what_is_kept_and_how_to_resume():
    """A full disk is a write failure, a lost connection to a worker (an OSError too) a dead worker,
    anything else is not the job's to explain."""
    import errno

    from synth.data.dataset import _job_failure

    disk = _job_failure(OSError(errno.ENOSPC, "No space left on device"), 3, 10)
    assert "writing the data set failed (No space left on device)" in str(disk) and "3 of 10 chunks" in str(disk)
    for exc in (ConnectionResetError("peer gone"), TimeoutError("no answer")):
        assert "a worker died" in str(_job_failure(exc, 1, 4)) and "re-run the same job to resume" in str(_job_failure(exc, 1, 4))
    assert _job_failure(ValueError("a bug"), 0, 4) is None


def test_dask_engine_on_a_local_cluster(tmp_path):
    pytest.importorskip("distributed")
    seen = []
    man = build_dataset(tmp_path, n_piles=2, workers=2, engine="dask", progress=seen.append,
                        **{**TINY, "max_trials_per_subset": 1, "n_renders": 1})
    assert man.summary["complete"] and 1 <= man.summary["trials"] <= 6 and len(man.shards) == 2
    assert seen[-1].chunks_done == 2 and seen[-1].trials_per_s > 0
    assert len(list(iter_samples(tmp_path))) == 6


_KILL_SCRIPT = """
import sys, time
from types import SimpleNamespace
from synth.data.dataset import build_dataset

def factory(pile, targets):
    def simulate(g):
        time.sleep(0.2)
        ok = g.width_m < 0.75
        return SimpleNamespace(success=ok, cos_beta=0.9, outcome=SimpleNamespace(value="success" if ok else "collision"))
    return simulate

build_dataset(sys.argv[1], n_piles=3, workers=1, simulate_factory=factory, n_logs=2, obstacles_fraction=0.0,
              seed=3, size_px=32, n_renders=2, max_trials_per_subset=3)
"""


def test_resume_after_killing_the_job_process(tmp_path):
    import subprocess
    import sys
    import time

    proc = subprocess.Popen([sys.executable, "-c", _KILL_SCRIPT, str(tmp_path)])
    try:
        def listed() -> int:  # shards the manifest lists (0 before the first is rewritten)
            try:
                return len(read_manifest(tmp_path).shards)
            except DatasetFormatError:
                return 0

        deadline = time.monotonic() + 60
        while not listed() and time.monotonic() < deadline:
            if proc.poll() is not None:
                pytest.fail("the job process ended before it could be killed")
            time.sleep(0.05)
    finally:
        proc.kill()  # SIGKILL, this test's own child only
        proc.wait()
    man = verify_dataset(tmp_path)  # consistent right after the kill
    assert len(man.shards) in (1, 2)
    # every finished shard (done record written, listed or not yet) is kept as it is
    done = [json.loads(r.read_text())["file"] for r in tmp_path.glob("shard_*.done.json")]
    assert {s.file for s in man.shards} <= set(done)
    kept = {f: (tmp_path / f).read_bytes() for f in done}
    man = build_dataset(tmp_path, n_piles=3, workers=1, simulate_factory=_fake_factory, **TINY)
    assert man.summary["complete"] and man.summary["piles"] == 3
    assert all((tmp_path / f).read_bytes() == b for f, b in kept.items())
    assert len(list(iter_samples(tmp_path))) == 3 * 3 * 2


def _as_format_1_0(path, stats_grid=True):
    """Rewrite a shard as format 1.0 wrote it: U marking each grasp's whole footprint."""
    from synth.data.maps import rectangle_mask

    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(bytes(arrays["meta"]).decode())
    meta["format_version"] = "1.0"
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    starts, G = arrays["grasp_start"], arrays["grasps"]
    for k in range(len(arrays["maps"])):
        for x, y, p, w, _ in G[starts[k]:starts[k + 1]]:
            arrays["maps"][k, 3][rectangle_mask(GRID, Grasp(x, y, p, w))] = 1.0
    np.savez_compressed(path, **arrays)
    rec_path = shards.done_record_path(path)
    rec = json.loads(rec_path.read_text())
    rec["stats"] = {"grid": {"size_px": 32, "extent_m": 5.0}} if stats_grid else {}
    rec_path.write_text(json.dumps(rec))


def test_format_1_0_shards_are_re_encoded_from_their_grasps(tmp_path):
    info = _write(tmp_path)[0]
    path = tmp_path / info.file
    new = {(x.subset, x.render): x.maps.copy() for x in load_shard(path)}
    _as_format_1_0(path)
    old = load_shard(path)
    assert len(old) == len(new)
    for x in old:  # the footprint U of 1.0 is gone: the maps are the 1.1 encoding of the same grasps
        np.testing.assert_array_equal(x.maps, new[(x.subset, x.render)])
    _as_format_1_0(path, stats_grid=False)
    with pytest.raises(DatasetFormatError, match="format 1.0 shard.*extent"):
        load_shard(path)
