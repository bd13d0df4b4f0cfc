"""A golden record of what ``loggrasp reconstruct`` makes of a fixed set of scans, to prove a refactor of
the fitting (reconstruct/fitting) behaviour-preserving (issue 37, step 1: the mechanical split):

    .venv/bin/python scripts/recon_golden.py scans /tmp/rg/scans            # once: the twin scans
    .venv/bin/python scripts/recon_golden.py record /tmp/rg/scans /tmp/rg/base   # at the base commit
    .venv/bin/python scripts/recon_golden.py compare /tmp/rg/scans /tmp/rg/base [/tmp/rg/new]  # after: records
                                                                        # anew (or takes a record made), compares

``scans DIR`` copies the bundled demo scan (field/demo_data) into DIR and makes the twin scans of
:data:`TWIN_SCANS` there with ``loggrasp synth scan`` (seeds outside every bench; 3 to 7 logs, with and
without obstacles, packed, float fixes, every end fixed, degraded surveys).

``record SCANS OUT`` runs ``loggrasp reconstruct --allow-float`` on each scan in this process (the demo
scan also without ``--allow-float``) and keeps, per case, ``pile.json``, ``ortho.npz``, ``report.json``
(every per-log fit result, the fusion, weak ends, contradicted points, survey warnings, moves; kept
without its timings, which are wall times) and ``outcome.json`` (the exit code, and the error line of a
refused scan), then ``hashes.txt``: the sha256 of every file.

``compare`` compares value by value, floats bit by bit (scripts/golden.py's comparison), and exits 1 on a
difference. Each reconstruction takes ~10-15 s on a free core.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import shutil
import sys
import tempfile
from pathlib import Path

from golden import compare as compare_records

ROOT = Path(__file__).resolve().parents[1]

#: (name, ``loggrasp synth scan`` flags): seeds no bench uses
TWIN_SCANS = (
    ("s9101-3logs", ["--seed", "9101", "--logs", "3", "--obstacles", "0"]),
    ("s9102-5logs-obst", ["--seed", "9102", "--logs", "5", "--obstacles", "2"]),
    ("s9103-7logs", ["--seed", "9103", "--logs", "7", "--obstacles", "1-3"]),
    ("s9104-packed", ["--seed", "9104", "--logs", "4", "--packed", "--obstacles", "0"]),
    ("s9105-degraded", ["--seed", "9105", "--logs", "4", "--float-fixes", "4", "--unsurveyed-logs", "1"]),
    ("s9106-all-fixed", ["--seed", "9106", "--logs", "6", "--float-fixes", "0"]),
    ("s9107-degraded-obst", ["--seed", "9107", "--logs", "5", "--obstacles", "2", "--float-fixes", "4",
                             "--unsurveyed-logs", "1"]),
    ("s9108-packed-obst", ["--seed", "9108", "--logs", "6", "--obstacles", "3", "--packed"]),
)
KEPT = ("pile.json", "ortho.npz", "report.json")
VOLATILE_REPORT_KEYS = ("timings_s",)  # wall times


def loggrasp(*args) -> tuple[int, str]:
    """``loggrasp ARGS`` in this process: its exit code and what it printed."""
    from field.cli import run

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        code = run([str(a) for a in args])
    return code, out.getvalue()


def make_scans(scans: Path) -> None:
    from field.demo import DEMO_DATA

    scans.mkdir(parents=True, exist_ok=True)
    if not (scans / "demo").exists():
        shutil.copytree(DEMO_DATA, scans / "demo")
    for name, flags in TWIN_SCANS:
        if (scans / name / "gnss.csv").exists():
            continue
        code, text = loggrasp("synth", "scan", *flags, "--out", scans / name)
        if code != 0:
            raise SystemExit(f"synth scan {name} failed (exit {code}):\n{text}")
        print(f"made {name}", flush=True)


def cases(scans: Path, only: set[str] | None = None) -> list[tuple[str, Path, list[str]]]:
    """(case name, scan folder, extra reconstruct flags), all or those named in ``only``."""
    out = [("demo", scans / "demo", []), ("demo-allow-float", scans / "demo", ["--allow-float"])]
    for name, _ in TWIN_SCANS:
        if not (scans / name / "gnss.csv").exists():
            raise SystemExit(f"{scans / name}: no scan there (make them with `recon_golden.py scans {scans}`)")
        out.append((name, scans / name, ["--allow-float"]))
    return [c for c in out if only is None or c[0] in only]


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def record(scans: Path, out: Path, only: set[str] | None = None) -> None:
    if out.exists():
        raise SystemExit(f"{out} exists; record into a new folder")
    out.mkdir(parents=True)
    with tempfile.TemporaryDirectory(prefix="recon-golden-") as tmp:
        for name, scan, flags in cases(scans, only):
            work = Path(tmp) / name
            code, text = loggrasp("reconstruct", scan / "scan", "--gnss", scan / "gnss.csv", "--out", work, *flags)
            dst = out / name
            dst.mkdir()
            (out / "logs").mkdir(exist_ok=True)
            (out / "logs" / f"{name}.txt").write_text(text)
            error = [ln for ln in text.splitlines() if ln.startswith(("error", "Error"))]
            (dst / "outcome.json").write_text(json.dumps({"exit_code": code, "error": error}, indent=1) + "\n")
            for f in KEPT:
                if (work / f).exists():
                    shutil.copy(work / f, dst / f)
            if (dst / "report.json").exists():  # without its wall times
                rep = json.loads((dst / "report.json").read_text())
                for k in VOLATILE_REPORT_KEYS:
                    rep.pop(k, None)
                (dst / "report.json").write_text(json.dumps(rep, indent=1) + "\n")
            print(f"{name}: exit {code}{' ' + error[-1] if error else ''}", flush=True)
    lines = [f"{sha256(p)}  {p.relative_to(out)}" for p in sorted(out.rglob("*"))
             if p.is_file() and p.relative_to(out).parts[0] != "logs"]
    (out / "hashes.txt").write_text("\n".join(lines) + "\n")
    print(f"recorded {len(lines)} files -> {out}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="verb", required=True)
    sub.add_parser("scans", help="make the scans").add_argument("scans", type=Path)
    rec = sub.add_parser("record", help="reconstruct every scan into a new folder")
    cmp_ = sub.add_parser("compare", help="record anew (into OTHER, or take OTHER when it exists) and compare "
                                          "with GOLDEN")
    for p in (rec, cmp_):
        p.add_argument("scans", type=Path)
        p.add_argument("--cases", default="", help="comma-separated case names (default: all); a quick look, "
                                                   "compared against the same cases of GOLDEN")
    rec.add_argument("out", type=Path)
    cmp_.add_argument("golden", type=Path)
    cmp_.add_argument("other", type=Path, nargs="?")
    args = ap.parse_args(argv)
    if args.verb == "scans":
        make_scans(args.scans)
        return 0
    only = {c for c in args.cases.split(",") if c} or None
    if args.verb == "record":
        record(args.scans, args.out, only)
        return 0
    new = args.other or Path(tempfile.mkdtemp(prefix="recon-golden-new-")) / "new"
    if not new.exists():
        record(args.scans, new, only)
    golden = args.golden
    if only is not None:  # the same cases of the golden record
        golden = Path(tempfile.mkdtemp(prefix="recon-golden-subset-")) / "golden"
        golden.mkdir()
        for name in only:
            shutil.copytree(args.golden / name, golden / name)
        keep = [ln for ln in (args.golden / "hashes.txt").read_text().splitlines()
                if ln.split()[1].split("/")[0] in only]
        (golden / "hashes.txt").write_text("\n".join(keep) + "\n")
    code = compare_records(golden, new)
    same = (golden / "hashes.txt").read_text() == (new / "hashes.txt").read_text()
    print(f"hashes.txt {'equal' if same else 'DIFFERENT'} ({golden} vs {new})")
    return code or int(not same)


if __name__ == "__main__":
    sys.exit(main())
