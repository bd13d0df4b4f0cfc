"""``loggrasp train``, ``plan`` and ``eval``: thin commands over :mod:`planner`.

Flags take their defaults from the config dataclasses (:func:`synth.common.cli.option`); errors
are raised and printed once by ``field.cli.run``."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal

import typer

from planner.data import DataConfig
from planner.evaluate import EvalConfig, PlannerSpec
from planner.checkpoint import DEFAULT_MODEL
from planner.inference import PRODUCT_F3_BALANCE, Objective, f3_sigma_b
from planner.loss import LossWeights
from planner.model import UNetConfig
from planner.subsets import SubsetPolicy
from synth.data.outcomes import OutcomeLabelConfig
from planner.train import TrainConfig
from planner.pile_copies import PerturbationConfig
from planner.verify import VerifyConfig
from synth.cli import JSON, WORKERS
from synth.common.cli import progress_bar
from synth.common.cli import (EXIT_TRIAL, CliError, Output, check_input, check_output_dir, check_output_file,
                              field_default, option)


OBJECTIVE_HELP = "f1 (graspability), f2 (+ more logs), f3 (+ balance)."
MODEL = option("--model", "Checkpoint (.safetensors); default: the shipped model.", default=None, metavar="PATH")
VIEWS = option("--views", "Dihedral views the planner averages: 1, 2, 4 or 8 (slower, steadier).", default=1,
               names=["views"])
RANKER = option("--ranker", "The ranker checkpoint (loggrasp train-ranker) that re-scores the best --rerank-k grasps "
                "by f1 and by f3 and orders them by the objective with its success probability; default: the "
                "shipped ranker.", default=None, metavar="PATH")
NO_RANKER = option("--no-ranker", "Order the grasps by the network's U alone (no re-scoring).", default=False)
RERANK_K = option("--rerank-k", "Grasps the ranker re-scores per objective.", field=(PlannerSpec, "rerank_k"),
                  min=1, max=127)
RANKER_U_WEIGHT = option("--ranker-u-weight", "The re-scored grasps are ordered by sigmoid(W logit U + (1 - W) "
                         "logit p), U the network's, p the ranker's; 0 = p alone.",
                         field=(PlannerSpec, "ranker_u_weight"), min=0.0, max=1.0, metavar="W")

F3_SIGMA_B = option("--f3-sigma-b", "f3's balance tolerance sigma_b in Q = u tau^mu exp(-(b - 1)^2 / sigma_b^2), b = "
                    "cos(beta); default: 0.25 with --f3-balance network (the paper's), 0.05 with hang; eval rows "
                    "with another value than 0.25 are named unet-f3-...-sbS.", default=None, metavar="S")


def f3_balance_option(default: str, note: str = "") -> Any:
    return option("--f3-balance", "What f3's b is: network (the B map, the paper's) or hang (the tilt the load "
                  "will hang with, from its mask and mass: planner.balance; it keeps f3's loads level, "
                  f"docs/model.md).{note}", default=default, metavar="network|hang")


def f3_objective(kind: str, balance: str, sigma_b: float | None) -> Objective:
    """The objective the f3 flags name; a bad tolerance is a :class:`CliError` naming --f3-sigma-b."""
    try:
        return Objective(kind=kind, sigma_b=f3_sigma_b(balance, sigma_b), balance=balance)
    except ValueError as exc:
        raise CliError(f"--f3-sigma-b {sigma_b:g}: f3's balance tolerance must be > 0 (the paper's is 0.25)") from exc


PRECISION = option("--precision", "The network's number format: auto (int8 where the CPU has int8 dot products "
                   "and the model an int8 calibration beside it, else bf16 where the CPU has bf16 dot products, "
                   "else fp32), bf16, fp32, int8 or int8-bf16-top (CPU only, oneDNN int8 kernels, the calibration "
                   "beside the model; docs/model.md, int8).", default="auto",
                   metavar="auto|bf16|fp32|int8|int8-bf16-top")
VIEW_SPREAD = option("--view-spread", "Lower U by K x its spread over the views (needs --views > 1).", default=0.0,
                     names=["view_spread_k"], metavar="K")


def check_ranker_flags(ranker: Path | None, no_ranker: bool) -> tuple[bool, Path | None]:
    """(re-rank?, the ``--ranker`` file checked, or None for the shipped one): a contradiction or a
    missing file is a :class:`CliError` (exit 2) before any work. Shared by plan, trial and demo."""
    if no_ranker:
        if ranker is not None:
            raise CliError("--ranker and --no-ranker contradict each other: give one")
        return False, None
    return True, None if ranker is None else check_input(ranker, "--ranker", "file")


def load_ranker_flag(ranker: Path | None, no_ranker: bool):
    """The ranker ``--ranker`` / ``--no-ranker`` ask for (the shipped one by default), or None."""
    from planner.checkpoint import DEFAULT_RANKER
    from planner.ranker import load_ranker

    rerank, path = check_ranker_flags(ranker, no_ranker)
    return load_ranker(path or DEFAULT_RANKER) if rerank else None


# -- verified planning: flags and table cells shared by plan, trial and demo ---------------------------
def check_verify_flags(k: int | None, budget_s: float | None, off_hint: str = "") -> float | None:
    """Fail now (a :class:`CliError`, exit 2) on ``--verify K`` < 1 or a ``--verify-budget`` too
    small for one twin trial; returns the budget in seconds, None for no limit (0 on the command
    line). ``off_hint``: how this command turns verification off."""
    from planner.verify import VerifyConfig

    if k is not None and (isinstance(k, bool) or k < 1):
        raise CliError(f"--verify {k}: K is how many grasps the twin tries and must be >= 1"
                       + (f"; {off_hint}" if off_hint else ""))
    if budget_s is None or budget_s == 0:
        return None
    least = VerifyConfig().min_trial_s
    if not (math.isfinite(budget_s) and budget_s >= least):
        raise CliError(f"--verify-budget {budget_s:g} s is too small for one twin trial (at least {least:g} s); "
                       "give more time, or 0 for no limit")
    return float(budget_s)


def budget_message(exc, budget_s: float | None) -> str:
    """A :class:`planner.verify.VerificationBudgetError` in the flags' words."""
    n = len(exc.verification.candidates)
    ran = sum(len(c.trials) for c in exc.verification.candidates)
    return (f"--verify-budget {budget_s:g} s ran out before any of the {n} candidates was checked ({ran} twin "
            "trials ran; a candidate needs one on the pile and one on every perturbed copy): give a larger "
            "--verify-budget, fewer --verify-copies or more --verify-workers")


