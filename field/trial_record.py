"""The trial record: what a field trial (:mod:`field.trial`) did, written as it goes, and its replay.

:func:`run_trial_record` probes the crane link first, then prepares and executes the trial and
writes the *trial record*: built in a temporary sibling folder until the plan is ready, then
renamed into place, after which ``record.json`` (replaced atomically) always says how far the trial
got (``AWAITING CONFIRMATION``, ``SENDING``, the final state; ``NOT SENT`` with the reason for a
trial that was refused, declined, not answered or interrupted). :func:`read_record` reads it back;
:func:`replay_record` checks the recorded inputs' sha256, re-runs reconstruction and planning from
them and says whether the command is bit-identical.

Trial record (``loggrasp.trial-record`` 1.3)::

    RECORD/record.json        versions, input hashes, options, plan, command, messages, outcome
    RECORD/inputs/scan/...    copies of the scan and the GNSS file as used
    RECORD/inputs/gnss.csv        (raw receiver logs: the survey averaged from them, dated like them)
    RECORD/inputs/gnss-raw/...    the raw logs and their time-window file, when those were given
    RECORD/reconstruction/    pile.json, ortho.npz, preview.png, compare.png, report.json
    RECORD/plan/              plan.json, plan.png, grasp_map.png, pile.geojson, pile.sweref99tm.geojson
    RECORD/link/traffic.blf   every CAN frame of the session (CAN links)
    RECORD/audit.jsonl        hash chain of every file and record.json step (field/audit/record.py)
    RECORD/trial.mcap         the trial in time for Foxglove: scan, pile, plan, verification, command,
                              CAN frames with their signals, the crane's state (:mod:`field.trial_view`)
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from dataclasses import asdict
from pathlib import Path
from typing import Callable

from field.audit.record import RecordSeal
from field.errors import FieldError
from field.trial import (REJECT_EXPLANATIONS, NotVerified, PreparedTrial, TrialAborted, TrialOptions, TrialOutcome,
                         captured_time, execute_trial, prepare_trial, probe_link, software_versions)
from synth.common.files import sha256_file as sha256_of
from synth.common.formats import VersionedJson

RECORD_FORMAT = "loggrasp.trial-record"
RECORD_VERSION = "1.3"  # 1.1: verification, chosen_rank, verified (a 1.0 record was never verified);
# 1.2: view and view_errors (trial.mcap beside record.json); 1.3: audit (audit.jsonl hash chain)


def _stage_record(record_dir: Path) -> Path:
    """A temporary sibling folder the record is built in (modes as the umask says)."""
    if record_dir.exists():
        raise TrialAborted(f"trial record {record_dir} already exists; choose a new --record folder", kind="input")
    record_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{record_dir.name}.", suffix=".tmp", dir=record_dir.parent))
    from synth.common.files import apply_umask

    apply_umask(tmp, directory=True)
    return tmp


def run_trial_record(scan_dir: str | Path, gnss_path: str | Path, link_url: str, record_dir: str | Path,
                     options: TrialOptions, confirm: Callable[[PreparedTrial], bool] | None = None,
                     progress: Callable[[str], None] | None = None, now: float | None = None,
                     probe: bool = True, foxglove_port: int | None = None) -> dict:
    """The whole trial; returns the record dict.

    The record's ``trial.mcap`` is logged as the trial runs (:class:`field.trial_view.TrialView`)
    and, with ``foxglove_port``, served live on 127.0.0.1 at that port (a port in use:
    :class:`TrialAborted` ``kind="input"`` before anything else).

    First the crane link is probed (:func:`probe_link`; nothing is written when it fails). The
    record is built in a temporary sibling folder until the plan is ready, then renamed to
    ``record_dir``; from then on ``record.json`` (replaced atomically) always says how far the
    trial got: ``AWAITING CONFIRMATION`` while ``confirm(prepared)`` asks the operator (the
    pictures it names are in ``record_dir/plan/``), ``SENDING`` (with the command) before
    anything goes on the link, then the final state. A trial that stops before sending —
    refused by a safety check, declined, no answer, Ctrl-C — leaves a complete record with
    ``final_state`` ``NOT SENT`` and the reason, and raises :class:`TrialAborted` (Ctrl-C:
    ``KeyboardInterrupt``). ``confirm`` None means already confirmed (``--yes``); it may raise
    :class:`TrialAborted` (e.g. no answer)."""
    say = progress or (lambda s: None)
    scan_dir, record_dir = Path(scan_dir), Path(record_dir)
    gnss_path = gnss_path if hasattr(gnss_path, "windows") else Path(gnss_path)  # a RawGnss stays one
    if record_dir.exists():
        raise TrialAborted(f"trial record {record_dir} already exists; choose a new --record folder", kind="input")
    from field.trial_view import ViewError, open_live_view, record_view

    try:
        live = open_live_view(record_dir, foxglove_port)
    except ViewError as exc:
        raise TrialAborted(str(exc), kind="input") from exc
    try:
        if probe:
            say(f"crane link {link_url}: controller {probe_link(link_url, options)}")
        tmp = _stage_record(record_dir)
    except BaseException:
        if live is not None:
            live.close(None)
        raise
    rec = _TrialRecord(record_dir, tmp, link_url, options, view=record_view(tmp, live, say))
    say = rec.in_final_words(say)
    try:
        rec.copy_inputs(scan_dir, gnss_path, say)
        prepared = rec.prepare(say, now)
        rec.confirm(prepared, confirm)
        outcome = rec.send(prepared, say)
        rec.finish(outcome)
        return rec.record
    except TrialAborted as exc:
        rec.stopped(exc)
        raise
    except KeyboardInterrupt:
        rec.interrupted()
        raise
    except BaseException as exc:
        rec.failed(exc)
        raise
    finally:
        rec.close_view()


def _record_raw_survey(raw, inputs: Path, allow_float: bool) -> None:
    """Raw receiver logs (a :class:`reconstruct.survey.windows.RawGnss`) into the record: the logs
    and windows under ``gnss-raw/``, the survey averaged from them as ``gnss.csv`` (what the trial and
    its replay read), dated like its newest raw file so the pile's age check sees the capture time."""
    from reconstruct.survey.gnss import read_gnss, write_gnss_csv

    survey = read_gnss(raw, allow_float=allow_float, require_both_ends=False)
    (inputs / "gnss-raw").mkdir(parents=True)
    for k, p in enumerate([*raw.logs, raw.windows]):
        shutil.copy2(p, inputs / "gnss-raw" / f"{k}_{Path(p).name}")
    out = write_gnss_csv(survey, inputs / "gnss.csv")
    newest = max(Path(p).stat().st_mtime for p in [*raw.logs, raw.windows])
    os.utime(out, (newest, newest))


