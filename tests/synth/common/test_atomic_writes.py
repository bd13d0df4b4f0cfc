"""Atomic writes: a write interrupted part-way leaves the old file (or nothing), never a partial one.

Two nets: (1) the shared writer and its main users, interrupted for real part-way through the
write by a file-size limit (``RLIMIT_FSIZE``: the kernel stops the write at N bytes with EFBIG,
as a full disk or a quota would); (2) a scan of the product code for direct file writes (
``write_bytes``, ``open(..., "w")``, ``np.save`` to a path, ...) outside the shared writer and a
short, reasoned allow-list, so that a user replacing ``atomic_write_bytes`` by a plain write is
caught even where no behavioural test reaches.
"""

from __future__ import annotations

import ast
import contextlib
import errno
import resource
import signal
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from synth.common.files import atomic_write_bytes  # the project's one atomic writer

ROOT = Path(__file__).resolve().parents[3]
PACKAGES = ("synth", "planner", "reconstruct", "field")


@contextlib.contextmanager
def file_size_limit(n_bytes: int):
    """No file of this process may grow past ``n_bytes`` inside the block: a write crossing it
    stops there and fails with EFBIG (SIGXFSZ ignored), leaving whatever it had written."""
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    old_handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (n_bytes, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, old_handler)


def _listing(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_the_limit_really_cuts_a_plain_write_part_way(tmp_path):
    """The harness itself: a plain write under the limit leaves a partial file (what the tests
    below must never see)."""
    p = tmp_path / "plain.bin"
    with file_size_limit(1000), pytest.raises(OSError) as ei:
        p.write_bytes(b"x" * 100_000)
    assert ei.value.errno == errno.EFBIG
    assert 0 < p.stat().st_size < 100_000


def test_interrupted_atomic_write_keeps_the_old_file(tmp_path):
    p = tmp_path / "f.bin"
    atomic_write_bytes(p, b"old contents")
    with file_size_limit(4096), pytest.raises(OSError):
        atomic_write_bytes(p, b"n" * 200_000)
    assert p.read_bytes() == b"old contents"
    assert [q.name for q in tmp_path.iterdir()] == ["f.bin"]  # no temp file left behind


def test_interrupted_atomic_write_of_a_new_file_leaves_nothing(tmp_path):
    p = tmp_path / "sub" / "f.bin"
    with file_size_limit(4096), pytest.raises(OSError):
        atomic_write_bytes(p, b"n" * 200_000)
    assert not p.exists() and list(p.parent.iterdir()) == []
    atomic_write_bytes(p, b"ok")  # and a later write works
    assert p.read_bytes() == b"ok"


# -- the writer's users -----------------------------------------------------------------------------
def _write_pile(path: Path, version: int) -> None:
    from synth.scene.pile import LogSpec, PileSpec, TerrainSpec, write_pile

    pile = PileSpec(terrain=TerrainSpec(seed=1, extent_m=5.0, resolution=16, amplitude_m=0.0),
                    logs=(LogSpec.from_endpoints((-1.0, 0.0, 0.1), (1.0, 0.0, 0.1), 0.2),),
                    notes="n" * (10 if version == 0 else 100_000))
    write_pile(pile, path / "pile.json")


def _write_ortho(path: Path, version: int) -> None:
    from synth.render.ortho import OrthoObservation

    rng = np.random.default_rng(version)
    n = 8 if version == 0 else 96
    OrthoObservation(intensity=rng.random((1, n, n), dtype=np.float32), depth=rng.random((n, n), dtype=np.float32),
                     instance=np.zeros((n, n), np.int16)).save(path / "ortho.npz")


def _write_shard(path: Path, version: int) -> None:
    """A data-set shard and its done record (through the data set's own write seam)."""
    from synth.data.shards import Sample, ShardWriter
    from synth.geometry.frames import OrthoGrid
    from synth.data.maps import encode_grasps

    n = 16 if version == 0 else 96  # the shard outweighs its done record: the cut falls in the shard
    rng = np.random.default_rng(version)
    w = ShardWriter(path, "w0", 0)
    maps = encode_grasps(OrthoGrid(n, 5.0), [], [])
    w.add(Sample(pile_id="pile_00000", render=0, subset=(0,), intensity=rng.random((n, n), dtype=np.float32),
                 depth=rng.random((n, n), dtype=np.float32) + 4.0, target_mask=np.ones((n, n), bool), maps=maps,
                 grasps=np.zeros((0, 5)), negative=True, n_logs=1))
    w.close({"version": version})


def _write_manifest(path: Path, version: int) -> None:
    from synth.data.shards import Manifest, write_manifest

    write_manifest(path, Manifest(params={"seed": version, "pad": "m" * (10 if version == 0 else 100_000)},
                                  grid={"size_px": 32}, shards=[], summary={}))


def _write_tensors(path: Path, version: int) -> None:
    import torch

    from planner.checkpoint import save_tensors

    save_tensors(path / "state.safetensors", {"w": torch.arange(4 if version == 0 else 50_000, dtype=torch.float32)},
                 {"format": "test", "format_version": "1.0"})


USERS = {"write_pile": _write_pile, "OrthoObservation.save": _write_ortho, "ShardWriter.close": _write_shard,
         "write_manifest": _write_manifest, "save_tensors": _write_tensors}


@pytest.mark.parametrize("user", sorted(USERS))
def test_users_of_the_writer_keep_the_old_file_when_interrupted(tmp_path, user):
    """Each user writes a small version 0, then is interrupted part-way through a large version 1:
    the folder still holds exactly version 0 (no partial file, no temp file)."""
    write = USERS[user]
    scratch, target = tmp_path / "scratch", tmp_path / "target"
    scratch.mkdir(), target.mkdir()
    write(scratch, 1)  # the size of version 1 (and every lazy import done outside the limit)
    big = max(len(b) for b in _listing(scratch).values())
    write(target, 0)
    old = _listing(target)
    assert max(len(b) for b in old.values()) < big // 2, "version 0 must be smaller than the cut"
    with file_size_limit(big // 2), pytest.raises(OSError):
        write(target, 1)
    assert _listing(target) == old


# -- no direct writes in the product code -------------------------------------------------------
#: (module, function) -> the direct writes it may make, and why they are safe
ALLOWED_DIRECT_WRITES: dict[tuple[str, str], tuple[Counter, str]] = {
    ("synth/common/files.py", "atomic_write_bytes"): (Counter({"fdopen('wb')": 1}), "the atomic writer itself"),
    ("synth/physics/meshes.py", "_write_cached"): (Counter({"fdopen('w')": 1}), "own temp file + os.replace in the mesh cache"),
    ("synth/common/files.py", "make_writable_dir"): (Counter({"write_bytes": 1}), "an empty write probe, deleted at once"),
    ("synth/render/stereo.py", "StereoPair.save"): (
        Counter({"write_bytes": 1, "open('wb')": 1, "np.savez_compressed": 1, "write_text": 1}),
        "files of a fresh temporary folder that is renamed into place"),
    ("planner/evaluate.py", "run_evaluation"): (
        Counter({"write_text": 1}), "examples.err: a note that a picture failed"),
    ("reconstruct/scan/sfm.py", "_run_colmap"): (Counter({"imwrite": 1}), "images in SfM's temporary work folder"),
    ("reconstruct/scan/sfm.py", "_sfm_model"): (Counter({"shutil.copytree": 1}), "keep_workdir: a debugging copy"),
    ("field/controller/executors.py", "FixedOutcomeExecutor.__init__"): (
        Counter({"open('w')": 1}), "the crane twin's append-only execution log (its header line)"),
    ("field/controller/executors.py", "FixedOutcomeExecutor._log_start"): (
        Counter({"open('a')": 1}), "the crane twin's append-only execution log (one line per command)"),
    ("field/link/secoc.py", "generate_key_file"): (
        Counter({"os.open": 1, "fdopen('w')": 1}), "a new key file created exclusively with mode 0600"),
    ("field/link/signing.py", "_write_new"): (
        Counter({"os.open": 1, "fdopen('wb')": 1}), "a new key file created exclusively (O_EXCL, its mode), removed if cut short"),
    ("synth/common/cli.py", "quiet_c_streams"): (
        Counter({"fdopen('w')": 2}), "C-level stdout/stderr pointed at /dev/null, not a file written"),
    ("field/audit/chain.py", "ChainFile.resume"): (
        Counter({"open('r+b')": 1}), "cuts a torn last line (a crash mid-append) off an append-only hash chain"),
    ("field/audit/chain.py", "ChainFile.append"): (
        Counter({"os.open": 1}), "the hash chain: append-only lines, one write each, fsynced"),
    ("field/trial_record.py", "_record_raw_survey"): (
        Counter({"shutil.copy2": 1}), "raw receiver logs copied into a temporary record folder renamed into place"),
    ("field/trial_record.py", "_TrialRecord.copy_inputs"): (
        Counter({"shutil.copytree": 1, "shutil.copy2": 1}),
        "inputs copied into a temporary record folder renamed into place"),
}
_WRITE_MODE_CHARS = set("wax+")


def _mode(call: ast.Call, pos: int) -> str:
    for kw in call.keywords:
        if kw.arg == "mode":
            return kw.value.value if isinstance(kw.value, ast.Constant) else "?"
    if len(call.args) > pos:
        a = call.args[pos]
        return a.value if isinstance(a, ast.Constant) and isinstance(a.value, str) else "?"
    return "r"


def _write_kind(call: ast.Call, buffers: set[str]) -> str | None:
    """What kind of direct file write ``call`` is, or None."""
    f = call.func
    name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", None)
    owner = f.value.id if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) else None
    first = call.args[0] if call.args else None
    to_buffer = isinstance(first, ast.Name) and first.id in buffers
    if name in ("write_bytes", "write_text"):
        return name
    if name == "open" and owner == "os":
        flags = ast.unparse(call.args[1]) if len(call.args) > 1 else ""
        return "os.open" if any(k in flags for k in ("O_CREAT", "O_TRUNC", "O_APPEND")) else None
    if name == "open" and (isinstance(f, ast.Name) or owner in ("io", "builtins", "codecs", "gzip")):
        m = _mode(call, 1)
        return f"open({m!r})" if m == "?" or _WRITE_MODE_CHARS & set(m) else None
    if name == "open":  # Path.open(mode): only a literal write mode counts (zenoh.open(conf) is no file)
        m = _mode(call, 0)
        return f"open({m!r})" if m != "?" and _WRITE_MODE_CHARS & set(m) else None
    if name == "fdopen":
        m = _mode(call, 1)
        return f"fdopen({m!r})" if m == "?" or _WRITE_MODE_CHARS & set(m) else None
    if name in ("save", "savez", "savez_compressed", "savetxt") and owner in ("np", "numpy", "torch"):
        return None if to_buffer else f"{owner}.{name}"
    if name in ("imwrite", "savefig", "tofile"):
        return None if to_buffer else name
    if owner == "shutil" and name and name.startswith(("copy", "move")):
        return f"shutil.{name}"
    return None


def direct_writes(source: str) -> list[tuple[str, int, str]]:
    """(function qualname, line, kind) of every direct file write in ``source``. Writes into an
    ``io.BytesIO``/``StringIO`` assigned in the same function are not file writes."""
    found: list[tuple[str, int, str]] = []

    def visit(node: ast.AST, scope: list[str], buffers: set[str]) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                inner = set(buffers)
                if not isinstance(child, ast.ClassDef):
                    for n in ast.walk(child):
                        if isinstance(n, ast.Assign) and isinstance(n.value, ast.Call):
                            fn = n.value.func
                            called = fn.attr if isinstance(fn, ast.Attribute) else getattr(fn, "id", "")
                            if called in ("BytesIO", "StringIO"):
                                inner |= {t.id for t in n.targets if isinstance(t, ast.Name)}
                visit(child, scope + [child.name], inner)
                continue
            if isinstance(child, ast.Call):
                kind = _write_kind(child, buffers)
                if kind:
                    found.append((".".join(scope) or "<module>", child.lineno, kind))
            visit(child, scope, buffers)

    visit(ast.parse(source), [], set())
    return found


def test_product_code_writes_files_only_through_the_atomic_writer():
    seen: dict[tuple[str, str], Counter] = {}
    where: dict[tuple[str, str], list[int]] = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            for func, line, kind in direct_writes(path.read_text()):
                seen.setdefault((rel, func), Counter())[kind] += 1
                where.setdefault((rel, func), []).append(line)
    bad = [f"{rel}:{where[(rel, func)][0]} {func}() writes directly ({dict(kinds)}); use "
           "synth.common.files.atomic_write_bytes (or add it, with its reason, to ALLOWED_DIRECT_WRITES)"
           for (rel, func), kinds in seen.items()
           if kinds != ALLOWED_DIRECT_WRITES.get((rel, func), (Counter(), ""))[0]]
    assert not bad, "\n".join(bad)
    stale = sorted(set(ALLOWED_DIRECT_WRITES) - set(seen))
    assert not stale, f"allow-list entries without a direct write any more (remove them): {stale}"


def test_the_scan_sees_plain_writes():
    src = """
import io, os, shutil
import numpy as np
def plain(path, data):
    path.write_bytes(data)
def nested():
    class K:
        def m(self, p):
            with open(p, "w") as f:
                f.write("x")
def buffered(obj):
    buf = io.BytesIO()
    np.savez_compressed(buf, a=obj)
    np.save("x.npy", obj)
    with open("r.txt") as f:
        f.read()
    with Path("y").open("ab") as f:
        pass
    fd = os.open("z", os.O_WRONLY | os.O_CREAT)
    shutil.copy2("a", "b")
"""
    assert [(f, k) for f, _, k in direct_writes(src)] == [
        ("plain", "write_bytes"), ("nested.K.m", "open('w')"), ("buffered", "np.save"),
        ("buffered", "open('ab')"), ("buffered", "os.open"), ("buffered", "shutil.copy2")]
