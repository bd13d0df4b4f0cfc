"""How big the commits since a base are, as a submission counts them: the packed size and the diffs added up
(a binary file counts its whole size each time it is added, changed or removed, old and new). Session 21's
work was refused for size: three 23-48 MB training resume states committed and removed again counted
twice each. Run it before a stop; it exits 1 past the limits (or past --max-diff-mib).

    .venv/bin/python scripts/submission_size.py --base <last landed commit>
"""

from __future__ import annotations

import argparse
import subprocess
import sys

LIMIT_PACK_MIB = 512
LIMIT_DIFF_MIB = 256


def git(*args: str, data: bytes | None = None) -> bytes:
    return subprocess.run(["git", *args], input=data, capture_output=True, check=True).stdout


def blob_size(sha: str) -> int:
    return 0 if set(sha) == {"0"} else int(git("cat-file", "-s", sha))


def commit_diff_bytes(commit: str) -> tuple[int, list[tuple[int, str]]]:
    """Bytes of the commit's diff against its first parent: the text patch, plus every binary blob
    (old and new) in full. Also the binary files, largest first."""
    patch = len(git("diff-tree", "-p", "--no-color", "--root", "-m", "--first-parent", commit))
    binaries = []
    raw = git("diff-tree", "-r", "--root", "-m", "--first-parent", "--numstat", "-z", commit).split(b"\0")
    binary_paths = {f.split(b"\t", 2)[2].decode() for f in raw if f.startswith(b"-\t-\t")}
    for line in git("diff-tree", "-r", "--root", "-m", "--first-parent", commit).decode().splitlines():
        if not line.startswith(":"):
            continue
        meta, path = line.split("\t", 1)
        _, _, old, new, _ = meta[1:].split(" ")
        if path in binary_paths:
            binaries.append((blob_size(old) + blob_size(new), path))
    return patch + sum(b for b, _ in binaries), sorted(binaries, reverse=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=True, help="the last landed commit (what the submission builds on)")
    ap.add_argument("--head", default="HEAD")
    ap.add_argument("--max-diff-mib", type=float, default=LIMIT_DIFF_MIB)
    args = ap.parse_args(argv)
    commits = git("rev-list", "--first-parent", "--reverse", f"{args.base}..{args.head}").decode().split()
    total = 0
    for c in commits:
        n, binaries = commit_diff_bytes(c)
        total += n
        big = ", ".join(f"{p} {b / 2**20:.1f} MiB" for b, p in binaries[:3] if b > 2**20)
        print(f"{c[:9]} {n / 2**20:8.2f} MiB  {big}")
    objects = git("rev-list", "--objects", f"{args.base}..{args.head}", f"^{args.base}")
    pack = len(git("pack-objects", "--stdout", "-q", data=b"\n".join(o.split(b" ")[0] for o in objects.splitlines())))
    print(f"{len(commits)} commits: diffs {total / 2**20:.1f} MiB (limit {LIMIT_DIFF_MIB}), "
          f"pack {pack / 2**20:.1f} MiB (limit {LIMIT_PACK_MIB})")
    return 0 if total <= args.max_diff_mib * 2**20 and pack <= LIMIT_PACK_MIB * 2**20 else 1


if __name__ == "__main__":
    sys.exit(main())