_STATES_BEFORE_SENDING = ("SENDING", "AWAITING CONFIRMATION", "CONFIRMED (--yes)")


class _TrialRecord:
    """A field trial's record while it runs: ``record.json`` rewritten atomically at each step, in
    a temporary folder until the plan is ready (:meth:`publish`), then in ``record_dir``."""

    def __init__(self, record_dir: Path, tmp: Path, link_url: str, options: TrialOptions, view=None) -> None:
        self.record_dir, self.tmp, self.where = record_dir, tmp, tmp
        self.options, self.link_url, self.view = options, link_url, view
        self.record: dict = {"format": RECORD_FORMAT, "format_version": RECORD_VERSION, "versions": software_versions(),
                             "started_utc_s": time.time(), "link": link_url, "options": asdict(options),
                             "final_state": "PREPARING"}
        self._seal = RecordSeal()  # the record's hash chain, RECORD/audit.jsonl (field.audit.record)

    def in_final_words(self, say: Callable[[str], None]) -> Callable[[str], None]:
        """``say`` with the temporary folder named as the record folder it becomes (also logged
        to the trial's view)."""
        def said(text) -> None:
            text = str(text).replace(str(self.tmp), str(self.record_dir))
            if self.view is not None:
                self.view.line(text)
            say(text)

        return said

    def write(self, **changes) -> None:
        if self.view is not None and "final_state" in changes:
            self.view.state(changes["final_state"], time.time(), reason=changes.get("reason"))
        self.record.update(changes)
        self._seal.write(self.where, self.record)  # changed files and record.json chained, then written

    def publish(self) -> None:
        os.replace(self.tmp, self.record_dir)
        self.where = self.record_dir

    @property
    def published(self) -> bool:
        return self.where is not self.tmp

    def copy_inputs(self, scan_dir: Path, gnss_path: Path, say: Callable[[str], None]) -> None:
        """The scan and survey copied into the record, with their hashes and the model's."""
        from planner.checkpoint import DEFAULT_MODEL, DEFAULT_RANKER

        inputs = self.tmp / "inputs"
        say("copying the inputs into the record")
        shutil.copytree(scan_dir, inputs / "scan")
        if isinstance(gnss_path, Path):
            shutil.copy2(gnss_path, inputs / "gnss.csv")
        else:
            _record_raw_survey(gnss_path, inputs, self.options.allow_float)
        if self.view is not None:
            self.view.scan_images(inputs / "scan", captured_time(inputs / "scan", inputs / "gnss.csv"))
        model = Path(self.options.model or DEFAULT_MODEL)
        self.record["inputs"] = {"scan": str(scan_dir), "gnss": str(gnss_path),
                                 "hashes": {str(p.relative_to(inputs)): sha256_of(p)
                                            for p in sorted(inputs.rglob("*")) if p.is_file()}}
        self.record["model"] = {"path": str(model), "sha256": sha256_of(model) if model.exists() else None,
                                "precision": _precision_of(model, self.options.precision)}
        if self.options.rerank:
            ranker = Path(self.options.ranker or DEFAULT_RANKER)
            self.record["ranker"] = {"path": str(ranker), "sha256": sha256_of(ranker) if ranker.exists() else None}

    def prepare(self, say: Callable[[str], None], now: float | None) -> PreparedTrial:
        """:func:`prepare_trial` on the copied inputs; its plan, verification and command recorded
        and the record published. A trial stopped here is recorded NOT SENT (then re-raised)."""
        from synth.common.files import json_safe

        inputs = self.tmp / "inputs"
        try:
            prepared = prepare_trial(inputs / "scan", inputs / "gnss.csv", self.tmp, self.options, progress=say,
                                     now=now, view=self.view)
        except TrialAborted as exc:
            if exc.verification is not None:  # every trial the twin ran, and the plan they were of
                self.record["verification"] = json_safe(exc.verification.to_dict())
            if exc.plan is not None:
                self.record["plan"] = json.loads(exc.plan.to_json())
            self.write(final_state="NOT SENT", reason=str(exc), stopped=exc.kind, finished_utc_s=time.time())
            self.publish()
            raise
        self.record.update({
            "plan": json.loads(prepared.plan.to_json()),  # what plan/plan.json holds, not read back
            "verification": None if prepared.verification is None else json_safe(prepared.verification.to_dict()),
            "chosen_rank": prepared.chosen_rank, "verified": prepared.verified, "command": prepared.command_fields,
            "geo": prepared.geo.to_dict(), "pile_age_s": prepared.report.get("pile_age_s"),
            "warnings": prepared.warnings()})
        return prepared

    def confirm(self, prepared: PreparedTrial, confirm: Callable[[PreparedTrial], bool] | None) -> None:
        """Publish the record, then ask the operator (None: confirmed already)."""
        self.write(final_state="AWAITING CONFIRMATION" if confirm is not None else "CONFIRMED (--yes)")
        self.publish()
        prepared.work_dir = self.record_dir
        if confirm is None:
            return
        try:
            ok = confirm(prepared)
        except TrialAborted as exc:
            self.write(final_state="NOT SENT", reason=str(exc), stopped=exc.kind, finished_utc_s=time.time())
            raise
        if not ok:
            self.write(final_state="NOT SENT", reason="the operator declined", stopped="declined",
                       finished_utc_s=time.time())
            raise TrialAborted("the operator declined: nothing was sent", kind="declined")

    def send(self, prepared: PreparedTrial, say: Callable[[str], None]) -> TrialOutcome:
        traffic = None
        if self.link_url.startswith("can"):
            (self.record_dir / "link").mkdir(exist_ok=True)
            traffic = self.record_dir / "link" / "traffic.blf"
        self.write(final_state="SENDING", confirmed_utc_s=time.time())
        outcome = execute_trial(prepared, self.link_url, self.options, record_traffic=traffic, say=say,
                                view=self.view)
        if self.view is not None:
            self.view.events(outcome.messages)
            if traffic is not None and traffic.is_file():
                from urllib.parse import parse_qs, urlsplit

                self.view.can_traffic(traffic, secured="secoc_key" in parse_qs(urlsplit(self.link_url).query))
        return outcome

    def close_view(self) -> None:
        """Finish ``trial.mcap`` in the record folder (dropped with a record that was never
        published); problems the view had are noted in ``record.json`` (``view_errors``)."""
        view, self.view = self.view, None
        if view is None:
            return
        t0 = time.perf_counter()
        where = self.where if self.where.is_dir() else None
        try:
            path = view.close(where)
        except OSError as exc:
            view.errors.append(f"closing {view.part_path}: {exc}")
            path = None
        if where is not None and (path is not None or view.errors):
            self.write(view={"path": None if path is None else path.name, "messages": view.counts,
                             "log_s": view.busy_s, "close_s": time.perf_counter() - t0},  # what it cost [s]
                       **({"view_errors": view.errors} if view.errors else {}))

    def finish(self, outcome: TrialOutcome) -> None:
        changes = {"command_id": outcome.command_id, "accepted": outcome.accepted,
                   "reject_reason": outcome.reject_reason, "outcome": outcome.outcome,
                   "final_state": outcome.final_state, "messages": outcome.messages,
                   "finished_utc_s": time.time()}
        if outcome.reject_reason:
            changes["reason"] = (f"the crane rejected the command ({outcome.reject_reason}): "
                                 + REJECT_EXPLANATIONS.get(outcome.reject_reason, "see the controller"))
        self.write(**changes)

    # -- how a trial that stopped is recorded --------------------------------------------------
    def stopped(self, exc: TrialAborted) -> None:
        if not self.published:
            shutil.rmtree(self.tmp, ignore_errors=True)
        elif self.record.get("final_state") in _STATES_BEFORE_SENDING:
            self.write(final_state="NOT SENT", reason=str(exc), stopped=exc.kind, finished_utc_s=time.time())

    def interrupted(self) -> None:
        state = self.record.get("final_state")
        if not self.published and "inputs" not in self.record:
            shutil.rmtree(self.tmp, ignore_errors=True)  # nothing of the trial yet
            return
        sent = state == "SENDING"
        self.write(final_state="INTERRUPTED" if sent else "NOT SENT", stopped="interrupted",
                   reason=("interrupted (Ctrl-C) after the command went to the crane: its outcome is unknown here, "
                           "check the crane" if sent else f"interrupted (Ctrl-C) while {state.lower()}: nothing was "
                           "sent"),
                   finished_utc_s=time.time())
        if not self.published:
            self.publish()

    def failed(self, exc: BaseException) -> None:
        if not self.published:
            shutil.rmtree(self.tmp, ignore_errors=True)
        elif self.record.get("final_state") == "SENDING":
            self.write(final_state="UNKNOWN", reason=f"the trial stopped after sending ({type(exc).__name__}: {exc}); "
                       "check the crane", finished_utc_s=time.time())
        elif self.record.get("final_state") not in ("NOT SENT",) and "messages" not in self.record:
            self.write(final_state="NOT SENT", reason=f"the trial stopped ({type(exc).__name__}: {exc})",
                       finished_utc_s=time.time())


