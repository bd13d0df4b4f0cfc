"""What the command-line tests share: the command run in-process through :func:`field.cli.run` (the one
error handler) or as a real process, its result, and the bundled demo scan."""


from __future__ import annotations

import io
import json
import os
import socket
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path


from field.cli import run
from field.demo import DEMO_DATA

ROOT = Path(__file__).resolve().parents[1]
SCAN, GNSS = DEMO_DATA / "scan", DEMO_DATA / "gnss.csv"
OLD = "1e9"  # the bundled scan is old: a --max-pile-age it passes
RAW = ROOT / "tests" / "data" / "gnss" / "raw"  # synthesised receiver captures (README beside them)


@dataclass
class Result:
    code: int
    out: str
    err: str

    @property
    def error(self) -> str:
        lines = [ln for ln in self.err.splitlines() if ln.startswith("error:")]
        assert len(lines) == 1, f"want exactly one error line:\n{self.err}"
        return lines[0]

    def json(self) -> dict:
        def strict(c):
            raise ValueError(f"{c} is not JSON")

        d = json.loads(self.out, parse_constant=strict)  # the whole of stdout: one document
        assert isinstance(d.get("format"), str) and d["format"].startswith("loggrasp.") and d.get("format_version")
        return d


def cli(capsys, *args, stdin: str | None = None, monkeypatch=None) -> Result:
    capsys.readouterr()
    if stdin is not None:
        monkeypatch.setattr(sys, "stdin", io.StringIO(stdin))
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err, err
    return Result(code, out, err)


def fails(r: Result, code: int, *words: str) -> str:
    """``r`` exited with ``code`` and one error line that contains every word."""
    assert r.code == code, (r.code, r.err)
    line = r.error
    for w in words:
        assert w in line, (w, line)
    return line


def run_captured(*args) -> Result:
    """:func:`run` for a module-scoped fixture (no capsys there)."""
    import contextlib

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = run([str(a) for a in args])
    r = Result(code, out.getvalue(), err.getvalue())
    assert "Traceback" not in r.out + r.err, r.err
    return r


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def loggrasp_process(*args: str, **kw) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, "-m", "field.cli", *args], stdout=subprocess.PIPE, cwd=ROOT,
                            stderr=subprocess.PIPE, text=True, env=env, **kw)
