#!/usr/bin/env python3
"""Plant plausible one-line bugs in a copy of the tree and check that the test suite catches them.

For each mutation in MUTATIONS below, the script copies the working tree (tracked and untracked,
not ignored files; never touching the tree itself) into a temporary folder, replaces one exact
piece of source text there, runs the test files that should guard it, and reports

    caught   the tests failed (the first failing assertion is shown)
    MISSED   the tests passed (or skipped) with the bug in place
    stale    the source text is no longer found exactly once: update the table
    error    pytest could not run (collection error, timeout)

Before the mutations the same test files are run on the unchanged copy: a mutation only counts as
caught if its tests pass without it (a failing baseline is reported and stops the run).

    python scripts/mutation_check.py                    # every mutation
    python scripts/mutation_check.py --list             # the table
    python scripts/mutation_check.py --only f3-reads-w  # some of them
    python scripts/mutation_check.py --quick            # only each entry's dedicated test file
    python scripts/mutation_check.py --tests-from main  # the tests of another commit on today's code

``--tests-from REF`` replaces the copy's ``tests/`` by that commit's (``git archive``): how the
suite of REF fares against the same bugs (test files REF does not have are left out).

After a refactor, update ``file``/``find`` (and ``tests``) of each entry to where the code lives.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Mutation:
    id: str
    what: str  # the regression, in words
    file: str  # repository-relative path of the mutated module
    find: str  # exact source text, present exactly once
    replace: str  # what it becomes
    tests: tuple[str, ...]  # test files (or node ids) that must catch it
    env: str | None = None  # an ENVIRONMENTS key: the machine the tests run on


M = Mutation
# ------------------------------------------------------------------------------------------------
# The mutation table. One entry, one planted bug.
# ------------------------------------------------------------------------------------------------
MUTATIONS: tuple[Mutation, ...] = (
    M("atomic-writer-plain", "the shared atomic writer writes in place",
      "synth/common/files.py", 'fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)',
      "path.write_bytes(data); return",
      ("tests/synth/common/test_atomic_writes.py", "tests/synth/scene/test_pile.py", "tests/synth/data/test_dataset.py")),
    M("dataset-write-plain", "the data set's write seam (shards, done records, manifest) writes in place",
      "synth/data/shards.py", "    atomic_write_bytes(path, data)\n", "    path.write_bytes(data)\n",
      ("tests/synth/common/test_atomic_writes.py", "tests/synth/data/test_dataset.py")),
    M("versioned-json-write-plain", "every versioned JSON artifact (pile.json, manifests, plans, records) is written in place",
      "synth/common/formats.py", "atomic_write_bytes(path, self.dumps(body, indent=indent, **kw).encode())",
      "path.write_bytes(self.dumps(body, indent=indent, **kw).encode())",
      ("tests/synth/common/test_atomic_writes.py", "tests/synth/scene/test_pile.py")),
    M("checkpoint-write-plain", "save_tensors (checkpoints, training state) writes in place",
      "planner/checkpoint.py", "atomic_write_bytes(path, data)", "path.write_bytes(data)",
      ("tests/synth/common/test_atomic_writes.py", "tests/planner/test_planner_inference.py")),
    M("geojson-write-plain", "write_geojson writes in place (no behavioural test reaches it)",
      "field/geo.py", 'atomic_write_bytes(path, json.dumps(fc, indent=1).encode("utf-8"))',
      'path.write_bytes(json.dumps(fc, indent=1).encode("utf-8"))',
      ("tests/synth/common/test_atomic_writes.py", "tests/field/test_geo.py")),
    M("resume-checksum-off", "resuming a data set no longer checks finished shards' sha256",
      "synth/data/dataset.py", "check_shard_file(out / info.file, info, checksum=True)",
      "check_shard_file(out / info.file, info, checksum=False)",
      ("tests/synth/data/test_dataset_resume_checksum.py", "tests/synth/data/test_dataset.py")),
    M("loss-lambda-w-dropped", "the lambda_W width term is left out of the loss",
      "planner/loss.py", " + weights.lambda_w * lw", "",
      ("tests/planner/test_loss_terms.py", "tests/planner/test_planner_loss_augment.py")),
    M("loss-u-pos-weight-dropped", "u_pos_weight no longer weighs the BCE",
      "planner/loss.py", "pred[:, 3], u, pos_weight=pos_weight)", "pred[:, 3], u)",
      ("tests/planner/test_loss_terms.py", "tests/planner/test_planner_loss_augment.py")),
    M("train-ignores-loss-config", "training steps use the default loss weights, not TrainConfig.loss",
      "planner/train.py", "loss, parts = grasp_loss(pred, y, config.loss)", "loss, parts = grasp_loss(pred, y)",
      ("tests/planner/test_loss_terms.py", "tests/planner/test_planner_train.py")),
    M("mirror-view-sin-sign", "the mirrored test-time view is mapped back without negating sin 2phi",
      "planner/inference.py", "        y[:, 1] *= -1.0", "        y[:, 1] *= 1.0",
      ("tests/planner/test_views_equivariance.py", "tests/planner/test_planner_inference.py")),
    M("quarter-turn-sign", "a quarter-turned test-time view is mapped back without turning (C, S)",
      "planner/inference.py", "        y[:, 0:2] *= -1.0", "        y[:, 0:2] *= 1.0",
      ("tests/planner/test_views_equivariance.py", "tests/planner/test_planner_inference.py")),
    M("f3-reads-w", "f3 (and the reported balance) read the W channel instead of B",
      "planner/inference.py", "np.ascontiguousarray(out[:, 4], dtype=np.float32)",
      "np.ascontiguousarray(out[:, 2], dtype=np.float32)",
      ("tests/planner/test_objective_channels.py", "tests/planner/test_planner_inference.py")),
    M("subset-slack-removed", "the subset pre-selection's slack for the sparse candidate centres is removed",
      "planner/subsets.py", "R = policy.fit_radius_m + slack", "R = policy.fit_radius_m",
      ("tests/planner/test_subset_slack.py", "tests/planner/test_planner_inference.py")),
    M("rh2000-ballpark", "RH 2000 heights fall back to PROJ's ballpark (ellipsoidal) without the geoid grid",
      "synth/geometry/geodesy.py", "    t = _rh2000_transformer()\n",
      '    t = _transformer(EPSG_SWEREF99_3D, f"{EPSG_SWEREF99}+5613")\n',
      ("tests/synth/geometry/test_rh2000_refusal.py", "tests/synth/geometry/test_geodesy.py")),
    M("rh2000-ballpark-on-a-grid-machine", "the same, tested on a machine that has the geoid grid installed",
      "synth/geometry/geodesy.py", "    t = _rh2000_transformer()\n",
      '    t = _transformer(EPSG_SWEREF99_3D, f"{EPSG_SWEREF99}+5613")\n',
      ("tests/synth/geometry/test_rh2000_refusal.py", "tests/synth/geometry/test_geodesy.py"), env="geoid-grid"),
    # -- the crane link ----------------------------------------------------------------------------
    M("busy-id-not-burned", "a command id rejected as BUSY is not burned (it could run once the crane is idle)",
      "field/controller/core.py", "            if known is None:\n                self._burn(cmd.command_id, reason, digest)",
      "            if known is None and reason is not RejectReason.BUSY:\n"
      "                self._burn(cmd.command_id, reason, digest)",
      ("tests/field/test_link_safety.py::test_an_id_rejected_busy_stays_burned_across_a_restart",
       "tests/field/test_controller_checks.py")),
    M("laptop-future-skew-off", "the laptop no longer refuses plans timestamped in its future",
      "field/link/safety.py", "if age > self.config.max_pile_age_s or age < -self.config.max_future_skew_s:",
      "if age > self.config.max_pile_age_s:",
      ("tests/field/test_link_guard.py", "tests/field/test_link_contract.py")),
    # -- guards of the tests that could not fail -------------------------------------------------
    M("real-test-angle-half-period", "the real test's angle difference wraps at 90 deg instead of 180",
      "experiments/real_test.py", "d = (a - b + math.pi / 2) % math.pi - math.pi / 2",
      "d = (a - b) % (math.pi / 2)",
      ("tests/experiments/test_real_test_angles.py",
       "tests/experiments/test_real_test.py::test_summary_counts_and_paired_uncertainty")),
    M("validation-split-per-process", "the by-pile split uses Python's per-process hash()",
      "planner/data.py", 'digest = hashlib.blake2b(f"{seed}:{pile_id}".encode(), digest_size=8).digest()',
      'digest = (hash(f"{seed}:{pile_id}") % 2 ** 64).to_bytes(8, "little")',
      ("tests/planner/test_planner_train.py::test_split_is_by_pile_and_deterministic",)),
    M("cli-slow-import", "`loggrasp --help` imports dask.distributed (0.2-0.8 s of CPU)",
      "field/cli/__init__.py", "import typer\n", "import typer\nimport distributed  # noqa: F401\n",
      ("tests/test_cli_startup.py", "tests/test_cli.py::test_help_is_fast_and_imports_nothing_heavy")),
    # -- ROS 2 over Zenoh and the trial's Foxglove recording -------------------------------------------
    M("ros2-cdr-unaligned", "the CDR writer does not align float64 to 8 bytes",
      "field/ros2.py", "        for v in vs:\n            self._align(8)\n", "        for v in vs:\n",
      ("tests/field/test_ros2.py",)),
    M("ros2-key-type-name", "the key expression's DDS type name lacks rmw's trailing underscore",
      "field/ros2.py", 'return f"{pkg}::{kind}::dds_::{leaf}_"', 'return f"{pkg}::{kind}::dds_::{leaf}"',
      ("tests/field/test_ros2.py",)),
    M("ros2-yaw-sign", "the grasp pose's yaw is heading - 90 deg (clockwise) instead of 90 deg - heading",
      "field/ros2.py", "yaw = math.radians(90.0 - heading_grid_deg)", "yaw = math.radians(heading_grid_deg - 90.0)",
      ("tests/field/test_ros2.py",)),
    M("trial-publishes-no-ros2", "a trial over zenoh:// publishes no ROS 2 grasp",
      "field/trial.py", "        if ros2 is not None and ros2() is not None:", "        if False:",
      ("tests/field/test_field_trial.py::test_trial_over_zenoh_loopback",)),
    M("view-times-go-back", "the recording logs a late message at its own earlier time (a topic's times go back)",
      "field/trial_view.py", "t = max(_ns(t_s), self._last_ns.get(topic, 0))", "t = _ns(t_s)",
      ("tests/field/test_trial_view.py",)),
    M("view-failure-stops-trial", "a failure to log raises into the trial",
      "field/trial_view.py", '            self.errors.append(f"{what}: {type(exc).__name__}: {exc}")\n', "            raise\n",
      ("tests/field/test_trial_view.py",)),
    M("view-no-can-frames", "the trial's recording leaves out the CAN frames",
      "field/trial_record.py", "                self.view.can_traffic(traffic, secured=",
      "                0 and self.view.can_traffic(traffic, secured=",
      ("tests/field/test_field_trial.py::test_trial_mcap_reads_back_with_an_independent_reader",)),
    M("zenoh-token-not-rechecked", "a laptop token's undeclaration is not re-checked (a stale one strands a live laptop)",
      "field/link/zenoh_backend.py", 'name="zenoh-laptop-recheck").start()', 'name="zenoh-laptop-recheck")',
      ("tests/field/test_link_zenoh.py::test_a_stale_token_undeclaration_aborts_but_does_not_strand_a_live_laptop",)),
    M("zenoh-recheck-ignores-newer-event", "a token re-check's answer revives a laptop whose token went again since",
      "field/link/zenoh_backend.py", "if live and not self._closed and self._laptop_events.get(peer) == event:",
      "if live and not self._closed:",
      ("tests/field/test_link_zenoh.py::test_a_token_event_newer_than_the_recheck_wins_over_its_answer",)),
    # issue 39: each safety-case cell fails when its measure is removed; the records' hash chain
    M("e2e-crc-unchecked", "frames are decoded without their E2E CRC check (corruption cells)",
      "field/link/codec.py", "    if not e2e_p05_check(data, data_id(kind)):\n", "    if False:\n",
      ("tests/field/test_link_faults.py::test_corrupted_command_frame_is_answered_for_nobody",
       "tests/field/test_safety_case_links.py::test_zenoh_corrupted_command_is_answered_for_nobody")),
    M("e2e-data-id-shared", "every message kind has the same E2E data id (addressing cells)",
      "field/link/codec.py", '    return int(_message(kind).dbc.attributes["E2EDataID"].value)\n', "    return 1\n",
      ("tests/field/test_safety_case_links.py::test_zenoh_frame_of_another_kind_at_the_command_key_is_rejected",
       "tests/field/test_safety_case_links.py::test_can_frame_of_another_kind_on_the_command_id_is_rejected")),
    M("counter-sequence-ignored", "an out-of-sequence command counter is not rejected (incorrect sequence cells)",
      "field/controller/core.py", "        if out_of_sequence:\n            return RejectReason.COUNTER\n", "",
      ("tests/field/test_link_faults.py::test_reordered_late_command_is_never_executed",
       "tests/field/test_safety_case_links.py::test_zenoh_reordered_late_command_is_never_executed")),
    M("counter-repeat-decided", "a repeated command counter (a copy) is decided again, not dropped (repetition cells)",
      "field/controller/core.py", "        if check is CounterCheck.REPEATED:\n", "        if False:\n",
      ("tests/field/test_link_faults.py::test_duplicated_command_frame_executes_once",
       "tests/field/test_safety_case_links.py::test_zenoh_duplicated_command_executes_once")),
    M("revocation-off", "a command left without an acknowledgement is not revoked (unacceptable delay cells)",
      "field/link/base.py", "ack = self._revoke(cmd)", "ack = None",
      ("tests/field/test_link_safety.py::test_a_command_delayed_past_its_timeout_never_runs_after_the_operator_was_"
       "told_it_did_not",
       "tests/field/test_safety_case_links.py::test_zenoh_command_delayed_past_its_timeout_never_runs")),
    M("secoc-mac-unchecked", "an authenticated frame's MAC is not compared (insertion and masquerade cells)",
      "field/link/secoc.py",
      "if not hmac.compare_digest(mac, self._mac(kind, pdu, fv)) or any(data[n + TRAILER_BYTES:]):",
      "if any(data[n + TRAILER_BYTES:]):",
      ("tests/field/test_link_secoc.py::test_forged_frames_are_dropped_on_both_sides",
       "tests/field/test_link_secoc.py::test_a_crane_with_another_key_is_not_reached")),
    M("audit-prev-unchecked", "a chained line's prev is not compared with the previous line's hash",
      "field/audit/chain.py", "    if obj.get(PREV_KEY) != prev:\n", "    if False:\n", ("tests/field/test_audit.py",)),
    M("audit-canonical-unchecked", "a chained line whose bytes are not canonical is accepted",
      "field/audit/chain.py", "    if canonical(obj).encode() != line:\n", "    if False:\n",
      ("tests/field/test_audit.py",)),
    M("audit-torn-tail-kept", "a torn last line is left in place and appended after",
      "field/audit/chain.py", "        if check.torn_tail:\n", "        if False:\n", ("tests/field/test_audit.py",)),
    M("audit-record-json-unsealed", "record.json is not compared with its sealed sha256",
      "field/audit/record.py", 'if last is not None and entries[last].get("sha256") == sha:', "if last is not None:",
      ("tests/field/test_audit.py",)),
    M("audit-files-unchecked", "a trial record's files are not compared with the chain",
      "field/audit/record.py", "    if problems:\n", "    if False:\n", ("tests/field/test_audit.py",)),
    M("audit-journal-unchained", "the controller journal appends plain lines, outside the chain",
      "field/controller/journal.py", "        self._chain.append(entry)  # one write of a whole line, fsynced\n",
      "        open(self.path, 'a').write(json.dumps(entry) + '\\n')\n", ("tests/field/test_audit.py",)),
)


# ------------------------------------------------------------------------------------------------
# environments: what the machine the tests run on has installed
# ------------------------------------------------------------------------------------------------
def _geoid_grid_env(copy: Path, scratch: Path) -> dict[str, str]:
    """A machine with the SWEN17_RH2000 geoid grid: a stand-in grid in PROJ's user folder (written
    by the working tree's tests/synth/geometry/geoid_stand_in.py, whatever tests the copy has)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("geoid_stand_in", REPO / "tests/synth/geometry/geoid_stand_in.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    folder = scratch / "proj-user"
    mod.write_stand_in_geoid(folder)
    return {"PROJ_USER_WRITABLE_DIRECTORY": str(folder)}