class RecordError(FieldError):
    """A trial record cannot be read or replayed as recorded (not a record, a newer version,
    recorded inputs that changed since the trial)."""


RECORD = VersionedJson(RECORD_FORMAT, RECORD_VERSION, "trial record", RecordError)


def read_record(record_dir: str | Path) -> dict:
    """``record_dir/record.json``, format and major version checked. Raises :class:`RecordError`."""
    return RECORD.read(Path(record_dir) / "record.json")


def changed_inputs(record_dir: str | Path, rec: dict | None = None) -> list[str]:
    """Recorded inputs whose files differ from the sha256 in ``record.json`` (changed, missing or
    added under ``inputs/``), as short descriptions; empty when the inputs are as recorded."""
    rec = read_record(record_dir) if rec is None else rec
    inputs = Path(record_dir) / "inputs"
    want = dict((rec.get("inputs") or {}).get("hashes") or {})
    have = {str(p.relative_to(inputs)): p for p in sorted(inputs.rglob("*")) if p.is_file()} if inputs.is_dir() else {}
    out = [f"inputs/{k} is missing" for k in sorted(set(want) - set(have))]
    out += [f"inputs/{k} changed (its sha256 differs from record.json)" for k in sorted(set(want) & set(have))
            if sha256_of(have[k]) != want[k]]
    out += [f"inputs/{k} was added after the trial" for k in sorted(set(have) - set(want))]
    return out


