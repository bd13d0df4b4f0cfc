"""The survey-conditions bench's report (issue 18, 37): a record's figures per condition, its tables
and figure, and several records side by side (:mod:`experiments.survey_conditions` runs the bench).
"""

from __future__ import annotations

import statistics
from pathlib import Path

import numpy as np

from experiments.survey_conditions import SURVEY_CONDITIONS


def obstacle_figures(entries: list[dict]) -> dict:
    """Obstacle figures over reconstructed conditions (refusals have no pile): how many carry an obstacle
    comparison (records older than format 2.2 do not), how many of those have at least one phantom obstacle
    (the issue 37 target: <= 2 % of scans), and the phantom, missed and true obstacles in all."""
    got = [e["obstacles"] for e in entries if "error" not in e and "obstacles" in e]
    with_phantom = sum(bool(o["phantom_obstacles"]) for o in got)
    return {"scans": len(got), "scans_with_phantom": with_phantom,
            "phantom_share": with_phantom / len(got) if got else None,
            "phantom_obstacles": sum(len(o["phantom_obstacles"]) for o in got),
            "missed_obstacles": sum(len(o["missed_obstacles"]) for o in got),
            "true_obstacles": sum(o["n_truth"] for o in got)}


def survey_summary(rec: dict) -> dict:
    """Per condition: failures, per-log worst-end / diameter error and mask IoU statistics, logs not
    reconstructed, end sources, times."""
    out = {}
    for cond in SURVEY_CONDITIONS:
        entries = [(r, r["conditions"][cond]) for r in rec["scans"] if cond in r["conditions"]]
        ok = [(r, e) for r, e in entries if "error" not in e]
        logs = [lg for _, e in ok for lg in e["logs"]]
        worst = [lg["worst_end_m"] for lg in logs]
        dia = [abs(lg["diameter_err_m"]) for lg in logs]
        iou = [lg["mask_iou"] for lg in logs if lg["mask_iou"] is not None]
        srcs: dict[str, int] = {}
        for lg in logs:
            for end in lg["ends"]:
                srcs[end["source"]] = srcs.get(end["source"], 0) + 1
        four = [(r["stereo_wall_s"] + e["wall_s"], r["stereo_cpu_s"] + e["cpu_s"]) for r, e in ok]
        out[cond] = {
            "scans": len(entries), "failures": len(entries) - len(ok),
            "failure_messages": [f"{r['seed']}: {e['error']}" for r, e in entries if "error" in e],
            "logs": len(logs), "missing_logs": sum(len(e["unmatched_truth"]) for _, e in ok),
            "extra_logs": sum(len(e["unmatched_recon"]) for _, e in ok),
            "worst_end_m": _stats(worst), "abs_diameter_m": _stats(dia), "mask_iou": _stats(iou, low=True),
            "sources": srcs, "weak_ends": sum(e["weak_ends"] for _, e in ok),
            "contradicted_points": sum(e["contradicted_points"] for _, e in ok),
            "scan_wall_s": _stats([w for w, _ in four]), "scan_cpu_s": _stats([c for _, c in four]),
            "recon_cpu_s": _stats([e["cpu_s"] for _, e in ok]),
            "tail": _tail(logs),
            "obstacles": obstacle_figures([e for _, e in entries]),
        }
    return out


def blind_log(log: dict) -> bool:
    """A log with an end that neither the scan sees nor an RTK fixed point places: where it lies along
    the log only a float point (+-20-30 cm) or an inference from what covers it says."""
    return any(e["source"] in ("float", "inferred") and e["scan"] != "seen" for e in log["ends"])


def flagged_log(log: dict) -> bool:
    """A log the report warns about: an end weaker than ``weak_sigma_m`` or against its survey point."""
    from reconstruct.fitting.fuse import FuseConfig

    weak = FuseConfig().weak_sigma_m
    return any(e["sigma_m"] > weak or e["contradicted"] for e in log["ends"])


def _tail(logs: list[dict], far_m: float = 0.08) -> dict:
    """What the worst-end tail is made of: the blind logs (:func:`blind_log`, their share and errors),
    the worst end over the others, and the logs farther off than ``far_m`` that the report did not
    warn about (silently wrong)."""
    blind = [lg for lg in logs if blind_log(lg)]
    seen = [lg["worst_end_m"] for lg in logs if not blind_log(lg)]
    silent = [lg for lg in logs if lg["worst_end_m"] > far_m and not flagged_log(lg)]
    return {"blind_logs": len(blind), "blind_share": len(blind) / max(len(logs), 1),
            "blind_worst_end_m": _stats([lg["worst_end_m"] for lg in blind]),
            "blind_over_far": sum(lg["worst_end_m"] > far_m for lg in blind),
            "other_worst_end_m": _stats(seen), "far_m": far_m,
            "over_far": sum(lg["worst_end_m"] > far_m for lg in logs), "silent_over_far": len(silent)}


