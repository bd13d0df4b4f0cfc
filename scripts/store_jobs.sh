#!/usr/bin/env bash
# The committed stores' rebuild (issue 35) and the on-policy rounds (issue 36) as long background jobs
# that outlive a session:
#
#   scripts/store_jobs.sh start [NAME]  # a detached worktree per job at HEAD (kept if it exists), each job
#                                 # (or only NAME) resumed there at nice 5 (ahead of the evaluation job's
#                                 # 10) with $STORE_WORKERS workers (default 1: a finished store's share
#                                 # goes to the others); logs in $RUNS
#   scripts/store_jobs.sh sync    # the chunks finished so far copied into this checkout with the store
#                                 # record they belong to (a snapshot taken first), checked by the
#                                 # datastore tests; then commit them and the Progress table of
#                                 # docs/dataset.md
#   scripts/store_jobs.sh status  # piles done per store, and whether its job runs
#
# A round is a grasp store too (planner.onpolicy), synced the same way. The worktrees' commit only needs
# the same trial revision as the store (and, for a round, the same model): a job refuses other
# parameters, another revision or another model itself; the number of workers is not a parameter, so a job may be
# resumed with more. Environment: WT_ROOT (default /work), RUNS (default /work/runs), STORE_WORKERS (default 1).
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
WT_ROOT="${WT_ROOT:-/work}"
RUNS="${RUNS:-/work/runs}"
WORKERS="${STORE_WORKERS:-1}"
PY="$ROOT/.venv/bin/python"

# name | worktree | the store's folder | the loggrasp command (docs/dataset.md gives each store's command and
# reason, docs/results/README.md each round's)
JOBS=(
  "paper-v4|$WT_ROOT/wt-store-v4b|data/paper-v4|synth dataset --store --piles 604 --logs 4 --obstacles-fraction 0.33 --seed 0"
  "mixed-v4|$WT_ROOT/wt-mixed-v4|data/mixed-v4|synth dataset --store --piles 300 --logs 2-7 --max-subsets 15 --obstacles-fraction 0.5 --seed 1"
  "round-r3|$WT_ROOT/wt-round3|data/rounds/r3|round --round 3 --piles 480"
)

# a data store counts piles; a round's store one pile per chunk
piles() { "$PY" -c "import json,sys; s=json.load(open(sys.argv[1]))['summary']; print(s.get('piles', s['chunks_done']))" "$1"; }

running() { pgrep -f -- "field.cli .*--out $1( |$)" >/dev/null; }

start() {
  mkdir -p "$RUNS"
  for job in "${JOBS[@]}"; do
    IFS='|' read -r name wt out args <<<"$job"
    [ -n "${1:-}" ] && [ "$1" != "$name" ] && continue
    if running "$out"; then echo "$name: already running"; continue; fi
    [ -d "$wt" ] || git -C "$ROOT" worktree add --quiet --detach "$wt" HEAD
    # shellcheck disable=SC2086  # args is a word list
    (cd "$wt" && nohup nice -n 5 "$PY" -m field.cli $args --out "$out" --workers "$WORKERS" \
      >>"$RUNS/store-$name.log" 2>&1 &)
    echo "$name: started in $wt (log $RUNS/store-$name.log)"
  done
}

sync_stores() {
  for job in "${JOBS[@]}"; do
    IFS='|' read -r name wt out _ <<<"$job"
    src="$wt/$out"
    [ -f "$src/store.json" ] || { echo "error: no store at $src (run: $0 start)" >&2; exit 1; }
    snap="$(mktemp)"
    cp "$src/store.json" "$snap"  # the record first, then exactly the chunks it lists
    mkdir -p "$ROOT/$out/chunks"
    "$PY" - "$snap" "$src" "$ROOT/$out" <<'PYEOF'
import json, shutil, sys
from pathlib import Path
snap, src, dst = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
for chunk in json.load(open(snap))["chunks"]:
    if not (dst / chunk["file"]).exists():
        shutil.copy2(src / chunk["file"], dst / chunk["file"])
PYEOF
    cp "$snap" "$ROOT/$out/store.json" && rm -f "$snap"
    echo "$name: $(piles "$ROOT/$out/store.json") piles"
  done
  (cd "$ROOT" && "$PY" -m pytest -q -p no:cacheprovider tests/synth/data/test_datastore.py | tail -1)
}

status() {
  for job in "${JOBS[@]}"; do
    IFS='|' read -r name wt out _ <<<"$job"
    done_here="-"; [ -f "$ROOT/$out/store.json" ] && done_here="$(piles "$ROOT/$out/store.json")"
    there="-"; [ -f "$wt/$out/store.json" ] && there="$(piles "$wt/$out/store.json")"
    state="stopped"; running "$out" && state="running"
    echo "$name: $done_here piles here, $there in $wt ($state)"
  done
}

case "${1:-}" in
  start) start "${2:-}" ;;
  sync) sync_stores ;;
  status) status ;;
  *) echo "usage: $0 start [NAME]|sync|status" >&2; exit 2 ;;
esac
