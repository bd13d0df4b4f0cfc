#!/usr/bin/env bash
# The committed stores' rebuild (issue 35) as long background jobs that outlive a session:
#
#   scripts/store_jobs.sh start   # a detached worktree per store at HEAD (kept if it exists), each job
#                                 # resumed there at nice 10 with one worker; logs in $RUNS
#   scripts/store_jobs.sh sync    # the chunks finished so far copied into this checkout with the store
#                                 # record they belong to (a snapshot taken first), checked by the
#                                 # datastore tests; then commit them and the "Progress:" line of
#                                 # docs/dataset.md
#   scripts/store_jobs.sh status  # piles done per store, and whether its job runs
#
# The worktrees' commit only needs the same trial revision as the store: a job refuses other
# parameters or another revision itself. Environment: WT_ROOT (default /work), RUNS (default /work/runs).
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
WT_ROOT="${WT_ROOT:-/work}"
RUNS="${RUNS:-/work/runs}"
PY="$ROOT/.venv/bin/python"

# name | worktree | the job's arguments (docs/dataset.md gives each store's command and reason)
JOBS=(
  "paper-v4|$WT_ROOT/wt-store-v4b|--piles 604 --logs 4 --obstacles-fraction 0.33 --seed 0"
  "mixed-v4|$WT_ROOT/wt-mixed-v4|--piles 300 --logs 2-7 --max-subsets 15 --obstacles-fraction 0.5 --seed 1"
)

piles() { "$PY" -c "import json,sys; print(json.load(open(sys.argv[1]))['summary']['piles'])" "$1"; }

running() { pgrep -f -- "synth dataset --store .*--out data/$1( |$)" >/dev/null; }

start() {
  mkdir -p "$RUNS"
  for job in "${JOBS[@]}"; do
    IFS='|' read -r name wt args <<<"$job"
    if running "$name"; then echo "$name: already running"; continue; fi
    [ -d "$wt" ] || git -C "$ROOT" worktree add --detach "$wt" HEAD >/dev/null
    # shellcheck disable=SC2086  # args is a word list
    (cd "$wt" && nohup nice -n 10 "$PY" -m field.cli synth dataset --store $args --out "data/$name" --workers 1 \
      >>"$RUNS/store-$name.log" 2>&1 &)
    echo "$name: started in $wt (log $RUNS/store-$name.log)"
  done
}

sync_stores() {
  for job in "${JOBS[@]}"; do
    IFS='|' read -r name wt _ <<<"$job"
    src="$wt/data/$name"
    [ -f "$src/store.json" ] || { echo "error: no store at $src (run: $0 start)" >&2; exit 1; }
    snap="$(mktemp)"
    cp "$src/store.json" "$snap"  # the record first, then exactly the chunks it lists
    "$PY" - "$snap" "$src" "$ROOT/data/$name" <<'PYEOF'
import json, shutil, sys
from pathlib import Path
snap, src, dst = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
for chunk in json.load(open(snap))["chunks"]:
    if not (dst / chunk["file"]).exists():
        shutil.copy2(src / chunk["file"], dst / chunk["file"])
PYEOF
    cp "$snap" "$ROOT/data/$name/store.json" && rm -f "$snap"
    echo "$name: $(piles "$ROOT/data/$name/store.json") piles"
  done
  (cd "$ROOT" && "$PY" -m pytest -q -p no:cacheprovider tests/synth/data/test_datastore.py | tail -1)
}

status() {
  for job in "${JOBS[@]}"; do
    IFS='|' read -r name wt _ <<<"$job"
    done_here="$(piles "$ROOT/data/$name/store.json")"
    there="-"; [ -f "$wt/data/$name/store.json" ] && there="$(piles "$wt/data/$name/store.json")"
    state="stopped"; running "$name" && state="running"
    echo "$name: $done_here piles here, $there in $wt ($state)"
  done
}

case "${1:-}" in
  start) start ;;
  sync) sync_stores ;;
  status) status ;;
  *) echo "usage: $0 start|sync|status" >&2; exit 2 ;;
esac