def _precision_of(model: Path, precision: str) -> str | None:
    """The number format the trial's network runs in (what "auto" resolves to on this machine); None
    where it cannot run (the planner's load then says why)."""
    from planner.inference import checkpoint_precision, default_device

    try:
        return checkpoint_precision(model, default_device(), precision)
    except ValueError:
        return None


def recorded_options(stored: dict, precision: str | None = None) -> TrialOptions:
    """The :class:`TrialOptions` a record's ``options`` name; a setting older records lack is what
    the trial did then, not today's default. ``precision``: the number format the trial's network ran
    in (the record's ``model``); records without one ran in the float format "auto" meant then."""
    stored = dict(stored)
    if precision is not None:
        stored["precision"] = precision
    elif stored.get("precision", "auto") == "auto":  # before "auto" could pick int8: bf16 or fp32 by the CPU
        from planner.inference import default_device
        from planner.runtime import default_precision

        stored["precision"] = default_precision(default_device())
    stored.setdefault("verify_k", 0)  # a 1.0 record sent the network's best grasp, unverified
    stored.setdefault("rerank", False)  # records before the ranker planned with U alone
    stored.setdefault("f3_balance", "network")  # records before the hang model scored f3 on the B map
    stored.setdefault("clear_obstacles", False)  # records before it planned over the obstacles the render showed
    if "claw_plate_m" not in stored:  # records before the claws' footprint tested the opening's rectangle
        from synth.geometry.grasp import RECT_WIDTH_M

        stored.update(claw_plate_m=0.0, claw_width_m=RECT_WIDTH_M)
    return TrialOptions(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in stored.items()})


