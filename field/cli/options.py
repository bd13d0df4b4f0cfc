"""The flags and helpers the field commands share: the link URL and its forms, the crane base, reach
and pile age, verified planning, and how a plan and an outcome are shown."""

from __future__ import annotations

import sys
from pathlib import Path


from field.controller import ReachEnvelope
from field.demo import CRANE_OFFSET_SOUTH_M
from field.trial import TrialOptions
from synth.common.cli import EXIT_LINK, CliError, option

LINK_FORMS = ("can://virtual/CH, can://socketcan/can0, can://remote/127.0.0.1:PORT/CH, can://, "
              "zenoh://HOST:PORT/CRANE, zenoh://CRANE?config=PATH.json5, twin://")
TWIN_PARAMETERS = (
    "twin:// runs a crane controller twin inside this process behind a simulated CAN bus. Its "
    "parameters (URL query, e.g. twin://?executor=pybullet&pile=truth/pile.json&trial=fast): "
    "crane_base=E,N,H (SWEREF 99 TM [m], ellipsoidal h [m]; trial fills it from --base, else 5 m "
    "south of the surveyed logs), crane_max_reach_m=M (trial: --max-reach), crane_max_pile_age_s=S "
    "(the twin crane's own staleness limit; trial: --max-pile-age, replay: the record's age), "
    "executor=fixed|pybullet (fixed: always the outcome=SUCCESS|COLLISION|... after delay_ms=MS; "
    "pybullet: a grasp trial on pile=PILE.json with trial=fast|careful), and the link options "
    "record=PATH.blf, heartbeat_ms, heartbeat_timeout_ms, connect_timeout_s, max_pile_age_s, secoc_key=KEYFILE "
    "(authenticated frames, SecOC style: both ends use the key; see `loggrasp link-key`), crane_key=CRANE.pub "
    "(laptop: the crane's public key, its answers are signed) and signing_key=CRANE (crane: its signing key; "
    "`loggrasp link-key --crane-signing CRANE` writes both); a can:// or zenoh:// link needs them unless "
    "insecure=1 / --insecure-link opts out.")


# -- shared field flags ----------------------------------------------------------------------------
def link_option(help: str = f"Crane link URL: {LINK_FORMS}."):
    return option("--link", help, default=..., metavar="URL")


BASE_HELP = "Crane base E,N,H (SWEREF 99 TM easting, northing [m], ellipsoidal height [m])"
MAX_REACH = option("--max-reach", "Boom reach.", field=(ReachEnvelope, "max_reach_m"), min=0.1)
MAX_PILE_AGE = option("--max-pile-age", "Refuse plans on pile data older than this.",
                      field=(TrialOptions, "max_pile_age_s"), min=0.001)


def parse_base(text: str | None, flag: str = "--base") -> tuple[float, float, float] | None:
    if text is None:
        return None
    try:
        parts = [float(v) for v in text.split(",")]
    except ValueError:
        parts = []
    if len(parts) != 3 or not all(v == v for v in parts):
        raise CliError(f"{flag} must be E,N,H (SWEREF 99 TM easting and northing [m], ellipsoidal height [m]), "
                       f"e.g. 743497.0,7117716.0,249.8; got {text!r}")
    from synth.geometry.geodesy import check_sweref_tm

    check_sweref_tm(parts[0], parts[1], flag)
    return parts[0], parts[1], parts[2]


def check_link(url: str, flag: str = "--link", serve: bool = False):
    """The parsed link URL, or a :class:`CliError` (exit 3) before any work: empty, malformed, or a
    scheme with no backend (``serve``: one a controller can serve, i.e. not ``twin://``)."""
    from field.link.base import BACKENDS, CONTROLLER_TRANSPORTS, LinkURL

    if not url or not url.strip():
        raise CliError(f"{flag} is empty; give a crane link URL: {LINK_FORMS}", EXIT_LINK)
    try:
        parsed = LinkURL.parse(url)
    except ValueError as exc:
        raise CliError(f"{flag}: {exc}", EXIT_LINK) from exc
    registry = CONTROLLER_TRANSPORTS if serve else BACKENDS
    if parsed.scheme not in registry:
        if serve and parsed.scheme == "twin":
            raise CliError(f"{flag} {url}: twin:// is a crane twin inside the laptop's own process; a controller "
                           "serves can://... or zenoh://...", EXIT_LINK)
        raise CliError(f"{flag} {url}: unknown link scheme {parsed.scheme + '://'!r}; use one of {LINK_FORMS}",
                       EXIT_LINK)
    if parsed.scheme == "zenoh" and not parsed.path and "config" not in parsed.query:
        raise CliError(f"{flag} {url}: a Zenoh URL names the crane: zenoh://HOST:PORT/CRANE or "
                       "zenoh://CRANE?config=PATH.json5", EXIT_LINK)
    return parsed


