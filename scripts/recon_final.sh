#!/usr/bin/env bash
# The ship decision on the final set (issue 37; docs/reconstruction.md, "The ship decision on the final
# set"): revision 22 (rules22) and the frozen joint estimator (revision 18) on the same final-set scans
# and stereo clouds, grown together, as one long background job that outlives a session:
#
#   scripts/recon_final.sh start   # a detached worktree at HEAD (kept if it exists); in it one loop at
#                                  # nice 10, one thread: rules22 extends its record by STEP scans, the
#                                  # new scans' files (not its reconstructions) are hard-linked into the
#                                  # joint work cache, the joint estimator extends its record on them;
#                                  # until TARGET scans. Resumable: a record's scans are skipped.
#   scripts/recon_final.sh sync    # the finished scan records copied into this checkout's
#                                  # docs/results/survey-conditions-final-{r22,joint18} (summary.json
#                                  # remade), the clouds of the shared scans checked equal; then commit
#   scripts/recon_final.sh status  # scans done per record, clouds checked, whether the job runs
#   scripts/recon_final.sh stop    # the job's process group ended (by its recorded id)
#
# The bench's own output (one line per scan with its errors) goes to $WORK/bench-sealed.log, not the
# job's log: the final set is read only through --survey-compare's tables once it is done.
# Environment: WT_ROOT (default /work), RUNS (default /work/runs), WORK (work caches, default
# /work/scratch/final), TARGET (scans per record, default 200), STEP (default 6), PY (the interpreter).
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
WT_ROOT="${WT_ROOT:-/work}"
RUNS="${RUNS:-/work/runs}"
WORK="${WORK:-/work/scratch/final}"
TARGET="${TARGET:-200}"
STEP="${STEP:-6}"
PY="${PY:-$ROOT/.venv/bin/python}"
[ -x "$PY" ] || PY="$WT_ROOT/main/.venv/bin/python"
JOB_WT="$WT_ROOT/wt-recon-final"
LOG="$RUNS/recon-final.log"
PIDFILE="$RUNS/recon-final.pid"
JOINT_REVISION=18  # the frozen candidate; the job refuses code with another revision
R22=docs/results/survey-conditions-final-r22
RJ=docs/results/survey-conditions-final-joint18
W22="$WORK/work-r22"
WJ="$WORK/work-joint18"

die() { echo "error: $*" >&2; exit 1; }
need_py() { [ -x "$PY" ] || die "no Python at $PY (set PY to the project's interpreter)"; }
note() { echo "$(date -u +%FT%TZ) $*" >>"$LOG"; }
count() { { find "$1/scans" -maxdepth 1 -name '[0-9]*.json' 2>/dev/null || true; } | wc -l; }

running() {
  [ -f "$PIDFILE" ] && kill -0 "$(cat "$PIDFILE")" 2>/dev/null \
    && tr '\0' ' ' <"/proc/$(cat "$PIDFILE")/cmdline" | grep -q "recon_final.sh _loop"
}

# the seeds whose cloud_sha256 differs between the two records (on the scans both have), one a line
cloud_mismatches() {
  local a="$1/scans" b="$2/scans" f sha_a sha_b
  for f in "$b"/[0-9]*.json; do
    [ -f "$f" ] && [ -f "$a/${f##*/}" ] || continue
    sha_a="$(jq -r .cloud_sha256 "$a/${f##*/}")"; sha_b="$(jq -r .cloud_sha256 "$f")"
    [ "$sha_a" = "$sha_b" ] || echo "${f##*/}"
  done
}

shared() {
  local n=0 f
  for f in "$2/scans"/[0-9]*.json; do [ -f "$f" ] && [ -f "$1/scans/${f##*/}" ] && n=$((n + 1)); done
  echo "$n"
}

# the scans rules22 has a record of, their scan and stereo-cloud files (not its reconstructions)
# hard-linked into the joint work cache; cloud_time.json last, so a scan cut off midway is linked again
link_scans() {
  local f seed src dst e
  for f in "$JOB_WT/$R22/scans"/[0-9]*.json; do
    [ -f "$f" ] || continue
    seed="$(basename "$f" .json)"; src="$W22/scan_$seed"; dst="$WJ/scan_$seed"
    [ -f "$dst/cloud_time.json" ] && continue
    [ -f "$src/cloud_time.json" ] || die "rules22 has a record of $seed but no stereo cloud in $src"
    mkdir -p "$dst"
    for e in "$src"/*; do
      case "${e##*/}" in recon_*|cloud_time.json) continue ;; esac
      cp -alf "$e" "$dst/"
    done
    cp -alf "$src/cloud_time.json" "$dst/"
  done
}

bench_step() {  # estimator n work out
  local before after t
  before="$(count "$JOB_WT/$4")"
  t="$(mktemp)"
  if ! { TIMEFORMAT='%R %U %S'; time "$PY" bench/bench_reconstruct.py --survey-set final \
      --survey-scans "$2" --survey-estimator "$1" --survey-work "$3" --survey-out "$4" \
      >>"$WORK/bench-sealed.log" 2>&1; } 2>"$t"; then
    note "$1 to $2 scans: the bench failed (its output: $WORK/bench-sealed.log); the job stops"
    rm -f "$t"; exit 1
  fi
  after="$(count "$JOB_WT/$4")"
  read -r wall user sys <"$t"; rm -f "$t"
  note "$1 to $2: +$((after - before)) scans ($after in its record), wall ${wall%.*} s, CPU $(awk "BEGIN{printf \"%.0f\", $user + $sys}") s, load $(cut -d' ' -f1-3 /proc/loadavg)"
}