TWIN_COLUMNS = ["twin", "held", "beta deg"]


def twin_cells(verification, rank: int) -> list[str]:
    """The plan table's twin columns for plan rank ``rank`` (0 = best): the outcome of its trial
    on the pile as given (``*`` marks the chosen grasp; ``pruned`` / ``not_checked`` for one the
    twin did not finish), the logs it held and the measured load angle beta; empty for a grasp that
    was no candidate."""
    c = next((c for c in verification.candidates if c.rank == rank), None)
    if c is None:
        return ["", "", ""]
    chosen = verification.chosen is not None and verification.chosen.rank == rank
    outcome = c.outcome if c.checked else (c.status if not c.trials else f"{c.status}:{c.outcome}")
    if c.copies and c.trials:
        outcome += f" {c.successes}/{c.copies + 1}"
    held = str(len(c.held)) if c.nominal is not None and c.nominal.result is not None else "-"
    beta = (f"{math.degrees(math.acos(max(-1.0, min(1.0, c.cos_beta)))):.1f}" if math.isfinite(c.cos_beta)
            else "-")
    return [("*" if chosen else "") + outcome, held, beta]


def train_command(
    data: list[Path] = option("--data", "Data set folder (from `loggrasp synth dataset`); repeat to train on several.",
                              default=..., metavar="DIR"),
    out: Path = option("--out", "Run folder: checkpoints, log, training curve.", default=..., metavar="DIR"),
    epochs: int = option("--epochs", "Passes over the training split.", field=(TrainConfig, "epochs"), min=1),
    batch_size: int = option("--batch-size", "Samples per step.", field=(TrainConfig, "batch_size"), min=1),
    lr: float = option("--lr", "Adam learning rate.", field=(TrainConfig, "lr"), min=0.0),
    lr_schedule: Literal["cosine", "constant"] = option("--lr-schedule", "cosine (decays to 5 % of --lr) or constant.",
                                                        field=(TrainConfig, "lr_schedule"), metavar="cosine|constant"),
    base_channels: int = option("--base-channels", "U-Net width (23 ~ 4.0M parameters, the paper's size; 16 ~ 1.9M).",
                                field=(UNetConfig, "base_channels"), min=2, max=256),
    no_depth: bool = option("--no-depth", "The paper's ablation: inputs (I, M_T) only.", default=False),
    mask_injection: Literal["input", "decoder"] = option(
        "--mask-injection", "input (the paper's: the target mask is an input channel) or decoder (encode the "
        "image once per pile, the mask joins at the decoder: faster planning).",
        field=(UNetConfig, "mask_injection"), metavar="input|decoder"),
    u_pos_weight: float = option("--u-pos-weight", "BCE weight of positive U pixels (U marks ~0.3 % of pixels; "
                                 "25 = the shipped model's, 1 = the paper's plain BCE, which leaves U flat). "
                                 "Default: 25 with --labels accepted, 1 with --labels outcome (a probability).",
                                 default=None, min=0.0, metavar="FLOAT", names=["u_pos_weight"]),
    labels: Literal["accepted", "outcome"] = option(
        "--labels", "U's target: accepted (1 on the grasps Algorithm 1 accepted, the paper's) or outcome (every "
        "tried grasp centre labelled by its outcome or success fraction; needs a grasp store).",
        field=(DataConfig, "labels"), metavar="accepted|outcome"),
    untried_weight: float = option("--untried-weight", "With --labels outcome: BCE weight of untried pixels "
                                   "(tried centres weigh 1; untried pixels of capped subsets 0).",
                                   field=(OutcomeLabelConfig, "untried_weight"), min=0.0),
    b_encoding: Literal["cos_beta", "beta_10deg"] = option(
        "--b-encoding", "What the B map learns: cos_beta (the paper's; nearly constant) or beta_10deg (the tilt in "
        "10-degree units, weighted by --lambda-beta).", field=(UNetConfig, "b_encoding"),
        metavar="cos_beta|beta_10deg"),
    lambda_beta: float = option("--lambda-beta", "With --b-encoding beta_10deg: the B term's loss weight.",
                                field=(LossWeights, "lambda_beta"), min=0.0),
    seed: int = option("--seed", "Initialisation, data order and augmentation.", field=(TrainConfig, "seed")),
    device: Literal["auto", "cpu", "cuda"] = option("--device", "auto (cuda when available), cpu or cuda.",
                                                    field=(TrainConfig, "device"), metavar="auto|cpu|cuda"),
    precision: Literal["bf16", "fp32"] = option("--precision", "bf16 (autocast) or fp32.",
                                                field=(TrainConfig, "precision"), metavar="bf16|fp32"),
    max_steps_per_epoch: int = option("--max-steps-per-epoch", "Cap steps per epoch (quick runs).", default=None,
                                      min=1, metavar="INT", names=["max_steps_per_epoch"]),
    train_fraction: float = option("--train-fraction", "Use this share of the training piles (nested: a learning "
                                   "curve's smaller shares are subsets of its larger ones; validation unchanged).",
                                   field=(DataConfig, "train_fraction"), min=0.0, max=1.0),
    skip_no_candidates: bool = option("--skip-no-candidates", "Leave out target subsets that had no admissible "
                                      "grasp candidate (needs a data set made from a grasp store).",
                                      field=(DataConfig, "skip_no_candidates")),
    init_from: Path = option("--init-from", "Start from this checkpoint's weights (fine-tuning; same network "
                             "settings except --b-encoding, whose head is re-learnt).", default=None,
                             metavar="PATH", names=["init_from"]),
    as_json: bool = JSON,
) -> None:
    """Train the target-conditioned U-Net; re-running the same command resumes from the last checkpoint.

    The network's image size is the data set's (a 64 px data set trains a 64 px network).

    \b
    Example: loggrasp train --data data/ --out runs/r1 --epochs 50
    """
    from dataclasses import replace

    from planner.data import list_shards
    from planner.train import train

    o = Output(as_json)
    for d in data:
        check_input(d, "--data", "dir")
    check_output_dir(out, "--out")
    if init_from is not None:
        check_input(init_from, "--init-from", "file")
    _, grid = list_shards(data if len(data) > 1 else data[0])
    in_ch = 2 if no_depth else 3
    size = int(grid.get("size_px", UNetConfig().size_px))
    if labels == "outcome" and skip_no_candidates:
        raise CliError("--skip-no-candidates cannot be combined with --labels outcome: it hides the subsets without a "
                       "candidate, which inference scores; drop --skip-no-candidates")
    if u_pos_weight is None:
        u_pos_weight = 1.0 if labels == "outcome" else LossWeights().u_pos_weight
    cfg = TrainConfig(model=replace(UNetConfig(), base_channels=base_channels, in_channels=in_ch, size_px=size,
                                         mask_injection=mask_injection, b_encoding=b_encoding),
                      loss=replace(LossWeights(), u_pos_weight=u_pos_weight, lambda_beta=lambda_beta),
                      data=replace(DataConfig(), in_channels=in_ch, train_fraction=train_fraction,
                                   skip_no_candidates=skip_no_candidates, labels=labels,
                                   outcome=OutcomeLabelConfig(untried_weight=untried_weight)),
                      epochs=epochs, batch_size=batch_size,
                      lr=lr, lr_schedule=lr_schedule, seed=seed, device=device, precision=precision,
                      max_steps_per_epoch=max_steps_per_epoch, init_from=None if init_from is None else str(init_from))
    with progress_bar() as bar:
        task = bar.add_task("training", total=epochs, info="")

        def progress(ev: dict) -> None:
            def num(key: str) -> str:
                v = ev.get(key)
                return "-" if v is None else f"{v:.4f}"

            if ev.get("kind") == "epoch":
                bar.update(task, completed=(ev.get("epoch") or 0) + 1,
                           info=f"train {num('train_loss')} val {num('val_loss')}")
            else:  # completed = the epochs done, so a resumed run's bar starts where it resumes
                bar.update(task, completed=ev.get("epoch") or 0,
                           info=f"step {ev.get('step')} loss {num('loss')} "
                                      f"{ev.get('samples_per_s') or 0:.1f} samples/s")

        result = train(data if len(data) > 1 else data[0], out, cfg, progress=progress)
    o.say(f"best checkpoint: {result.model_path}\ntraining curve: {result.curve_path}")
    o.result("loggrasp.train", {"out": str(out), "model": str(result.model_path), "state": str(result.state_path),
                                "log": str(result.log_path), "curve": str(result.curve_path), "size_px": size})