def twin_url(url: str, base_tm, max_reach_m: float, max_pile_age_s: float) -> str:
    """A ``twin://`` URL with the twin crane's own limits filled in where the URL leaves them out,
    so the twin judges a command like the laptop does."""
    from urllib.parse import urlencode

    from field.link.base import LinkURL

    u = LinkURL.parse(url)
    q = dict(u.query)
    if "crane_base" not in q:
        q["crane_base"] = ",".join(f"{v:.3f}" for v in base_tm)
        q.setdefault("crane_max_reach_m", f"{max_reach_m:g}")
    q.setdefault("crane_max_pile_age_s", f"{max_pile_age_s:g}")
    return "twin://?" + urlencode(q, safe=",/:")


def base_from_survey(gnss) -> tuple[float, float, float]:
    """A crane base :data:`field.demo.CRANE_OFFSET_SOUTH_M` south (site frame) of the surveyed log
    ends' centre, at about ground height: the twin crane's default position, known before the
    reconstruction."""
    import numpy as np

    from reconstruct.survey.gnss import read_gnss
    from synth.geometry.geodesy import site_to_tm

    survey = read_gnss(gnss, allow_float=True)
    origin = survey.default_origin()
    ends = np.array([p for a_b in survey.endpoints_site(origin).values() for p in a_b], dtype=float)
    c = ends.mean(axis=0)
    point = np.array([c[0], c[1] - CRANE_OFFSET_SOUTH_M, float(ends[:, 2].min()) - 0.3])
    e, n, h = site_to_tm(origin, point)
    return float(np.ravel(e)[0]), float(np.ravel(n)[0]), float(np.ravel(h)[0])





def trial_options(objective, model, allow_float, max_pile_age, base_tm, max_reach, capacity, views=1,
                   view_spread=0.0, **verify) -> TrialOptions:
    """The trial's options; ``verify``: the ``TrialOptions.verify_*`` / ``operator_rank`` fields."""
    return TrialOptions(objective=objective, model=None if model is None else str(model), allow_float=allow_float,
                        max_pile_age_s=max_pile_age, crane_base_tm=base_tm, max_reach_m=max_reach,
                        lift_capacity_kg=capacity, views=views, view_spread_k=view_spread, **verify)


# -- verified planning flags of trial and demo ------------------------------------------------------
NO_VERIFY = option("--no-verify", "Send without trying the grasps in the twin first (the network's best, or "
                   "--send-rank).", default=False)
VERIFY_K = option("--verify", "Grasps the twin tries on the reconstructed pile before one is sent; the best that "
                  "succeeded there is sent.", field=(TrialOptions, "verify_k"), metavar="K")
VERIFY_COPIES = option("--verify-copies", "Also try each grasp that succeeded on this many perturbed copies of the "
                       "reconstruction (its measured uncertainty, per log from how it was fitted).",
                       field=(TrialOptions, "verify_copies"), min=0, max=64)
VERIFY_BUDGET = option("--verify-budget", "Wall time for the twin's trials; no trial starts after it and only the "
                       "grasps checked by then can be sent (0 = no limit).", field=(TrialOptions, "verify_budget_s"),
                       names=["time_budget_s"])
VERIFY_WORKERS = option("--verify-workers", "Processes for the twin's trials (0 = all cores, 1 = in this process).",
                        field=(TrialOptions, "verify_workers"), min=0)
SEND_RANK = option("--send-rank", "When no grasp succeeded in the twin (or with --no-verify): send plan rank N "
                   "anyway, the operator's explicit choice, marked NOT VERIFIED.", default=None, min=1, metavar="N",
                   names=["operator_rank"])