loop() {  # runs in the job's worktree, started by `start`
  exec 9>"$WORK/job.lock"
  flock -n 9 || die "another recon-final job holds $WORK/job.lock"
  echo "$$" >"$PIDFILE"
  export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONPATH="$JOB_WT"
  local rev n
  rev="$("$PY" -c 'from reconstruct.fitting.joint_config import JOINT_REVISION; print(JOINT_REVISION)')"
  [ "$rev" = "$JOINT_REVISION" ] || { note "JOINT_REVISION is $rev, not $JOINT_REVISION: the job stops"; exit 1; }
  note "job $$ at $(git -C "$JOB_WT" rev-parse --short HEAD): to $TARGET scans in steps of $STEP, load $(cut -d' ' -f1-3 /proc/loadavg)"
  n=$(( $(count "$JOB_WT/$R22") < $(count "$JOB_WT/$RJ") ? $(count "$JOB_WT/$R22") : $(count "$JOB_WT/$RJ") ))
  n=$(( n / STEP * STEP ))  # a resumed job starts at the last step both records had finished
  while [ "$n" -lt "$TARGET" ]; do
    n=$((n + STEP)); [ "$n" -gt "$TARGET" ] && n="$TARGET"
    bench_step rules22 "$n" "$W22" "$R22"
    link_scans
    bench_step joint "$n" "$WJ" "$RJ"
    note "step $n: clouds differing on shared scans: $(cloud_mismatches "$JOB_WT/$R22" "$JOB_WT/$RJ" | wc -l)"
  done
  note "job $$ done: $(count "$JOB_WT/$R22") rules22 and $(count "$JOB_WT/$RJ") joint18 scans"
}

start() {
  need_py
  mkdir -p "$RUNS" "$W22" "$WJ"
  running && { echo "recon-final: already running (pid $(cat "$PIDFILE"))"; return; }
  [ -d "$JOB_WT" ] || git -C "$ROOT" worktree add --quiet --detach "$JOB_WT" HEAD
  [ -f "$JOB_WT/scripts/recon_final.sh" ] || die "$JOB_WT has no scripts/recon_final.sh (an older commit?)"
  (cd "$JOB_WT" && WORK="$WORK" RUNS="$RUNS" TARGET="$TARGET" STEP="$STEP" PY="$PY" \
    nohup setsid -f nice -n 10 bash scripts/recon_final.sh _loop >>"$LOG" 2>&1 </dev/null)
  for _ in 1 2 3 4 5 6 7 8 9 10; do running && break; sleep 1; done
  running || die "the job did not start; see $LOG"
  echo "recon-final: started in $JOB_WT at $(git -C "$JOB_WT" rev-parse --short HEAD) (pid $(cat "$PIDFILE"), log $LOG)"
}

stop() {
  running || die "no recon-final job runs (pid file $PIDFILE)"
  kill -- "-$(cat "$PIDFILE")"
  note "job $(cat "$PIDFILE") stopped (scripts/recon_final.sh stop)"
  echo "recon-final: stopped job $(cat "$PIDFILE")"
}

sync_records() {
  local rec src
  need_py
  for rec in "$R22" "$RJ"; do
    [ "$(count "$JOB_WT/$rec")" -gt 0 ] || die "no finished scan record in $JOB_WT/$rec/scans to sync (run: $0 start)"
  done
  for rec in "$R22" "$RJ"; do
    src="$JOB_WT/$rec/scans"
    mkdir -p "$ROOT/$rec/scans"
    # the bench writes each scan record atomically (a dot-named temp file, then a rename): every
    # [0-9]*.json is whole
    find "$src" -maxdepth 1 -name '[0-9]*.json' -exec cp -p {} "$ROOT/$rec/scans/" \;
    (cd "$ROOT" && PYTHONPATH="$ROOT" "$PY" -c \
      'import sys; from pathlib import Path; from experiments.survey_conditions import read_survey_records; read_survey_records(Path(sys.argv[1]))' \
      "$rec")
    echo "$rec: $(count "$ROOT/$rec") scans"
  done
  report_clouds "$ROOT"
}

report_clouds() {
  local bad
  bad="$(cloud_mismatches "$1/$R22" "$1/$RJ" | wc -l)"
  echo "shared scans: $(shared "$1/$R22" "$1/$RJ"), of them with different stereo clouds: $bad"
  [ "$bad" -eq 0 ] || die "the records disagree on cloud_sha256 for $bad scans: the joint run did not reuse rules22's clouds"
}

status() {
  local state="stopped"
  running && state="running (pid $(cat "$PIDFILE"))"
  echo "recon-final: $state; log $LOG"
  for rec in "$R22" "$RJ"; do
    echo "$rec: $(count "$ROOT/$rec") scans here, $(count "$JOB_WT/$rec") in $JOB_WT (target $TARGET)"
  done
  [ -d "$JOB_WT/$RJ/scans" ] && report_clouds "$JOB_WT"
  grep -v '^$' "$LOG" 2>/dev/null | tail -2 || true
}

case "${1:-}" in
  start) start ;;
  sync) sync_records ;;
  status) status ;;
  stop) stop ;;
  _loop) loop ;;
  *) echo "usage: $0 start|sync|status|stop (got: ${1:-nothing})" >&2; exit 2 ;;
esac