def load_observation(path: Path, cfg, warn=None):
    """An observation from a pile folder (its ortho.npz when it has the network's pixel pitch,
    else re-rendered) or a pile.json (rendered at the pitch of ``cfg``, a
    :class:`planner.model.UNetConfig`). Returns (observation, pile or None). ``warn(text)`` hears
    about an ortho.npz that could not be used beside a readable pile.json."""
    from planner.errors import ObservationError
    from planner.inference import check_grid
    from synth.errors import PileFormatError
    from synth.scene.pile import read_pile
    from synth.render.ortho import OrthoObservation, OrthoRenderConfig, render_ortho
    from synth.physics.world import World

    folder = path if path.is_dir() else path.parent
    pile = None
    if (folder / "pile.json").exists() or path.suffix == ".json":
        pile = read_pile(path)
    npz = folder / "ortho.npz" if path.suffix != ".npz" else path
    if npz.exists():
        try:
            obs = OrthoObservation.load(npz)
        except PileFormatError as exc:
            if pile is None:
                raise
            if warn:
                warn(f"{exc}; rendering from {folder / 'pile.json'} instead")
        else:
            try:
                check_grid(obs.depth.shape[0], obs.extent_m, cfg)
                return obs, pile
            except ObservationError:
                pass  # rendered from the pile below
    if pile is None:
        raise ObservationError(f"{path}: neither a pile.json nor an ortho.npz at the network's pixel pitch "
                               f"({100 * cfg.pixel_m:.2f} cm)")
    size = max(16, round(pile.terrain.extent_m / cfg.pixel_m))  # plan() names a patch that does not fit
    try:
        world = World(pile)
    except Exception as exc:  # pybullet and its mesh code raise plain errors (a flat rock: no hull)
        first = (str(exc).strip().splitlines() or [""])[0][:160]
        raise ObservationError(f"the twin cannot load the pile {path} to render it ({type(exc).__name__}: {first}); "
                               "check the pile file (loggrasp synth render PILE)") from exc
    with world:
        return render_ortho(world, OrthoRenderConfig(size_px=size, n_renders=1), seed=pile.seed or 0), pile