def _stats(v: list[float], low: bool = False) -> dict:
    if not v:
        return {"n": 0}
    a = np.asarray(v, dtype=float)
    d = {"n": int(a.size), "median": float(np.median(a)), "p95": float(np.percentile(a, 95)), "max": float(a.max())}
    if low:
        d.update(p5=float(np.percentile(a, 5)), min=float(a.min()))
    return d


def seed_ranges(rec: dict) -> str:
    """The recorded scans' seeds as ranges, e.g. ``1100000..1100129, 1100131``: a run stopped and
    resumed out of order leaves gaps that ``first..first + n - 1`` would hide."""
    seeds = sorted(int(r["seed"]) for r in rec["scans"])
    runs: list[list[int]] = []
    for x in seeds:
        if runs and x == runs[-1][1] + 1:
            runs[-1][1] = x
        else:
            runs.append([x, x])
    return ", ".join(f"{a}..{b}" if b > a else f"{a}" for a, b in runs) or "-"


def survey_markdown(rec: dict, figure: Path | None = None) -> list[str]:
    s = survey_summary(rec)
    n = len(rec["scans"])
    loads = [r["load"] for r in rec["scans"]]
    lines = [
        "#### Reconstruction under three survey conditions (the same scans)"
        + (f": the {rec['set']} set" if rec.get("set", "tuning") != "tuning" else ""),
        f"{n} fresh twin scans (`loggrasp synth scan` piles, seeds {seed_ranges(rec)}, "
        f"{_shapes_text(rec)}"
        f"{rec['key']['logs'][0]}-{rec['key']['logs'][1]} logs, {rec['key']['obstacles'][0]}-{rec['key']['obstacles'][1]} "
        f"obstacles, {_pairs_text(rec)} at 3 m), each reconstructed with three surveys of its pile "
        f"(fitting revision {rec['key']['fit_revision']}"
        f"{', estimator ' + rec['key']['estimator'] if 'estimator' in rec['key'] else ''}"
        + "".join(f", {k} {v}" for k, v in rec["key"].get("joint_options", {}).items()) + "). "
        "Per log: worst end error (the farther of its two ends from the truth), absolute mean-diameter error, mask IoU (128 px). Targets (issue 18): <= 1 % failures, "
        "worst end <= 3 cm median and <= 8 cm p95, diameter <= 1 cm median, <= 15 s per 4-pair scan. "
        f"{max(r.get('processes', 1) for r in rec['scans'])} bench process(es) on {rec['scans'][0].get('cpus', '?')} cores; "
        f"load average {min(loads):.1f}-{max(loads):.1f} "
        f"(median {statistics.median(loads):.1f}) while it ran.\n",
        "| survey | scans | failures | logs | not reconstructed | worst end median [cm] | p95 | max | "
        "abs diameter median [cm] | p95 | mask IoU median | p5 |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for cond, d in s.items():
        if not d["logs"]:
            continue
        w, di, io = d["worst_end_m"], d["abs_diameter_m"], d["mask_iou"]
        lines.append(f"| {cond} | {d['scans']} | {d['failures']} ({100 * d['failures'] / max(d['scans'], 1):.1f} %) | "
                     f"{d['logs']} | {d['missing_logs']} | {100 * w['median']:.1f} | {100 * w['p95']:.1f} | "
                     f"{100 * w['max']:.1f} | {100 * di['median']:.2f} | {100 * di['p95']:.1f} | {io['median']:.3f} | "
                     f"{io['p5']:.3f} |")
    lines += ["", "| survey | ends placed: scan / fixed / float / inferred | weak ends | survey points contradicted | "
              "4-pair scan wall median [s] | p95 | CPU median [s] | reconstruction CPU (stereo excluded) [s] |",
              "|---|---|---|---|---|---|---|---|"]
    for cond, d in s.items():
        if not d["logs"]:
            continue
        src = " / ".join(str(d["sources"].get(k, 0)) for k in ("scan", "fixed", "float", "inferred"))
        lines.append(f"| {cond} | {src} | {d['weak_ends']} | {d['contradicted_points']} | "
                     f"{d['scan_wall_s']['median']:.1f} | {d['scan_wall_s']['p95']:.1f} | {d['scan_cpu_s']['median']:.1f} | "
                     f"{d['recon_cpu_s']['median']:.1f} |")
    lines += ["", "What the worst-end tail is made of. *Blind* logs have an end that neither the scan sees nor an RTK "
              "fixed point places (a float point or an inference from what covers it: +-20-30 cm along the log); "
              "*silent*: farther off than the limit without a warning in the report (no weak or contradicted end).",
              "", "| survey | blind logs | share | their worst end median [cm] | p95 | over 8 cm | worst end p95, "
              "the other logs [cm] | logs over 8 cm | of them silent |", "|---|---|---|---|---|---|---|---|---|"]
    for cond, d in s.items():
        if not d["logs"]:
            continue
        t = d["tail"]
        bw, ow = t["blind_worst_end_m"], t["other_worst_end_m"]
        cm = (lambda st, k: f"{100 * st[k]:.1f}" if st.get("n") else "-")  # noqa: E731
        lines.append(f"| {cond} | {t['blind_logs']} | {100 * t['blind_share']:.1f} % | {cm(bw, 'median')} | "
                     f"{cm(bw, 'p95')} | {t['blind_over_far']} | {cm(ow, 'p95')} | {t['over_far']} | "
                     f"{t['silent_over_far']} |")
    if any(d["obstacles"]["scans"] for d in s.values()):
        lines += ["", "Obstacles against the truth (one-to-one within the gate of `reconstruct.compare.OBSTACLE_GATE_M` plus "
                  "half the true obstacle's size; missed ones include those outside the scan or under logs).", "",
                  "| survey | reconstructed scans | with a phantom obstacle | phantom obstacles | missed / true obstacles |",
                  "|---|---|---|---|---|"]
        for cond, d in s.items():
            o = d["obstacles"]
            if o["scans"]:
                lines.append(f"| {cond} | {o['scans']} | {o['scans_with_phantom']} ({100 * o['phantom_share']:.1f} %) | "
                             f"{o['phantom_obstacles']} | {o['missed_obstacles']} / {o['true_obstacles']} |")
    for cond, d in s.items():
        for m in d["failure_messages"]:
            lines.append(f"- {cond}, seed {m}")
    if figure is not None:
        lines += ["", f"![error distributions per survey condition]({figure})"]
    return lines


def _pairs_text(rec: dict) -> str:
    """How the record's scans laid out their pairs, e.g. ``2x2 pairs`` or ``pairs planned from the survey (9-18)``."""
    if rec["key"].get("pairs") != "auto":
        return "2x2 pairs"
    n = [r["n_pairs"] for r in rec["scans"]]
    return f"pairs planned from the survey ({min(n)}-{max(n)})" if n else "pairs planned from the survey"


def _shapes_text(rec: dict) -> str:
    """The record's pile shapes and how many scans of each, e.g. ``packed 10, loose 10, dropped 10 piles, ``."""
    counts: dict[str, int] = {}
    for r in rec["scans"]:
        counts[r.get("shape", "dropped")] = counts.get(r.get("shape", "dropped"), 0) + 1
    return ", ".join(f"{k} {v}" for k, v in counts.items()) + " piles, " if counts else ""


def survey_figure(rec: dict, path: Path) -> Path:
    """Histograms (cumulative) of the per-log worst end error and the diameter error, per condition."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for cond in SURVEY_CONDITIONS:
        logs = [lg for r in rec["scans"] for lg in r["conditions"].get(cond, {}).get("logs", [])]
        if not logs:
            continue
        for ax, key, scale in ((axes[0], "worst_end_m", 100), (axes[1], "diameter_err_m", 100)):
            v = np.sort(np.abs([lg[key] for lg in logs])) * scale
            ax.plot(v, np.arange(1, len(v) + 1) / len(v), label=f"{cond} ({len(v)} logs)")
    axes[0].axvline(3, color="grey", ls=":")
    axes[0].axvline(8, color="grey", ls="--")
    axes[0].set(xlabel="worst end error per log [cm]", ylabel="share of logs", xscale="log", xlim=(0.3, 100))
    axes[1].axvline(1, color="grey", ls=":")
    axes[1].set(xlabel="|mean diameter error| per log [cm]", xscale="log", xlim=(0.01, 30))
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right", fontsize=8)
    fig.suptitle(f"Reconstruction under three survey conditions, {len(rec['scans'])} twin scans", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def compare_summary(recs: dict[str, dict]) -> dict[str, dict[str, dict]]:
    """Records of several estimators (or revisions) side by side on the scans they all measured, matched by
    seed and stereo cloud (:func:`experiments.survey_conditions.cloud_fingerprint`): ``{condition: {label: figures}}``. The figures are the
    issue 37 targets': failures, worst end median / p95, diameter median, logs over 8 cm (and how many of those
    the report did not warn about), survey points called wrong (every one on the all-fixed survey is a correct
    fixed point discarded), logs made that are not in the truth, and how many blind logs' worst end lies within
    2 sigma of their less certain end (the coverage of the reported sigma)."""
    common = None
    for rec in recs.values():
        got = {(r["seed"], r.get("cloud_sha256")) for r in rec["scans"]}
        common = got if common is None else common & got
    out: dict[str, dict[str, dict]] = {}
    for cond in SURVEY_CONDITIONS:
        out[cond] = {}
        for label, rec in recs.items():
            rows = [r for r in rec["scans"] if (r["seed"], r.get("cloud_sha256")) in common and cond in r["conditions"]]
            ok = [r["conditions"][cond] for r in rows if "error" not in r["conditions"][cond]]
            logs = [lg for e in ok for lg in e["logs"]]
            blind = [lg for lg in logs if blind_log(lg)]
            worst = _stats([lg["worst_end_m"] for lg in logs])
            out[cond][label] = {
                "scans": len(rows), "failures": len(rows) - len(ok), "logs": len(logs),
                "worst_median_m": worst.get("median"), "worst_p95_m": worst.get("p95"),
                "diameter_median_m": _stats([abs(lg["diameter_err_m"]) for lg in logs]).get("median"),
                "over_8cm": sum(lg["worst_end_m"] > 0.08 for lg in logs),
                "silent_over_8cm": sum(lg["worst_end_m"] > 0.08 and not flagged_log(lg) for lg in logs),
                "points_called_wrong": sum(e["contradicted_points"] for e in ok),
                "phantom_logs": sum(len(e["unmatched_recon"]) for e in ok),
                "obstacles": obstacle_figures(ok),
                "blind_logs": len(blind),
                "blind_within_2sigma": sum(lg["worst_end_m"] <= 2 * max(x["sigma_m"] for x in lg["ends"]) for lg in blind),
                "recon_cpu_median_s": _stats([e["cpu_s"] for e in ok]).get("median"),
                "scan_cpu_median_s": _stats([r["stereo_cpu_s"] + r["conditions"][cond]["cpu_s"] for r in rows
                                             if "error" not in r["conditions"][cond]]).get("median"),
            }
    return out


def compare_markdown(recs: dict[str, dict]) -> list[str]:
    """:func:`compare_summary` as a markdown table (one row per condition and record)."""
    s = compare_summary(recs)
    cm = (lambda v: "-" if v is None else f"{100 * v:.1f}")  # noqa: E731
    sec = (lambda v: "-" if v is None else f"{v:.1f}")  # noqa: E731
    lines = ["| survey | estimator | scans | failures | worst end median [cm] | p95 | abs diameter median [cm] | "
             "logs over 8 cm | of them silent | points called wrong | phantom logs | scans with a phantom obstacle | "
             "phantom / missed obstacles | blind logs within 2 sigma | reconstruction CPU median [s] | "
             "4-pair scan CPU median [s] |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for cond, by_label in s.items():
        for label, d in by_label.items():
            cov = f"{d['blind_within_2sigma']} / {d['blind_logs']}" if d["blind_logs"] else "-"
            dia = "-" if d["diameter_median_m"] is None else f"{100 * d['diameter_median_m']:.2f}"
            fail = f"{d['failures']} ({100 * d['failures'] / max(d['scans'], 1):.1f} %)"
            lines.append(f"| {cond} | {label} | {d['scans']} | {fail} | {cm(d['worst_median_m'])} | {cm(d['worst_p95_m'])} | "
                         f"{dia} | {d['over_8cm']} | {d['silent_over_8cm']} | {d['points_called_wrong']} | "
                         f"{d['phantom_logs']} | {_phantom_text(d['obstacles'])} | {cov} | {sec(d['recon_cpu_median_s'])} | {sec(d['scan_cpu_median_s'])} |")
    return lines


def _phantom_text(o: dict) -> str:
    """The compare table's two obstacle cells, e.g. ``2 / 80 (2.5 %) | 2 / 31``; ``- | -`` for records without
    obstacle comparisons (format 2.1)."""
    if not o["scans"]:
        return "- | -"
    return (f"{o['scans_with_phantom']} / {o['scans']} ({100 * o['phantom_share']:.1f} %) | "
            f"{o['phantom_obstacles']} / {o['missed_obstacles']}")