ENVIRONMENTS = {"geoid-grid": _geoid_grid_env}


# ------------------------------------------------------------------------------------------------
def copy_tree(dest: Path) -> None:
    """The working tree's tracked and untracked, not ignored files (no .git) into ``dest``."""
    out = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=REPO,
                         capture_output=True, check=True).stdout
    for rel in sorted({p for p in out.decode().split("\0") if p}):
        src = REPO / rel
        if src.is_file():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)


def replace_tests(dest: Path, ref: str) -> None:
    data = subprocess.run(["git", "archive", "--format=tar", ref, "tests"], cwd=REPO, capture_output=True,
                          check=True).stdout
    shutil.rmtree(dest / "tests", ignore_errors=True)
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        tar.extractall(dest, filter="data")


def _exists(copy: Path, test: str) -> bool:
    return (copy / test.split("::")[0]).is_file()


def run_pytest(copy: Path, tests: list[str], python: str, timeout_s: float, extra_env: dict) -> tuple[int, str, float]:
    env = {**os.environ, "PYTHONPATH": str(copy), "PYTHONDONTWRITEBYTECODE": "1", **extra_env}
    cmd = [python, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", "-rfEs", *tests]
    t0 = time.perf_counter()
    try:
        r = subprocess.run(cmd, cwd=copy, env=env, capture_output=True, text=True, timeout=timeout_s)
        return r.returncode, r.stdout + r.stderr, time.perf_counter() - t0
    except subprocess.TimeoutExpired as exc:
        return -1, f"timed out after {timeout_s:.0f} s\n{exc.stdout or ''}", time.perf_counter() - t0


def first_failure(output: str) -> str:
    """The first failing test and its assertion, in one line."""
    test = next((m.group(1) for m in re.finditer(r"^FAILED (\S+)", output, re.M)), "")
    errs = [ln[1:].strip() for ln in output.splitlines() if ln.startswith("E ") and ln[1:].strip()]
    err = " ".join(errs[:2]) if errs and re.fullmatch(r"\w+(Error|Exception):?", errs[0]) else (errs or [""])[0]
    return f"{test.split('/')[-1]}: {err}"[:240]


def summary_line(output: str) -> str:
    lines = [ln for ln in output.strip().splitlines() if re.search(r"\d+ (passed|failed|skipped|error)", ln)]
    if lines:
        return lines[-1].strip("= ")
    return (output.strip().splitlines() or [""])[-1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="+", metavar="ID", help="run only these mutations")
    ap.add_argument("--list", action="store_true", help="print the mutation table and exit")
    ap.add_argument("--tests-from", metavar="REF", help="use the tests/ of this git commit")
    ap.add_argument("--python", default=sys.executable, help="interpreter with the project's dependencies")
    ap.add_argument("--timeout", type=float, default=900.0, help="per pytest run [s]")
    ap.add_argument("--quick", action="store_true", help="run only each entry's first (dedicated) test file")
    ap.add_argument("--json", metavar="PATH", help="also write the results as JSON")
    ap.add_argument("--keep", action="store_true", help="keep the temporary copy")
    a = ap.parse_args(argv)

    chosen = [m for m in MUTATIONS if not a.only or m.id in a.only]
    if a.quick:
        from dataclasses import replace

        chosen = [replace(m, tests=m.tests[:1]) for m in chosen]
    unknown = set(a.only or ()) - {m.id for m in MUTATIONS}
    if unknown:
        ap.error(f"unknown mutation ids: {sorted(unknown)}")
    if a.list:
        for m in chosen:
            print(f"{m.id:36s} {m.file:24s} {m.what}" + (f"  [on: {m.env}]" if m.env else ""))
        return 0

    tmp = Path(tempfile.mkdtemp(prefix="loggrasp-mutation-"))
    copy, scratch = tmp / "tree", tmp / "scratch"
    copy.mkdir(), scratch.mkdir()
    results = []
    try:
        copy_tree(copy)
        if a.tests_from:
            replace_tests(copy, a.tests_from)
        envs = {name: ENVIRONMENTS[name](copy, scratch / name) for name in {m.env for m in chosen if m.env}}
        # baseline: every test set passes on the unchanged copy, on each environment used
        for env_name in sorted({m.env or "" for m in chosen}):
            tests = sorted({t for m in chosen if (m.env or "") == env_name for t in m.tests if _exists(copy, t)})
            rc, out, wall = run_pytest(copy, tests, a.python, a.timeout, envs.get(env_name, {}))
            print(f"baseline{' on ' + env_name if env_name else ''}: {summary_line(out)} ({wall:.0f} s)", flush=True)
            if rc != 0:
                print(out[-4000:])
                print("the baseline fails: fix the suite first", file=sys.stderr)
                return 2
        for m in chosen:
            path = copy / m.file
            original = path.read_text()
            n = original.count(m.find)
            tests = [t for t in m.tests if _exists(copy, t)]
            row = {"id": m.id, "what": m.what, "file": m.file, "env": m.env, "tests": tests}
            if n != 1:
                row.update(result="stale", detail=f"the text to replace occurs {n} times in {m.file}")
            elif not tests:
                row.update(result="MISSED", detail="no test file of this entry exists")
            else:
                mutated = original.replace(m.find, m.replace)
                try:
                    compile(mutated, str(path), "exec")
                except SyntaxError as exc:
                    row.update(result="stale", detail=f"the mutated {m.file} does not compile: {exc}")
                    results.append(row)
                    print(f"stale   {m.id}: {row['detail']}", flush=True)
                    continue
                path.write_text(mutated)
                try:
                    rc, out, wall = run_pytest(copy, tests, a.python, a.timeout, envs.get(m.env, {}))
                finally:
                    path.write_text(original)
                row["wall_s"] = round(wall, 1)
                if rc == 1 and re.search(r"^FAILED ", out, re.M):
                    row.update(result="caught", detail=first_failure(out))
                elif rc == 0:
                    row.update(result="MISSED", detail=summary_line(out))
                else:
                    row.update(result="error", detail=f"pytest exit {rc}: {summary_line(out)}")
            results.append(row)
            print(f"{row['result']:7s} {m.id}: {row['detail']}", flush=True)
    finally:
        if a.keep:
            print(f"copy kept in {tmp}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)

    print()
    print("| mutation | file | result | by (first failure) |")
    print("|---|---|---|---|")
    for r in results:
        on = f" (on: {r['env']})" if r["env"] else ""
        print(f"| {r['id']}{on} | {r['file']} | {r['result']} | {r['detail'].replace('|', '/')} |")
    n_caught = sum(r["result"] == "caught" for r in results)
    print(f"\n{n_caught} of {len(results)} caught" + (f" (tests from {a.tests_from})" if a.tests_from else ""))
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=1))
    return 0 if n_caught == len(results) else 1


if __name__ == "__main__":
    sys.exit(main())