def verify_fields(verify: int, no_verify: bool, copies: int, budget: float | None, workers: int,
                  send_rank: int | None) -> dict:
    """The ``TrialOptions`` fields of the verification flags, checked (exit 2) before any work."""
    from planner.cli import check_verify_flags

    if no_verify:
        return {"verify_k": 0, "operator_rank": send_rank}
    budget_s = check_verify_flags(verify, budget, off_hint="--no-verify turns verification off")
    return {"verify_k": verify, "verify_copies": copies, "verify_budget_s": budget_s, "verify_workers": workers,
            "operator_rank": send_rank}


RANKER = option("--ranker", "The grasp ranker that re-scores the network's best grasps before verification "
                "(loggrasp train-ranker); default: the shipped ranker.", default=None, metavar="PATH")
NO_RANKER = option("--no-ranker", "Order the network's grasps by its U alone (no re-scoring).", default=False)


def ranker_fields(ranker: Path | None, no_ranker: bool) -> dict:
    """The ``TrialOptions`` fields of ``--ranker`` / ``--no-ranker``, checked (exit 2) before any work."""
    from planner.cli import check_ranker_flags

    rerank, path = check_ranker_flags(ranker, no_ranker)
    return {"rerank": rerank, "ranker": None if path is None else str(path)}


def outcome_words(outcome: dict | None, targets: int | None = None) -> str:
    """A grasp outcome for people: ``SUCCESS: 4 logs held (4 targeted), balance cos β 0.999``."""
    if not outcome:
        return "no outcome"
    held = outcome.get("logs_grasped")
    text = f"{outcome.get('class')}: {held} log{'' if held == 1 else 's'} held"
    if targets is not None:
        text += f" ({targets} targeted)"
    if outcome.get("cos_beta") is not None:
        text += f", balance cos β {outcome['cos_beta']:.3f}"
    return text


def show_plan(prepared) -> None:
    """What the operator confirms: the plan table, the grasp in SWEREF 99 TM, the warnings and
    the pictures (paths that exist)."""
    from planner.cli import TWIN_COLUMNS, twin_cells
    from synth.common.cli import format_table

    v = prepared.verification
    shown = max([5, prepared.chosen_rank] + ([] if v is None else [c.rank + 1 for c in v.candidates]))
    rows = [[("*" if g is prepared.best else "") + str(i + 1), ",".join(map(str, g.targets)), f"{g.quality:.3f}",
             f"{g.graspability:.3f}", f"{g.balance:.3f}", f"{g.grasp.width_m:.2f}"]
            + ([] if v is None else twin_cells(v, i)) for i, g in enumerate(prepared.plan.grasps[:shown])]
    what = ("twin: its outcome on the reconstructed pile, held logs, beta" if v is not None
            else "not tried in the twin")
    print(format_table(f"plan: the best grasp of each target subset (*{prepared.chosen_rank} is sent; Q quality, "
                       f"U graspability, B balance; {what})",
                       ["#", "targets", "Q", "U", "B", "width m"] + ([] if v is None else TWIN_COLUMNS), rows),
          file=sys.stderr)
    for line in prepared.summary_lines():
        print(("  " if not line.startswith("WARNING") else "") + line, file=sys.stderr)
    plan_dir = Path(prepared.work_dir) / "plan"
    pictures = [p for p in (plan_dir / "plan.png", plan_dir / "grasp_map.png", plan_dir / "pile.geojson") if p.exists()]
    print("  look before sending: " + ", ".join(str(p) for p in pictures), file=sys.stderr, flush=True)


def ask_yes_no(question: str) -> bool | None:
    """Ask on standard error, read a line from standard input: True for y/yes, False for anything
    else, None when there is no answer (end of input, Ctrl-C). Standard output is left alone."""
    print(f"{question} [y/N]: ", end="", file=sys.stderr, flush=True)
    try:
        line = sys.stdin.readline() if sys.stdin is not None else ""
    except (KeyboardInterrupt, OSError, ValueError):
        line = ""
    if not line:
        print(file=sys.stderr, flush=True)
        return None
    return line.strip().lower() in ("y", "yes")
