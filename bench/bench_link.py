"""Crane link latency (command -> acknowledgement) per backend, with and without authenticated
frames, and the end-to-end demo time."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


#: the frames column of an authenticated rig: SecOC MACs both ways, and the crane's answers signed
SIGNED = "authenticated (SecOC) + signed answers (Ed25519)"


def per_frame_costs(repeats: int = 2000) -> list[tuple[str, float, float]]:
    """(what, median µs, p99 µs) per frame of one Ack (the most frequent answer): securing and
    verifying it with today's HMAC-SHA256/64, the same with AES-128-CMAC (SecOC's MAC, cryptography's
    CMAC), and Ed25519 signing and verifying of the bytes a signature covers."""
    import secrets
    import statistics

    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
    from cryptography.hazmat.primitives.ciphers.algorithms import AES
    from cryptography.hazmat.primitives.cmac import CMAC

    from field.link.codec import Encoder
    from field.link.messages import Ack
    from field.link.secoc import SecOC
    from field.link.signing import AnswerSigner, AnswerVerifier, signed_bytes

    kind, plain = Encoder().encode(Ack(123456, True))
    secoc = SecOC(secrets.token_bytes(32))
    secured = secoc.secure(kind, plain)
    covered = signed_bytes(kind, secured)
    aes_key = secrets.token_bytes(16)
    signing = Ed25519PrivateKey.generate()
    signer, verifier = AnswerSigner(signing), AnswerVerifier(signing.public_key())
    signature = signer.sign(kind, secured)

    def cmac() -> bytes:
        c = CMAC(AES(aes_key))
        c.update(covered)
        return c.finalize()[:8]

    cases = [("HMAC-SHA256/64: secure (MAC + freshness value)", lambda: secoc.secure(kind, plain)),
             ("HMAC-SHA256/64: verify (MAC only)", lambda: secoc.verify(kind, secured, check_freshness=False)),
             ("AES-128-CMAC/64 over the same bytes", cmac),
             ("Ed25519: sign (crane)", lambda: signer.sign(kind, secured)),
             ("Ed25519: verify (laptop)", lambda: verifier.check(kind, secured, signature))]
    out = []
    for what, fn in cases:
        for _ in range(200):  # warm up
            fn()
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter_ns()
            fn()
            times.append((time.perf_counter_ns() - t0) / 1000.0)
        times.sort()
        out.append((what, statistics.median(times), times[int(0.99 * (len(times) - 1))]))
    return out


def markdown(n: int = 500) -> str:
    import tempfile

    from field.link.latency import measure_backends
    from field.link.secoc import generate_key_file
    from field.link.signing import generate_signing_key

    rows = ["| backend | frames | mode | commands | p50 ms | p99 ms | mean ms |", "|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        key = str(generate_key_file(Path(tmp) / "bench.key"))
        generate_signing_key(f"{key}.sign")  # beside the key: the rigs sign the crane's answers with it
        for mode in ("reject", "accept"):
            for secoc in (None, key):
                for s in measure_backends(n if mode == "reject" else n // 5, mode,
                                          backends=("can-virtual", "can-remote", "zenoh"), secoc_key=secoc):
                    rows.append(f"| {s.label.split()[0]} | {SIGNED if secoc else 'E2E only'} | {mode} "
                                f"| {s.n} | {s.p50_ms:.2f} | {s.p99_ms:.2f} | {s.mean_ms:.2f} |")
    costs = ["| operation on one Ack frame | median µs | p99 µs |", "|---|---|---|"]
    costs += [f"| {what} | {med:.1f} | {p99:.1f} |" for what, med, p99 in per_frame_costs()]
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
            "field/link/secoc.py) and every crane answer signed with Ed25519 (field/link/signing.py; on CAN a "
            "signature frame after each answer, checked before the answer counts), `E2E only` = CRC and counter "
            "alone.\n\n"
            + "\n".join(rows)
            + "\n\n### Cost of authenticating one link frame\n"
              "One process, one thread, the `cryptography` package (OpenSSL); HMAC is Python's hmac module. The "
              "AES-128-CMAC row is what SecOC's own profiles use, measured over the bytes today's MAC covers "
              "(not wired into the link).\n\n"
            + "\n".join(costs)
            + f"\n\n### End-to-end `loggrasp demo` (process start to exit)\nTarget: under 30 s.\n\n"
              f"| command | wall s | result |\n|---|---|---|\n| `loggrasp demo` | {demo_s:.1f} | {ok} |")


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("commands", nargs="?", type=int, default=500, help="commands per backend and mode (default 500)")
    print(markdown(ap.parse_args().commands))
