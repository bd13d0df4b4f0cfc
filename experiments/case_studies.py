"""The paper's case studies ("Results") as pictures, with every drawn grasp tried in the twin.

Four figures, each from fresh, settled, rendered piles and the planner passed in:

* ``ranking.png`` — one pile, the best grasp of *every* target subset, ranked by Q (one block per
  objective, e.g. f1 and f3), each panel titled with rank, targets, q, u, b and the trial outcome;
* ``obstacle.png`` — piles planned without an obstacle, then with a rock / stump placed at the
  chosen grasp's claw landing spot (a :class:`synth.scene.pile.PileSpec` edit, checked physical): the
  chosen grasp and its outcome in each scene, the first grasp retried in the obstacle scene, and
  the network's graspability U for the first targets in both scenes;
* ``packed.png`` — tightly packed piles (``GenerationConfig(packed=True)``) and one of them spread
  with small gaps and re-settled: the free choice and the best grasp on half of the logs;
* ``logs.png`` — thick, short logs and strongly tapered (conical) logs, far outside the training
  distribution: the best grasp (thick) and the next ones (thin).

Each case draws its pile seeds from ``CaseStudyConfig.seed`` plus a fixed offset, so a run is
repeatable; with another model only the plans (and so the trials) change.
:func:`run_case_studies` writes the figures, ``results.json`` (versioned, read back by
:func:`read_results`) and a ``README.md`` with the command, seeds, model and a table of outcomes.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from experiments.case_study_panels import (describe_trial, fmt_targets, grid_image, outcome_colour, render_panel,
                                           stack_blocks, titled, u_panel, with_heading)
from planner.errors import PlannerError
from synth.common.formats import VersionedJson

CASE_STUDIES_FORMAT = "loggrasp.case-studies"
CASE_STUDIES_FORMAT_VERSION = "1.0"

# seed offsets of the cases (added to CaseStudyConfig.seed)
_RANKING, _OBSTACLE, _PACKED, _THICK, _CONICAL = 0, 1000, 2000, 3000, 4000


class CaseStudyError(PlannerError):
    """A case study could not be built (no valid pile, nowhere to place an obstacle...)."""


RESULTS = VersionedJson(CASE_STUDIES_FORMAT, CASE_STUDIES_FORMAT_VERSION, "case-study results", CaseStudyError,
                        fix="re-run scripts/case_studies.py", unreadable_fix="re-run scripts/case_studies.py",
                        filename="results.json")


@dataclass(frozen=True)
class CaseStudyConfig:
    """What the case studies draw. Sizes follow the paper's figures; the defaults take a few
    minutes on one CPU core."""

    seed: int = 700_000  # base pile seed [-]; each case adds its own offset
    ranking_logs: int = 5  # logs in the ranking pile [-] (2^n - 1 panels per objective)
    ranking_objectives: tuple[str, ...] = ("f1", "f3")  # one ranked block per objective
    ranking_columns: int = 8  # panels per row [-]
    obstacle_logs: int = 4  # logs per obstacle pile [-]
    obstacle_kinds: tuple[str, ...] = ("rock", "stump")  # one pile per entry [-]
    rock_size_m: float = 0.8  # placed rock's diameter [m]
    stump_radius_m: float = 0.22  # placed stump's foot radius [m]
    stump_height_m: float = 0.6  # placed stump's height [m]
    packed_logs: int = 4  # logs per packed pile [-]
    packed_piles: int = 2  # tightly packed piles [-]; the first is also drawn spread with gaps
    packed_gap_m: float = 0.10  # gap between neighbours in the spread version [m]
    shape_logs: int = 3  # logs per thick/short and conical pile [-]
    shape_piles: int = 2  # piles of each kind [-]
    thick_diameter_m: float = 0.34  # mean diameter of thick logs [m] (training: 0.16 +- 0.02)
    short_length_m: float = 1.2  # mean length of short logs [m] (training: 2.5 +- 0.2)
    conical_butt_m: float = 0.28  # mean butt diameter of conical logs [m]
    conical_top_ratio: float = 0.35  # top / butt diameter of conical logs [-]
    objective: str = "f1"  # objective of the obstacle, packed and logs figures
    trial: str = "fast"  # synth.physics.trial preset: "fast" or "careful"
    panel_px: int = 256  # panel side [px] (the render is scaled by an integer to about this)
    max_seed_tries: int = 25  # seeds tried per case for a pile whose logs are all visible [-]

    def __post_init__(self) -> None:
        for name in ("ranking_logs", "obstacle_logs", "packed_logs", "shape_logs"):
            if not 1 <= getattr(self, name) <= 7:
                raise ValueError(f"{name} must be in [1, 7], got {getattr(self, name)}")
        if self.packed_logs < 2:
            raise ValueError("packed_logs must be >= 2 (a packed pile needs neighbours)")
        if not self.ranking_objectives or any(o not in ("f1", "f2", "f3") for o in self.ranking_objectives):
            raise ValueError(f"ranking_objectives must be f1/f2/f3, got {self.ranking_objectives}")
        if any(k not in ("rock", "stump") for k in self.obstacle_kinds):
            raise ValueError(f"obstacle_kinds must be 'rock' or 'stump', got {self.obstacle_kinds}")
        if self.trial not in ("fast", "careful"):
            raise ValueError(f"trial must be 'fast' or 'careful', got {self.trial!r}")
        if self.packed_piles < 1 or self.shape_piles < 1 or self.ranking_columns < 1:
            raise ValueError("packed_piles, shape_piles and ranking_columns must be >= 1")
        if not 0.3 <= self.rock_size_m <= 2.0:
            raise ValueError(f"rock_size_m must be in [0.3, 2] m, got {self.rock_size_m}")
        if not 0.05 <= self.conical_top_ratio <= 1.0:
            raise ValueError("conical_top_ratio must be in [0.05, 1]")
        if self.packed_gap_m < 0 or self.panel_px < 32 or self.max_seed_tries < 1:
            raise ValueError("need packed_gap_m >= 0, panel_px >= 32 and max_seed_tries >= 1")

    @staticmethod
    def tiny(**kw) -> "CaseStudyConfig":
        """Small piles and one pile per case: for tests."""
        base = dict(ranking_logs=2, obstacle_logs=2, obstacle_kinds=("rock",), packed_logs=2, packed_piles=1,
                    shape_logs=1, shape_piles=1, panel_px=64, ranking_objectives=("f1", "f3"))
        base.update(kw)
        return CaseStudyConfig(**base)


# -- piles and observations -------------------------------------------------------------------
def observe(pile, size_px: int, seed: int = 0):
    """Render ``pile`` top-down (one render, the pile's own colours) at ``size_px``."""
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.physics.world import World

    with World(pile) as world:
        return render_ortho(world, OrthoRenderConfig(size_px=size_px, n_renders=1), seed=seed)


def resettle(pile):
    """Drop an edited pile's logs to rest and check it is physical. Raises :class:`CaseStudyError`."""
    from synth.errors import GenerationError, PileValidationError
    from synth.scene.generate import GenerationConfig, settle
    from synth.physics.world import World

    try:
        with World(pile, visuals=False) as world:
            settle(world, GenerationConfig())
            world.check_valid()
            return world.settled_pile()
    except (GenerationError, PileValidationError) as exc:
        raise CaseStudyError(f"the edited pile does not settle into a valid pile: {exc}") from exc


def visible_pile(seed: int, gen_cfg, size_px: int, tries: int, edit=None):
    """The first pile from seeds ``seed, seed + 1, ...`` whose logs all show in the render
    (after ``edit(pile) -> pile``, if given). Returns ``(seed, pile, observation)``."""
    from synth.errors import SynthError
    from synth.scene.generate import generate_pile

    last = "?"
    for k in range(tries):
        try:
            pile, _ = generate_pile(seed + k, gen_cfg)
            if edit is not None:
                pile = edit(pile)
        except (SynthError, CaseStudyError) as exc:
            last = str(exc)
            continue
        obs = observe(pile, size_px, seed + k)
        codes = set(np.unique(obs.instance).tolist())
        if all(i + 1 in codes for i in range(pile.n_logs)):
            return seed + k, pile, obs
        last = "a log is hidden in the render"
    raise CaseStudyError(f"no usable pile in seeds {seed}..{seed + tries - 1} (last: {last}); "
                         "raise max_seed_tries or change the seed")


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    t = float(np.clip(np.dot(p - a, b - a) / max(float(np.dot(b - a, b - a)), 1e-12), 0.0, 1.0))
    return float(np.linalg.norm(a + t * (b - a) - p))


def place_obstacle_near(pile, grasp, kind: str = "rock", cfg: CaseStudyConfig = CaseStudyConfig(), seed: int = 0):
    """``pile`` plus one rock or stump where a claw of ``grasp`` lands (or as close to it as the
    logs allow: the obstacle must not touch a log, so the logs keep their settled poses).
    Returns ``(pile, obstacle centre (x, y) [m])``; raises :class:`CaseStudyError` when no spot
    near the grasp is free."""
    from synth.errors import PileValidationError
    from synth.scene.generate import validate_pile
    from synth.scene.pile import RockSpec, StumpSpec, quat_from_euler

    radius = cfg.rock_size_m / 2 if kind == "rock" else cfg.stump_radius_m
    half = pile.terrain.extent_m / 2
    a = grasp.closing_axis()
    b = np.array([-a[1], a[0]])
    centre = np.array([grasp.x_m, grasp.y_m])
    segs = [(*(e[:2] for e in log.endpoints_m()), log.diameter_m / 2) for log in pile.logs]
    spots = []
    for side in (1.0, -1.0):
        claw = centre + side * a * grasp.width_m / 2
        for d in np.arange(-0.2, 1.21, 0.05):
            for t in (0.0, 0.15, -0.15, 0.3, -0.3, 0.5, -0.5):
                # kept on the terrain patch: as close to the claw as the patch allows
                p = np.clip(claw + side * a * (radius + d) + b * t, -(half - radius - 0.1), half - radius - 0.1)
                spots.append((float(np.linalg.norm(p - claw)), p))
    spots.sort(key=lambda s: s[0])
    rng = np.random.default_rng([seed, 0x0B5])
    for _, p in spots:
        if any(_segment_distance(p, s0, s1) < radius + r + 0.04 for s0, s1, r in segs):
            continue
        if kind == "rock":
            n = 14
            d = rng.normal(size=(n, 3))
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            verts = d * np.array([1.0, 0.85, 0.6]) * radius
            ground = float(np.min(pile.terrain.height_at(p[0] + verts[:, 0], p[1] + verts[:, 1])))
            z = ground + 0.6 * radius * 0.8  # vertical half-axis 0.6 r; a fifth of it below the lowest ground
            ob = RockSpec(position_m=(float(p[0]), float(p[1]), z), orientation=quat_from_euler(0, 0, 0),
                          vertices_m=tuple(tuple(float(c) for c in v) for v in verts), colour=(0.55, 0.55, 0.55))
            edited = replace(pile, rocks=(*pile.rocks, ob))
        else:
            ob = StumpSpec(position_m=(float(p[0]), float(p[1])), height_m=cfg.stump_height_m,
                           bottom_radius_m=radius, top_radius_m=radius * 0.85, colour=(0.5, 0.38, 0.25))
            edited = replace(pile, stumps=(*pile.stumps, ob))
        try:
            validate_pile(edited)
        except PileValidationError:
            continue
        return edited, (float(p[0]), float(p[1]))
    raise CaseStudyError(f"no free spot for a {kind} of radius {radius:.2f} m near the grasp's claws "
                         "(every spot touches a log); use a smaller obstacle")


def spread_logs(pile, gap_m: float):
    """Move the logs of a packed pile apart across their common direction so that neighbours
    are ``gap_m`` further apart, lift them clear and re-settle (:func:`resettle`)."""
    axes = np.array([log.axis()[:2] for log in pile.logs])
    axes *= np.sign(axes @ axes[0])[:, None]
    mean = axes.mean(axis=0)
    mean /= np.linalg.norm(mean)
    normal = np.array([-mean[1], mean[0]])
    centres = np.array([log.centre_m for log in pile.logs])
    order = np.argsort(centres[:, :2] @ normal)
    rank = np.empty(len(order), int)
    rank[order] = np.arange(len(order))
    mid = (len(order) - 1) / 2
    logs = []
    for i, log in enumerate(pile.logs):
        c = centres[i].copy()
        c[:2] += normal * (rank[i] - mid) * gap_m
        c[2] += 0.05
        logs.append(replace(log, centre_m=tuple(float(v) for v in c)))
    try:
        moved = pile.with_logs(tuple(logs))
    except ValueError as exc:
        raise CaseStudyError(f"spreading the logs by {gap_m} m pushes one off the terrain: {exc}") from exc
    return resettle(moved)


def taper_logs(pile, top_ratio: float):
    """Make every log a truncated cone with top diameter ``top_ratio`` x butt, re-settled."""
    logs = tuple(replace(log, top_diameter_m=max(0.02, log.diameter_m * top_ratio)) for log in pile.logs)
    return resettle(pile.with_logs(logs))


# -- planning, trials and maps ------------------------------------------------------------------
def trial_config(preset: str):
    from synth.physics.trial import TrialConfig

    return TrialConfig.preset(preset)


def try_grasp(pile, planned, trial_cfg) -> dict:
    """Run the twin trial of one :class:`~planner.inference.PlannedGrasp`; a JSON-able record."""
    from synth.physics.trial import run_trial

    r = run_trial(pile, planned.grasp, planned.targets, trial_cfg)
    return {"targets": list(planned.targets), "q": planned.quality, "u": planned.graspability,
            "b": planned.balance, "grasp": planned.grasp.to_dict(), "outcome": r.outcome.value,
            "grasped": [int(i) for i in r.grasped], "cos_beta": float(r.cos_beta)}


def graspability_map(obs, planner, targets) -> np.ndarray:
    """The network's U (sigmoid of the graspability output) for one target subset, (H, W)."""
    from planner.data import make_inputs
    from planner.inference import observation_arrays

    inten, depth, inst, _, cam_h = observation_arrays(obs)
    mask = np.isin(inst, [t + 1 for t in targets])
    out = planner.predict(make_inputs(inten, depth, mask[None], planner.config.in_channels, cam_h))
    return 1.0 / (1.0 + np.exp(-out[0, 3]))


# -- the four case studies ------------------------------------------------------------------------
def ranking_case(planner, cfg: CaseStudyConfig) -> tuple[np.ndarray, list[dict]]:
    """One pile, the best grasp of every subset ranked by Q, per objective; all tried."""
    from planner.inference import Objective, plan
    from synth.scene.generate import GenerationConfig

    size = planner.config.size_px
    seed, pile, obs = visible_pile(cfg.seed + _RANKING, GenerationConfig(n_logs=cfg.ranking_logs), size,
                                   cfg.max_seed_tries)
    tc = trial_config(cfg.trial)
    blocks, records = [], []
    for obj in cfg.ranking_objectives:
        p = plan(obs, planner, Objective(obj), pile=pile)
        panels = []
        for rank, g in enumerate(p.grasps, 1):
            rec = {"case": "ranking", "panel": f"{obj} #{rank}", "seed": seed, "objective": obj, "rank": rank,
                   **try_grasp(pile, g, tc)}
            records.append(rec)
            panels.append(titled(render_panel(obs, [(g.grasp, g.targets)], cfg),
                                  [f"#{rank} {fmt_targets(g.targets)} q={g.quality:.3f}",
                                   f"u={g.graspability:.2f} b={g.balance:.2f} {describe_trial(rec)}"],
                                  outcome_colour(rec["outcome"])))
        n_ok = sum(r["outcome"] == "success" for r in records if r["objective"] == obj)
        blocks.append(with_heading(grid_image(panels, cfg.ranking_columns),
                               f"seed {seed}: best grasp of every target subset ranked by Q = {obj} "
                               f"({n_ok}/{len(panels)} succeed in the twin)"))
    return stack_blocks(blocks), records


def obstacle_case(planner, cfg: CaseStudyConfig) -> tuple[np.ndarray, list[dict]]:
    """Piles without, then with an obstacle placed where the first chosen grasp's claw lands."""
    from planner.inference import Objective, plan
    from synth.scene.generate import GenerationConfig

    size = planner.config.size_px
    obj = Objective(cfg.objective)
    tc = trial_config(cfg.trial)
    rows, records = [], []
    seed = cfg.seed + _OBSTACLE
    for kind in cfg.obstacle_kinds:
        seed, pile, obs = visible_pile(seed, GenerationConfig(n_logs=cfg.obstacle_logs), size, cfg.max_seed_tries)
        before = plan(obs, planner, obj, pile=pile).best
        if before is None:
            raise CaseStudyError(f"the planner found no grasp on pile {seed}")
        with_ob, where = place_obstacle_near(pile, before.grasp, kind, cfg, seed)
        obs2 = observe(with_ob, size, seed)
        after = plan(obs2, planner, obj, pile=with_ob).best
        if after is None:
            raise CaseStudyError(f"the planner found no grasp on pile {seed} with the {kind}")
        base = {"case": "obstacle", "seed": seed, "objective": cfg.objective, "obstacle": kind,
                "obstacle_xy_m": list(where)}
        r0 = {**base, "panel": "without", **try_grasp(pile, before, tc)}
        r1 = {**base, "panel": f"with {kind}", **try_grasp(with_ob, after, tc)}
        r2 = {**base, "panel": f"first grasp, with {kind}", **try_grasp(with_ob, before, tc)}
        records += [r0, r1, r2]
        u0 = graspability_map(obs, planner, before.targets)
        u1 = graspability_map(obs2, planner, before.targets)
        u_max = float(max(u0.max(), u1.max()))
        t0 = fmt_targets(before.targets)
        rows += [
            titled(render_panel(obs, [(before.grasp, before.targets)], cfg),
                    [f"seed {seed}, no obstacle: {t0}", f"q={before.quality:.3f} {describe_trial(r0)}"],
                    outcome_colour(r0["outcome"])),
            titled(render_panel(obs2, [(after.grasp, after.targets)], cfg),
                    [f"{kind} placed: {fmt_targets(after.targets)}", f"q={after.quality:.3f} {describe_trial(r1)}"],
                    outcome_colour(r1["outcome"])),
            titled(render_panel(obs2, [(before.grasp, before.targets)], cfg),
                    [f"first grasp with the {kind}", f"{describe_trial(r2)}"], outcome_colour(r2["outcome"])),
            titled(u_panel(u0, obs, cfg, u_max), [f"U for {t0}, no obstacle", f"max {u0.max():.2f} (scale 0-{u_max:.2f})"]),
            titled(u_panel(u1, obs2, cfg, u_max), [f"U for {t0}, with {kind}", f"max {u1.max():.2f} (scale 0-{u_max:.2f})"]),
        ]
        seed += 1
    return grid_image(rows, 5), records


def _best_of_size(p, k: int):
    for g in p.grasps:
        if len(g.targets) == k:
            return g
    return None


def packed_case(planner, cfg: CaseStudyConfig) -> tuple[np.ndarray, list[dict]]:
    """Packed piles: the free choice and the best grasp on half of the logs; the first pile
    again with gaps between its logs."""
    from planner.inference import Objective, plan
    from synth.scene.generate import GenerationConfig

    size = planner.config.size_px
    obj = Objective(cfg.objective)
    tc = trial_config(cfg.trial)
    gen = GenerationConfig(n_logs=cfg.packed_logs, packed=True)
    cases = []
    seed = cfg.seed + _PACKED
    for k in range(cfg.packed_piles):
        seed, pile, obs = visible_pile(seed, gen, size, cfg.max_seed_tries)
        cases.append((seed, "packed", pile, obs))
        if k == 0:
            spread = spread_logs(pile, cfg.packed_gap_m)
            cases.append((seed, f"gaps {cfg.packed_gap_m:.2f} m", spread, observe(spread, size, seed)))
        seed += 1
    panels, records = [], []
    half = max(1, cfg.packed_logs // 2)
    for seed, label, pile, obs in cases:
        p = plan(obs, planner, obj, pile=pile)
        for which, g in (("free choice", p.best), (f"{half} of {pile.n_logs} logs", _best_of_size(p, half))):
            if g is None:
                continue
            rec = {"case": "packed", "panel": f"{label}, {which}", "seed": seed, "objective": cfg.objective,
                   **try_grasp(pile, g, tc)}
            records.append(rec)
            panels.append(titled(render_panel(obs, [(g.grasp, g.targets)], cfg),
                                  [f"seed {seed} {label}, {which}",
                                   f"{fmt_targets(g.targets)} q={g.quality:.3f} {describe_trial(rec)}"],
                                  outcome_colour(rec["outcome"])))
    return grid_image(panels, 2), records


def logs_case(planner, cfg: CaseStudyConfig) -> tuple[np.ndarray, list[dict]]:
    """Thick, short logs and conical logs: best grasp (thick) and the next two (thin)."""
    from planner.inference import Objective, plan
    from synth.scene.generate import GenerationConfig

    size = planner.config.size_px
    obj = Objective(cfg.objective)
    tc = trial_config(cfg.trial)
    thick = GenerationConfig(n_logs=cfg.shape_logs, length_mean_m=cfg.short_length_m, length_std_m=0.1,
                             diameter_mean_m=cfg.thick_diameter_m, diameter_std_m=0.02)
    conical = GenerationConfig(n_logs=cfg.shape_logs, diameter_mean_m=cfg.conical_butt_m, diameter_std_m=0.02)
    panels, records = [], []
    for label, gen, offset, edit in (
        (f"thick {cfg.thick_diameter_m:.2f} m, short {cfg.short_length_m:.1f} m", thick, _THICK, None),
        (f"conical, top/butt {cfg.conical_top_ratio:.2f}", conical, _CONICAL,
         lambda pl: taper_logs(pl, cfg.conical_top_ratio)),
    ):
        seed = cfg.seed + offset
        for _ in range(cfg.shape_piles):
            seed, pile, obs = visible_pile(seed, gen, size, cfg.max_seed_tries, edit)
            p = plan(obs, planner, obj, pile=pile)
            if p.best is None:
                raise CaseStudyError(f"the planner found no grasp on pile {seed}")
            rec = {"case": "logs", "panel": label, "seed": seed, "objective": cfg.objective,
                   **try_grasp(pile, p.best, tc)}
            records.append(rec)
            top = p.grasps[:3]
            panels.append(titled(render_panel(obs, [(g.grasp, g.targets) for g in top], cfg),
                                  [f"seed {seed} {label}",
                                   f"{fmt_targets(p.best.targets)} q={p.best.quality:.3f} {describe_trial(rec)}"],
                                  outcome_colour(rec["outcome"])))
            seed += 1
    return grid_image(panels, min(4, len(panels))), records


# -- the whole run ----------------------------------------------------------------------------
FIGURES = {"ranking": ranking_case, "obstacle": obstacle_case, "packed": packed_case, "logs": logs_case}


def run_case_studies(planner, out_dir: str | Path, cfg: CaseStudyConfig = CaseStudyConfig(),
                     model: dict | None = None, command: str = "", cases=tuple(FIGURES),
                     progress=None) -> dict:
    """Build the case studies ``cases`` with ``planner`` (a :class:`planner.inference.Planner`),
    write ``<case>.png``, ``results.json`` and ``README.md`` under ``out_dir``. ``model``
    describes the checkpoint (path, sha256, ...) for the record. Returns the results."""
    from synth.common.files import atomic_write_bytes
    from synth.render.preview import write_png

    unknown = set(cases) - set(FIGURES)
    if unknown:
        raise ValueError(f"unknown case studies {sorted(unknown)}; choose from {sorted(FIGURES)}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    records = []
    for name in cases:
        if progress:
            progress(name)
        img, recs = FIGURES[name](planner, cfg)
        write_png(out / f"{name}.png", img)
        records += recs
    results = RESULTS.document({"config": asdict(cfg), "model": model or {}, "command": command,
                                "cases": list(cases), "records": records})
    RESULTS.write(out, results)
    atomic_write_bytes(out / "README.md", readme_markdown(results).encode())
    return results


def read_results(path: str | Path) -> dict:
    """Read a ``results.json`` written by :func:`run_case_studies` (or its folder)."""
    return RESULTS.read(path)


_CAPTIONS = {
    "ranking": "one pile, the best grasp of every target subset, ranked by the model's Q (f1 = U; f3 = U τ^μ "
               "with the balance term); the title of each panel gives rank, targets, q, u, b and the twin "
               "trial outcome (green: success, red: failure) with logs held / targeted.",
    "obstacle": "each row: the pile without obstacle and the chosen grasp; the same pile with a rock or a stump "
                "placed where that grasp's claw lands (not touching any log) and the grasp chosen there; the "
                "first grasp tried again with the obstacle; the network's U for the first targets in both scenes "
                "(the paper's figure on obstacles).",
    "packed": "tightly packed piles: the free choice and the best grasp on half of the logs; the last row is "
              "the first pile spread with gaps between its logs and re-settled (the paper's packed-logs figure).",
    "logs": "thick, short logs and strongly tapered (conical) logs, far outside the training distribution "
            "(training logs: diameter 0.16 ± 0.02 m, length 2.5 ± 0.2 m, cylinders): best grasp thick, the next "
            "two thin.",
}


def readme_markdown(results: dict) -> str:
    """The case studies' README: command, seeds, model, figures and a table of outcomes."""
    cfg, model, recs = results["config"], results["model"], results["records"]
    lines = ["# Case studies (the paper's \"Results\" figures) in the twin", "",
             "Written by `scripts/case_studies.py` (library: `experiments/case_studies.py`); re-run it after the model "
             "changes, the pictures, `results.json` and this file are rewritten.", "",
             f"- Command: `{results['command']}`" if results.get("command") else "- Command: (library call)",
             f"- Model: `{model.get('path', '?')}`, sha256 `{model.get('sha256', '?')}`"
             + (f", epoch {model['epoch']}, val loss {model['val_loss']:.4f}" if "epoch" in model and
                isinstance(model.get("val_loss"), (int, float)) else "")
             + (f", {model['n_parameters']:,} parameters" if isinstance(model.get("n_parameters"), int) else ""),
             f"- Base seed {cfg['seed']} (ranking +{_RANKING}, obstacle +{_OBSTACLE}, packed +{_PACKED}, "
             f"thick/short +{_THICK}, conical +{_CONICAL}; the first seed whose logs are all visible is used; "
             "the seed of each pile is in the table)",
             f"- Trials: `synth.physics.trial.run_trial`, preset `{cfg['trial']}`; objective of the obstacle, packed and "
             f"logs figures: {cfg['objective']}", ""]
    for name in results["cases"]:
        lines += [f"## {name}", "", f"![{name}]({name}.png)", "", _CAPTIONS[name], ""]
        mine = [r for r in recs if r["case"] == name]
        if name == "ranking":
            for obj in cfg["ranking_objectives"]:
                ro = [r for r in mine if r["objective"] == obj]
                if not ro:
                    continue
                ok = sum(r["outcome"] == "success" for r in ro)
                top = ro[0]
                lines += [f"{obj}: {ok}/{len(ro)} subsets' best grasps succeed; the top-ranked grasp "
                          f"({fmt_targets(top['targets'])}, q = {top['q']:.3f}) gives `{top['outcome']}`.", ""]
        lines += ["| panel | seed | targets | q | u | b | outcome | held (enclosed if not lifted) |", "|---|---|---|---|---|---|---|---|"]
        for r in mine:
            lines.append(f"| {r['panel']} | {r['seed']} | {fmt_targets(r['targets'])} | {r['q']:.3f} | "
                         f"{r['u']:.3f} | {r['b']:.2f} | {r['outcome']} | {fmt_targets(r['grasped'])} |")
        lines.append("")
    return "\n".join(lines)


def model_record(path: str | Path, planner) -> dict:
    """Path, sha256 and training metadata of a checkpoint, for the results."""
    from synth.common.files import sha256_file

    meta = getattr(planner, "meta", {}) or {}
    rec = {"path": str(path), "sha256": sha256_file(Path(path))}
    for k in ("epoch", "val_loss", "n_parameters", "data_dir"):
        if k in meta:
            rec[k] = meta[k]
    return rec


__all__ = ["CaseStudyConfig", "CaseStudyError", "run_case_studies", "read_results", "readme_markdown",
           "place_obstacle_near", "spread_logs", "taper_logs", "visible_pile", "observe", "resettle",
           "graspability_map", "grid_image", "model_record"]
