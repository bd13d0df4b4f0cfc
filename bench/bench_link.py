"""Crane link latency (command -> acknowledgement) per backend, with and without authenticated
frames, and the end-to-end demo time."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def markdown(n: int = 500) -> str:
    import tempfile

    from field.link.latency import measure_backends
    from field.link.secoc import generate_key_file

    rows = ["| backend | frames | mode | commands | p50 ms | p99 ms | mean ms |", "|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        key = str(generate_key_file(Path(tmp) / "bench.key"))
        for mode in ("reject", "accept"):
            for secoc in (None, key):
                for s in measure_backends(n if mode == "reject" else n // 5, mode,
                                          backends=("can-virtual", "can-remote", "zenoh"), secoc_key=secoc):
                    rows.append(f"| {s.label.split()[0]} | {'authenticated (SecOC)' if secoc else 'E2E only'} | {mode} "
                                f"| {s.n} | {s.p50_ms:.2f} | {s.p99_ms:.2f} | {s.mean_ms:.2f} |")
    t0 = time.perf_counter()
    # the interpreter running the bench (the venv's), so the demo is the code being measured
    proc = subprocess.run([sys.executable, "-m", "field.cli", "demo", "--out", "out/bench-demo"],
                          capture_output=True, text=True, cwd=ROOT)
    demo_s = time.perf_counter() - t0
    ok = "ok" if proc.returncode == 0 else f"FAILED (exit {proc.returncode})"
    return ("### Crane link: command → acknowledgement round trip\n"
            "`reject` commands are out of reach (answered OUT_OF_REACH, nothing moves); `accept` commands are "
            "executed by the controller twin's fixed executor. can-remote and zenoh cross processes on 127.0.0.1. "
            "`authenticated` = SecOC-style frames on both ends (freshness value + truncated HMAC-SHA256, "
            "field/link/secoc.py), `E2E only` = CRC and counter alone.\n\n"
            + "\n".join(rows)
            + f"\n\n### End-to-end `loggrasp demo` (process start to exit)\nTarget: under 30 s.\n\n"
              f"| command | wall s | result |\n|---|---|---|\n| `loggrasp demo` | {demo_s:.1f} | {ok} |")


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("commands", nargs="?", type=int, default=500, help="commands per backend and mode (default 500)")
    print(markdown(ap.parse_args().commands))