def plan_command(
    pile: Path = typer.Argument(..., metavar="PILE",
                                help="A pile folder (pile.json and/or ortho.npz), a pile.json or an ortho.npz."),
    model: Path = MODEL,
    objective: Literal["f1", "f2", "f3"] = option("--objective", OBJECTIVE_HELP, field=(Objective, "kind"),
                                                  metavar="f1|f2|f3", names=["objective"]),
    top: int = option("--top", "How many subsets' best grasps to list (and draw).", default=5, min=1,
                      names=["top_k"]),
    as_json: bool = option("--json", "Print the plan as JSON (format loggrasp.plan) on standard output.",
                           default=False),
    png: Path = option("--png", "Write a picture of the plan: ranked grasps over the render, legend, scale, "
                       "north.", default=None, metavar="OUT.png"),
    max_subsets: int = option("--max-subsets", "Network passes budget; larger piles are pruned.",
                              field=(SubsetPolicy, "max_subsets"), min=1),
    views: int = VIEWS,
    view_spread: float = VIEW_SPREAD,
    verify: int = option("--verify", "Let the twin try the K best grasps on the pile (needs its pile.json) and "
                         "choose the best that succeeded there; off when not given. Exit 4 when none succeeded.",
                         default=None, metavar="K"),
    verify_copies: int = option("--verify-copies", "With --verify: also try each grasp that succeeded on this many "
                                "perturbed copies of the pile (the reconstruction's uncertainty).",
                                field=(PerturbationConfig, "copies"), min=0, max=64, names=["verify_copies"]),
    verify_budget: float = option("--verify-budget", "With --verify: wall time for the twin's trials; no trial "
                                  "starts after it (0 = no limit).", field=(VerifyConfig, "time_budget_s"),
                                  names=["verify_budget_s"]),
    verify_workers: int = option("--verify-workers", "With --verify: processes for the twin's trials (0 = all "
                                 "cores, 1 = in this process).", default=field_default(VerifyConfig, "workers"),
                                 min=0, names=["verify_workers"]),
    ranker: Path = RANKER,
    no_ranker: bool = NO_RANKER,
    rerank_k: int = RERANK_K,
    ranker_u_weight: float = RANKER_U_WEIGHT,
    f3_sigma_b: float = F3_SIGMA_B,
    f3_balance: Literal["network", "hang"] = f3_balance_option(PRODUCT_F3_BALANCE),
    precision: Literal["auto", "bf16", "fp32", "int8", "int8-bf16-top"] = PRECISION,
    over_obstacles: bool = option("--grasp-over-obstacles", "Allow grasps whose claws come down on a rock or stump "
                                  "the pile shows (by default each such grasp moves to its subset's next best pixel).",
                                  default=False),
) -> None:
    """Plan the best multi-log grasp on a pile: every target subset scored with Q = f(U, tau, B).

    The shipped grasp ranker then re-scores the best grasps by f1 and by f3 (--rerank-k of each) and
    orders them by the objective with U replaced by the blend of U and its success probability
    (--no-ranker: U alone, the paper's planner).

    With --verify K the twin tries the K best grasps on the pile itself and the table shows each
    one's twin outcome, the logs it held and beta; the grasp marked * is the best that succeeded
    (by the objective computed from what the twin measured). A verification cut short by
    --verify-budget chooses only among the grasps it checked and says which.

    \b
    Example: loggrasp plan piles/pile_00000 --objective f3 --json
    Example: loggrasp plan recon/s3 --objective f3 --png plan.png
    Example: loggrasp plan piles/pile_00000 --objective f3 --verify 8 --verify-budget 20
    Example: loggrasp plan piles/pile_00000 --objective f3 --precision int8
    """
    from rich.console import Console

    from planner.constraints import Constraints
    from planner.inference import load_planner
    from planner.ranker import plan_reranked

    o = Output(as_json)
    path = model or DEFAULT_MODEL
    pile_json, spec, vcfg = _check_plan_flags(pile, path, png, views, view_spread, verify, verify_copies,
                                              verify_budget, verify_workers)
    obj = f3_objective(objective, f3_balance, f3_sigma_b)
    rk = load_ranker_flag(ranker, no_ranker)
    try:
        planner = load_planner(path, precision=precision, views=views, view_spread_k=view_spread)
    except ValueError as exc:  # an int8 precision where it cannot run
        raise CliError(f"--precision {precision}: {exc}") from exc
    obs, spec = load_observation(pile, planner.config, warn=o.warn)
    o.progress(f"planning on {pile}: {obs.n_logs} logs, up to {max_subsets} target subsets x {views} view(s)")
    with Console(stderr=True).status("planning"):
        keep = top if vcfg is None else max(top, vcfg.k)
        result = plan_reranked(obs, planner, obj, rk, Constraints(clear_obstacles=not over_obstacles), top_k=keep,
                               rerank_k=rerank_k, u_weight=ranker_u_weight,
                               subsets=SubsetPolicy(max_subsets=max_subsets), pile=spec)
    verification = None
    if vcfg is not None:
        from planner.verify import VerificationBudgetError, verify_plan

        o.progress(f"verifying: the twin tries the best {vcfg.k} grasps on {pile_json}"
                   + (f", each also on {verify_copies} perturbed copies" if verify_copies else "")
                   + (f" ({vcfg.time_budget_s:g} s)" if vcfg.time_budget_s is not None else " (no time limit)"))
        try:
            verification = verify_plan(result, spec, obj, vcfg)
        except VerificationBudgetError as exc:
            raise CliError(budget_message(exc, vcfg.time_budget_s)) from exc
    if png is not None:
        from planner.pictures import draw_plan

        draw_plan(obs, result, png, pile=spec, objective=obj, top=top)
    _print_plan(o, pile, result, verification, obj, png)


