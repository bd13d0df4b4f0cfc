"""Crane link latency (command -> acknowledgement) per backend, and the end-to-end demo time."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def markdown(n: int = 500) -> str:
    from field.link.latency import measure_backends

    rows = ["| backend | mode | commands | p50 ms | p99 ms |", "|---|---|---|---|---|"]
    for mode in ("reject", "accept"):
        for s in measure_backends(n if mode == "reject" else n // 5, mode,
                                  backends=("can-virtual", "can-remote", "zenoh")):
            d = s.__dict__
            rows.append(f"| {d.get('backend', d.get('url'))} | {mode} | {d.get('n')} | {d.get('p50_ms'):.2f} | "
                        f"{d.get('p99_ms'):.2f} |")
    t0 = time.perf_counter()
    proc = subprocess.run([str(ROOT / ".venv" / "bin" / "loggrasp"), "demo", "--out", "out/bench-demo"],
                          capture_output=True, text=True, cwd=ROOT)
    demo_s = time.perf_counter() - t0
    ok = "ok" if proc.returncode == 0 else f"FAILED (exit {proc.returncode})"
    return ("### Crane link: command → acknowledgement round trip\n"
            "`reject` commands are out of reach (answered OUT_OF_REACH, nothing moves); `accept` commands are "
            "executed by the controller twin's fixed executor. can-remote and zenoh cross processes on 127.0.0.1.\n\n"
            + "\n".join(rows)
            + f"\n\n### End-to-end `loggrasp demo` (process start to exit)\nTarget: under 30 s.\n\n"
              f"| command | wall s | result |\n|---|---|---|\n| `loggrasp demo` | {demo_s:.1f} | {ok} |")


if __name__ == "__main__":
    print(markdown(int(sys.argv[1]) if len(sys.argv) > 1 else 500))
