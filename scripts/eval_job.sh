#!/usr/bin/env bash
# The product's evaluation on 1,200 held-out piles (issue 36's targets) as a long background job that
# outlives a session, in the pattern of scripts/store_jobs.sh:
#
#   scripts/eval_job.sh start    # a detached worktree at HEAD (kept if it exists); the job resumed there at
#                                # nice 10, one worker; log in $RUNS/$NAME.log
#   scripts/eval_job.sh sync     # the finished pile records (and the tables of the last finished step)
#                                # copied into docs/results/$NAME of this checkout; then commit
#   scripts/eval_job.sh status   # piles with a record per step, and whether the job runs
#   scripts/eval_job.sh stop     # ends the job (a later start resumes: one record file per pile)
#
# The job grows the evaluation in steps of 20 piles per cell (240 piles), so that whatever it has finished
# is balanced over the 12 cells (the evaluation runs cell by cell): first the product's rows (the shipped
# network re-ranked by the shipped ranker, f1 and f3, each with its field row), then the same rows
# verified in the twin (K = 8). Each record is fingerprinted with the model, the ranker, the calibration
# and the verifier, so a worktree at another commit with other weights re-runs what differs.
# NAME is the product's evaluation as it ships now: a new folder (and worktree) when a shipped weight changes,
# the old folder kept as that product's record (docs/results/README.md: eval-product-1200 is ranker-r3's).
# Environment: WT_ROOT (default /work), RUNS (default /work/runs).
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
WT_ROOT="${WT_ROOT:-/work}"
RUNS="${RUNS:-/work/runs}"
PY="$ROOT/.venv/bin/python"
WT="$WT_ROOT/wt-eval-product-r6"
NAME="eval-product-r6-1200"
OUT="docs/results/$NAME"
ARGS=(--objectives f1,f3 --baselines '' --ranker planner/weights/ranker.safetensors --ranked-only
      --field-error 0.03,2 --seed-base 970000000 --workers 1 --out "$OUT")
STEPS=(20 40 60 80 100)

running() { pgrep -f -- "eval_job.sh loop" >/dev/null; }

loop() {  # runs in the worktree
  for verify in "" 8; do
    for n in "${STEPS[@]}"; do
      extra=(); [ -n "$verify" ] && extra=(--verify "$verify")
      echo "$(date -u +%FT%TZ) step: --per-cell $n ${extra[*]:-} (load $(cut -d' ' -f1-3 /proc/loadavg))"
      "$PY" -m field.cli eval --per-cell "$n" "${ARGS[@]}" "${extra[@]}" >/dev/null
    done
  done
  echo "$(date -u +%FT%TZ) done"
}

start() {
  if running; then echo "$NAME: already running"; return; fi
  mkdir -p "$RUNS"
  [ -d "$WT" ] || git -C "$ROOT" worktree add --quiet --detach "$WT" HEAD
  mkdir -p "$WT/$OUT/records"
  if [ -d "$ROOT/$OUT/records" ]; then  # what an earlier session's job finished and committed
    cp -n "$ROOT/$OUT"/records/*.json "$WT/$OUT/records/" 2>/dev/null || true
  fi
  (cd "$WT" && nohup nice -n 10 bash "$ROOT/scripts/eval_job.sh" loop >>"$RUNS/$NAME.log" 2>&1 &)
  echo "$NAME: started in $WT (log $RUNS/$NAME.log)"
}

sync_records() {
  [ -d "$WT/$OUT/records" ] || { echo "error: no evaluation at $WT/$OUT (run: $0 start)" >&2; exit 1; }
  mkdir -p "$ROOT/$OUT/records"
  cp "$WT/$OUT"/records/*.json "$ROOT/$OUT/records/"  # each record is written whole (temp file, rename)
  for f in eval.json results.md results.json examples.png; do
    [ -f "$WT/$OUT/$f" ] && cp "$WT/$OUT/$f" "$ROOT/$OUT/$f"
  done
  echo "$NAME: $(ls "$ROOT/$OUT/records" | wc -l) pile records in $ROOT/$OUT"
}

status() {
  state="stopped"; running && state="running"
  n=0; [ -d "$WT/$OUT/records" ] && n=$(ls "$WT/$OUT/records" | wc -l)
  echo "$NAME: $n pile records in $WT/$OUT ($state); last step: $(grep step: "$RUNS/$NAME.log" 2>/dev/null | tail -1)"
}

stop() {
  pkill -f -- "eval_job.sh loop" || true
  pkill -f -- "field.cli eval .*--out $OUT" || true
  echo "$NAME: stopped"
}

case "${1:-}" in
  start) start ;;
  loop) loop ;;
  sync) sync_records ;;
  status) status ;;
  stop) stop ;;
  *) echo "usage: $0 start|sync|status|stop" >&2; exit 2 ;;
esac