def _check_plan_flags(pile: Path, model: Path, png: Path | None, views: int, view_spread: float, verify: int | None,
                      verify_copies: int, verify_budget: float | None, verify_workers: int):
    """``plan``'s flags and files checked before the network loads: (pile.json path, its pile or
    None, the verification config or None)."""
    from planner.inference import check_views

    check_views(views, view_spread)
    budget_s = check_verify_flags(verify, verify_budget)
    if verify is None and verify_copies:
        raise CliError("--verify-copies needs --verify K")
    check_input(pile, "PILE")
    check_input(model, "--model", "file")
    if png is not None:
        check_output_file(png, "--png", ".png")
    pile_json = pile if pile.suffix == ".json" else pile / "pile.json" if pile.is_dir() else pile.parent / "pile.json"
    if verify is not None and not pile_json.is_file():
        raise CliError(f"--verify needs the pile the plan is made on, and {pile} has no pile.json: give a pile "
                       "folder with its pile.json, or the pile.json itself (in the field: the reconstruction's)")
    spec = None
    if pile_json.is_file():
        from synth.scene.pile import read_pile

        spec = read_pile(pile_json)  # a bad pile file stops the command before the network loads
        if verify is not None:
            from planner.pile_copies import check_twin_loads

            check_twin_loads(spec)
    vcfg = None
    if verify is not None:
        vcfg = VerifyConfig(k=verify, time_budget_s=budget_s, workers=verify_workers,
                            perturbation=PerturbationConfig(copies=verify_copies))
    return pile_json, spec, vcfg