def replay_record(record_dir: str | Path, work_dir: str | Path, progress=None) -> dict:
    """Re-run reconstruction, planning and verification from a record's inputs; compare with what
    was sent and with every verification trial the record stores.

    The recorded inputs are checked against their sha256 first (:class:`RecordError` naming the
    changed file); a model whose sha256 differs from the record's is a :class:`RecordError` too.
    Returns ``{"identical": bool, "command_sent", "command_replayed", "plan_identical",
    "differences", "verification_identical", "verification_differences"}``; ``identical`` needs
    the command, the plan and every recorded verification trial reproduced bit for bit (a trial's
    wall and CPU times aside). The staleness check is judged against the record's own time (the
    data was fresh then); the verification runs without the time budget and chooses among the
    candidates the record checked (:func:`verify_trial_plan`). A record that refused to send
    because no grasp verified is identical when the replay refuses too, with the same plan and
    the same trials."""
    from planner.verify import trial_differences
    from synth.common.files import json_safe

    rec = read_record(record_dir)
    if not rec.get("inputs", {}).get("hashes"):
        raise RecordError(f"{record_dir}/record.json lists no input hashes: this record cannot be replayed")
    changed = changed_inputs(record_dir, rec)
    if changed:
        more = f" (and {len(changed) - 1} more)" if len(changed) > 1 else ""
        raise RecordError(f"{record_dir}: {changed[0]}{more}"
                          + "; a replay re-runs the recorded inputs: restore them from the original record")
    recorded_v = rec.get("verification")
    sent = rec.get("command")
    refused = sent is None and isinstance(recorded_v, dict) and not recorded_v.get("ok")
    if sent is None and not refused:
        raise RecordError(f"{record_dir}: the trial never got to a command ({rec.get('final_state')}: "
                          f"{rec.get('reason', 'no reason recorded')}); there is nothing to replay")
    opts = recorded_options(rec["options"], (rec.get("model") or {}).get("precision"))
    for what in ("model", "ranker"):
        used = rec.get(what) or {}
        if used.get("sha256") and (not Path(used["path"]).exists() or sha256_of(Path(used["path"])) != used["sha256"]):
            raise RecordError(f"the {what} {used['path']} differs from the one the trial used (sha256 "
                              f"{used['sha256'][:12]}... in record.json) or is gone: a replay needs that checkpoint at "
                              f"that path (a shipped one that has since been replaced is in the history: git log -- "
                              f"{used['path']})")
    inputs = Path(record_dir) / "inputs"
    strip = lambda p: {k: p.get(k) for k in ("grasps", "subsets_evaluated")}  # noqa: E731 - elapsed_s differs

    def verification_diffs(replayed) -> list[str]:
        if recorded_v is None:
            return [] if replayed is None else ["the record has no verification; the replay verified"]
        if replayed is None:
            return ["the record has a verification; the replay did not verify"]
        return trial_differences(recorded_v, json_safe(replayed.to_dict()))

    try:
        prepared = prepare_trial(inputs / "scan", inputs / "gnss.csv", work_dir, opts, progress=progress,
                                 now=rec["started_utc_s"], recorded_verification=recorded_v if opts.verify_k else None)
    except NotVerified as exc:
        vdiff = verification_diffs(exc.verification)
        plan_same = rec.get("plan") is not None and strip(rec["plan"]) == strip(json.loads(exc.plan.to_json()))
        diffs = [] if refused else ["no grasp verified on replay: the replay refuses to send"]
        return {"identical": refused and plan_same and not vdiff, "command_sent": sent, "command_replayed": None,
                "plan_identical": plan_same, "differences": diffs, "verification_identical": not vdiff,
                "verification_differences": vdiff}
    again = prepared.command_fields
    plan_again = json.loads((Path(work_dir) / "plan" / "plan.json").read_text())
    diffs = [k for k in again if sent is None or sent.get(k) != again[k]]
    if refused:
        diffs = [f"the record refused to send (no grasp verified); the replay chose plan rank {prepared.chosen_rank}"]
    plan_same = rec.get("plan") is not None and strip(rec["plan"]) == strip(plan_again)
    vdiff = verification_diffs(prepared.verification)
    if rec.get("chosen_rank") is not None and rec["chosen_rank"] != prepared.chosen_rank:
        diffs.append(f"chosen plan rank {rec['chosen_rank']} in the record, {prepared.chosen_rank} on replay")
    return {"identical": not refused and not diffs and plan_same and not vdiff, "command_sent": sent,
            "command_replayed": again, "plan_identical": plan_same, "differences": diffs,
            "verification_identical": not vdiff, "verification_differences": vdiff}
