import json

import pytest

from synth.errors import OutputError
from synth.common.ranges import parse_range
from synth.data.jobs import PileJob, pile_dir_name, run_pile_job
from synth.scene.pile import read_pile
from synth.render.ortho import OrthoObservation


def test_job_writes_complete_piles_and_resumes(tmp_path):
    job = PileJob(count=2, logs=(2, 3), obstacles=(0, 1), seed=5, n_renders=1)
    stats = run_pile_job(tmp_path, job, workers=1)
    assert stats["generated"] == 2
    for k in range(2):
        d = tmp_path / pile_dir_name(k)
        pile = read_pile(d)
        obs = OrthoObservation.load(d)
        assert obs.n_logs == pile.n_logs and (d / "preview.png").stat().st_size > 1000
    first = (tmp_path / pile_dir_name(0) / "pile.json").read_bytes()
    # a killed job leaves a temp folder: it is cleaned up, finished piles are kept as they are
    (tmp_path / ".pile_00002.tmp-999").mkdir()
    stats = run_pile_job(tmp_path, PileJob(count=3, logs=(2, 3), obstacles=(0, 1), seed=5, n_renders=1), workers=1)
    assert stats == {"generated": 1, "skipped": 2, "attempts": stats["attempts"]}
    assert (tmp_path / pile_dir_name(0) / "pile.json").read_bytes() == first
    assert not list(tmp_path.glob(".pile_*"))


def test_pile_params_depend_only_on_seed_and_index():
    a = PileJob(count=10, logs=(2, 7), seed=1)
    assert [a.pile_params(k) for k in range(5)] == [PileJob(count=3, logs=(2, 7), seed=1).pile_params(k) for k in range(5)]
    assert all(2 <= a.pile_params(k)[1] <= 7 for k in range(10))


def test_resume_with_other_parameters_is_refused(tmp_path):
    (tmp_path / "job.json").write_text(json.dumps({"format": "loggrasp.piles", "logs": [9, 9]}))
    (tmp_path / pile_dir_name(0)).mkdir()  # a finished pile binds the folder to its job
    with pytest.raises(OutputError, match="other parameters"):
        run_pile_job(tmp_path, PileJob(count=2), workers=1)


def test_a_job_file_without_finished_piles_binds_nothing(tmp_path):
    """A typo that failed before making a pile does not refuse the corrected command."""
    (tmp_path / "job.json").write_text(json.dumps({"format": "loggrasp.piles", "logs": [9, 9]}))
    assert run_pile_job(tmp_path, PileJob(count=1, logs=(2, 2), n_renders=1, size_px=64), workers=1)["generated"] == 1
    assert json.loads((tmp_path / "job.json").read_text())["logs"] == [2, 2]


def test_unwritable_output(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(OutputError, match="cannot write"):
        run_pile_job(blocker / "sub", PileJob(count=1), workers=1)


@pytest.mark.parametrize("text", ["a-b", "5-2", "-3", "1-2-3"])
def test_bad_ranges(text):
    with pytest.raises(ValueError):
        parse_range(text, "--logs")


@pytest.mark.parametrize("kwargs", [{"count": 0}, {"count": 1, "logs": (0, 2)}, {"count": 1, "obstacles": (3, 99)}])
def test_bad_jobs(kwargs):
    with pytest.raises(ValueError):
        PileJob(**kwargs)


_POOL_SCRIPT = """
import multiprocessing as mp, sys, time
from concurrent.futures import ProcessPoolExecutor
sys.path.insert(0, {root!r})
from synth.common.processes import exit_with_parent
from tests.synth.data.test_jobs import _sleeper

if __name__ == "__main__":
    with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn"), initializer=exit_with_parent,
                             initargs=(0.1,)) as pool:
        pool.submit(_sleeper, {pid_file!r}).result()
"""


def _sleeper(pid_file: str) -> None:
    import os
    import time

    with open(pid_file + ".tmp", "w") as f:
        f.write(str(os.getpid()))
    os.replace(pid_file + ".tmp", pid_file)
    time.sleep(60)


def test_pool_workers_end_with_a_killed_job(tmp_path):
    """A job killed outright (SIGKILL: no clean-up runs) takes its pool workers with it: none is
    left writing into its output folder while the next run starts."""
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    root = str(Path(__file__).resolve().parents[3])
    pid_file = str(tmp_path / "worker.pid")
    script = tmp_path / "job.py"
    script.write_text(_POOL_SCRIPT.format(root=root, pid_file=pid_file))
    job = subprocess.Popen([sys.executable, str(script)], cwd=root)
    try:
        t0 = time.monotonic()
        while not os.path.exists(pid_file):
            assert time.monotonic() - t0 < 60, "the worker never started"
            time.sleep(0.1)
        worker = int(Path(pid_file).read_text())
        os.kill(job.pid, signal.SIGKILL)
        job.wait()
        t0 = time.monotonic()
        while True:
            try:
                os.kill(worker, 0)
            except ProcessLookupError:
                break
            if time.monotonic() - t0 > 10:
                os.kill(worker, signal.SIGKILL)
                pytest.fail("the pool worker outlived its killed job by 10 s")
            time.sleep(0.1)
    finally:
        if job.poll() is None:
            job.kill()