def _print_plan(o: Output, pile: Path, result, verification, objective: Objective, png: Path | None) -> None:
    """The plan as JSON, its table, the constraints' removals and the verification's verdict
    (exit 4 when no checked grasp succeeded)."""
    how = {"balance": objective.balance, "sigma_b": objective.sigma_b} if objective.kind == "f3" else {}
    doc = {k: v for k, v in result.to_dict().items() if k != "info"} | {"pile": str(pile),
                                                                         "objective": {"kind": objective.kind, **how}}
    if verification is not None:
        doc["verification"] = verification.to_dict()
    if "reranked" in result.info:  # the first n grasps' U is the blend of U and the ranker's p; both beside it
        doc["ranker"] = {k: result.info[k] for k in ("reranked", "u_network", "p_ranker", "u_weight")}
        o.progress(f"ranker: the first {result.info['reranked']} grasps re-scored (their U is the blend of the "
                   f"network's U and the ranker's p, weight {result.info['u_weight']:g} on U); the others follow "
                   "with Q 0")
    o.result("loggrasp.plan", doc)
    rows = [[str(i + 1), ",".join(map(str, g.targets)), f"{g.grasp.x_m:.3f}", f"{g.grasp.y_m:.3f}",
             f"{math.degrees(g.grasp.phi_rad):.1f}", f"{g.grasp.width_m:.3f}", f"{g.quality:.3f}",
             f"{g.graspability:.3f}", f"{g.balance:.3f}"]
            + ([] if verification is None else twin_cells(verification, i)) for i, g in enumerate(result.grasps)]
    o.table(f"plan for {pile}: {result.subsets_evaluated} target subsets in {result.elapsed_s:.2f} s, "
            f"objective {objective.kind}"
            + (f", b from the {'hang model' if objective.balance == 'hang' else 'B map'}, sigma_b "
               f"{objective.sigma_b:g}" if how else "")
            + " (Q = quality, U = graspability, B = balance; pile frame"
            + ("; twin: outcome on the pile, * = chosen" if verification is not None else "") + ")",
            ["rank", "targets", "x m", "y m", "phi deg", "width m", "Q", "U", "B"]
            + ([] if verification is None else TWIN_COLUMNS), rows)
    if not result.grasps:
        o.say("no grasp: every target subset was removed by a constraint (below)")
    for r in result.rejected:
        o.say(f"{'no grasp for' if r['action'] == 'removed' else 'moved grasp of'} targets {r['targets']}: "
              f"{r['constraint']} ({r['detail']})")
    if png is not None:
        o.say(f"picture: {png}")
    if verification is not None:
        if not verification.ok:
            raise CliError(verification.reason, EXIT_TRIAL)
        o.say(verification.reason)


