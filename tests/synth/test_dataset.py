import errno
import json

import numpy as np
import pytest

import synth.dataset as ds
from synth.dataset import (
    DatasetFormatError, DatasetIntegrityError, Manifest, Sample, ShardWriter, iter_samples, load_shard,
    read_manifest, write_manifest,
)
from synth.frames import OrthoGrid
from synth.grasp import Grasp
from synth.maps import encode_grasps

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

    monkeypatch.setattr(ds, "_write_bytes", full)
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
