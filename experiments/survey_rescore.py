"""Obstacle comparisons for survey-conditions records made before they had any (format 2.1), read from the
scans' kept work folders instead of reconstructing again: ``bench/bench_reconstruct.py --survey-rescore``.

A scan's work folder (``--survey-work``) keeps its true pile (``truth/pile.json``), its stereo cloud and the
last reconstruction of each condition and estimator (``recon_<condition>`` for revision 22,
``recon_<condition>_<estimator>`` otherwise) - the last only: a later run of another revision of the same
estimator overwrites it, and a run that refused leaves the one before. So a kept pile is used only when it is
the one the record measured: the same stereo cloud (``cloud_sha256``), the report's estimator and revision the
record's key's, and its logs measured against the truth exactly as the record has them (every log's truth
index and worst end error within :data:`SAME_ERROR_M`). Every other condition is left as it is and counted.
"""

from __future__ import annotations

import json
from pathlib import Path

#: a kept pile's log errors must equal the record's to this [m]: the pile file holds the floats the record
#: was computed from (JSON round-trips them), so any difference is another reconstruction
SAME_ERROR_M = 1e-9


class RescoreError(ValueError):
    """A record or work folder that cannot be rescored (named in the message)."""


def rescore_obstacles(out: Path, work_dir: Path, progress=print) -> dict:
    """Add each reconstructed condition's obstacle comparison (:func:`experiments.survey_conditions.obstacle_entry`)
    to the scan records of ``out`` (kept piles of ``work_dir`` only: see the module docstring) and rewrite their
    summary; every other field of a record is written back as it was. Returns counts: ``filled``, ``refused``
    (no pile: the record is a failure), and why the others were not filled."""
    from synth.common.files import atomic_write_bytes

    from experiments.survey_conditions import SURVEY_BENCH_VERSION, read_survey_records

    paths = sorted((out / "scans").glob("*.json"))
    if not paths:
        raise RescoreError(f"{out}/scans holds no scan records: check --survey-rescore")
    counts: dict[str, int] = {}
    keys: dict[str, dict] = {}  # the records' keys as written (the summary keeps its own order, else theirs)
    for path in paths:
        text = path.read_text()
        row = json.loads(text)
        if json.dumps(row, indent=1) != text:
            raise RescoreError(f"{path} is not as the bench writes it: rescoring would rewrite more than its obstacles")
        keys.setdefault(json.dumps(row["key"], sort_keys=True), row["key"])
        root = work_dir / f"scan_{row['seed']}"
        same_cloud = _cloud_sha(root) == row.get("cloud_sha256")
        changed = False
        for cond, entry in row["conditions"].items():
            why = _fill(root, row, cond, entry) if same_cloud or "error" in entry else "another stereo cloud"
            counts[why] = counts.get(why, 0) + 1
            changed |= why == "filled"
        if changed:
            row["format_version"] = SURVEY_BENCH_VERSION
            atomic_write_bytes(path, json.dumps(row, indent=1).encode())
        progress(f"scan {row['seed']}: " + ", ".join(
            f"{c} {len(e['obstacles']['phantom_obstacles'])} phantom / {len(e['obstacles']['missed_obstacles'])} missed"
            if "obstacles" in e else f"{c} -" for c, e in row["conditions"].items()))
    most = read_survey_records(out, write=False)["key"]
    old = json.loads((out / "summary.json").read_text()).get("key") if (out / "summary.json").exists() else None
    rec = read_survey_records(out, old if old == most else keys.get(json.dumps(most, sort_keys=True), most))
    return {"counts": counts, "scans": len(rec["scans"])}


def _fill(root: Path, row: dict, cond: str, entry: dict) -> str:
    """Put the obstacle comparison into ``entry`` when the kept pile is the record's; returns what was done."""
    if "error" in entry:
        return "refused"
    if "obstacles" in entry:
        return "already filled"
    estimator = row["key"].get("estimator", "rules22")
    folder = root / (f"recon_{cond}" if estimator == "rules22" else f"recon_{cond}_{estimator}")
    if not (folder / "pile.json").exists() or not (root / "truth" / "pile.json").exists():
        return "no kept pile"
    report = json.loads((folder / "report.json").read_text())
    if (report.get("estimator"), report.get("estimator_revision")) != (
            row["key"].get("estimator"), row["key"].get("estimator_revision")):
        return "another estimator revision"
    from reconstruct.compare import compare_piles
    from synth.scene.pile import read_pile

    from experiments.survey_conditions import obstacle_entry

    cmp = compare_piles(read_pile(root / "truth" / "pile.json"), read_pile(folder / "pile.json"), render=False)
    kept = sorted((e["truth_index"], e["endpoint_max_err_m"]) for e in cmp["logs"])
    recorded = sorted((lg["truth_index"], lg["worst_end_m"]) for lg in entry["logs"])
    if len(kept) != len(recorded) or any(a[0] != b[0] or abs(a[1] - b[1]) > SAME_ERROR_M
                                         for a, b in zip(kept, recorded)):
        return "another reconstruction"
    entry["obstacles"] = obstacle_entry(cmp)
    return "filled"


def _cloud_sha(root: Path) -> str | None:
    """The fingerprint of the stereo cloud kept in ``root`` (None: none kept)."""
    from types import SimpleNamespace

    import numpy as np

    from experiments.survey_conditions import cloud_fingerprint

    if not (root / "cloud.npz").exists():
        return None
    with np.load(root / "cloud.npz") as z:
        return cloud_fingerprint(SimpleNamespace(points=z["points"]))