def eval_command(
    out: Path = option("--out", "Results folder (records, results.md/json, examples.png).", default=...,
                       metavar="DIR"),
    model: Path = MODEL,
    per_cell: int = option("--per-cell", "Piles per (size, obstacles) cell.", field=(EvalConfig, "per_cell"), min=1),
    logs: str = option("--logs", "Pile sizes, 'A-B' or 'A'.", default="2-7"),
    obstacles: Literal["yes", "no", "both"] = option("--obstacles", "Cells with obstacles: yes, no or both.",
                                                     default="both", metavar="yes|no|both"),
    objectives: str = option("--objectives", "Comma-separated U-Net objectives: f1,f2,f3.", default="f1,f2,f3"),
    baselines: str = option("--baselines", "Comma-separated baselines through the same trials: random, geometric, "
                            "oracle ('' for none).", default="random,geometric,oracle"),
    extra_model: list[str] = option("--extra-model", "LABEL=PATH, e.g. no-depth=runs/nd/best.safetensors; repeatable.",
                                    default=[], metavar="LABEL=PATH"),
    workers: int = WORKERS,
    engine: Literal["local", "dask"] = option("--engine", "local (process pool) or dask.", default="local",
                                              metavar="local|dask"),
    address: str = option("--address", "Dask scheduler address (tcp://HOST:PORT); none = a local cluster.",
                          default=None, metavar="URL"),
    trial: Literal["fast", "careful"] = option("--trial", "Trial preset.", field=(EvalConfig, "trial"),
                                                metavar="fast|careful"),
    seed_base: int = option("--seed-base", "First test seed (keep far from training seeds).",
                            field=(EvalConfig, "seed_base")),
    verify: int = option("--verify", "Add a verified U-Net row per objective: its K best grasps tried in the twin on "
                         "a perturbed copy of each test pile (never the pile itself), the best that succeeded "
                         "there is the one tried on the pile.", default=None, metavar="K"),
    verify_copies: int = option("--verify-copies", "With --verify: further perturbed copies each grasp is tried on.",
                                field=(PlannerSpec, "verify_copies"), min=0, max=64),
    views: int = option("--views", "Add a U-Net row per objective that averages V dihedral test-time views (2, 4 "
                        "or 8; V times the planning time).", default=None, metavar="V"),
    view_spread: float = option("--view-spread", "With --views: lower U by K x its spread over the views.",
                                default=0.0, metavar="K"),
    ranker: Path = option("--ranker", "Add a U-Net row per objective (and per verified row) whose best --rerank-k "
                          "grasps by f1 and by f3 a ranker checkpoint re-scores.", default=None, metavar="PATH"),
    ranked_only: bool = option("--ranked-only", "With --ranker: only the re-ranked rows (the product's planner), "
                               "not the U-Net rows they re-rank.", default=False),
    rerank_k: int = RERANK_K,
    ranker_u_weight: float = RANKER_U_WEIGHT,
    f3_sigma_b: float = F3_SIGMA_B,
    f3_balance: Literal["network", "hang"] = f3_balance_option("network", " Eval's default is the paper's; hang rows "
                                                               "are named unet-f3-hang."),
    field_error: str = option("--field-error", "Add a field row per planner: its chosen grasp executed with the "
                              "crane's positioning error, SIGMA_XY_M,SIGMA_PHI_DEG (e.g. 0.03,2: 3 cm per axis, 2 deg).",
                              default=None, metavar="M,DEG"),
    precision: Literal["auto", "bf16", "fp32", "int8", "int8-bf16-top"] = PRECISION,
    as_json: bool = option("--json", "Print results.json (format loggrasp.eval-results) on standard output.",
                           default=False),
) -> None:
    """Evaluate planners in the twin, the paper's protocol: fresh piles, one grasp each, tried in physics.

    \b
    Example: loggrasp eval --per-cell 100 --logs 2-7 --obstacles both --objectives f1,f2,f3 --out results/
    Re-running resumes (one record file per pile).
    """
    import json
    from dataclasses import replace

    from planner.cli.eval_specs import base_specs, view_specs, with_precision, with_ranker
    from planner.evaluate import run_evaluation
    from synth.common.ranges import parse_range

    o = Output(as_json)
    if address is not None and engine != "dask":
        raise CliError("--address needs --engine dask")
    lo, hi = parse_range(logs, "--logs")
    obs = {"yes": (True,), "no": (False,), "both": (True, False)}[obstacles]
    error = None
    if field_error is not None:
        from synth.physics.perturb import PositioningError

        try:
            error = PositioningError.parse(field_error)
        except ValueError as exc:
            raise CliError(f"--field-error: {exc}") from exc
    cfg = EvalConfig(logs=tuple(range(lo, hi + 1)), obstacles=obs, per_cell=per_cell, trial=trial, seed_base=seed_base,
                     field_error=error)
    specs = base_specs(str(model or DEFAULT_MODEL), objectives, baselines, extra_model, verify, verify_copies)
    specs += view_specs(str(model or DEFAULT_MODEL), objectives, views, view_spread)
    f3 = f3_objective("f3", f3_balance, f3_sigma_b)
    specs = [replace(s, sigma_b=f3.sigma_b, balance=f3.balance) if s.kind == "unet" and s.objective == "f3" else s
             for s in specs]
    specs = with_ranker(specs, ranker, rerank_k, ranker_u_weight, ranked_only)
    specs = with_precision(specs, precision)
    check_output_dir(out, "--out")
    with progress_bar() as bar:
        task = bar.add_task("piles", total=len(cfg.tasks()), info="")
        run_evaluation(specs, cfg, out, workers=workers, engine=engine, address=address,
                                progress=lambda d, t: bar.update(task, completed=d))
    if as_json:
        o.result("loggrasp.eval-results", json.loads((Path(out) / "results.json").read_text()))
    else:
        o.say((Path(out) / "results.md").read_text().rstrip())
    o.say(f"results: {Path(out) / 'results.md'}, {Path(out) / 'results.json'}; examples: {Path(out) / 'examples.png'}")


