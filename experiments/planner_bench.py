"""Planner speed: training throughput and planning latency on this machine (``make bench``
section "planner", through ``bench/bench_planner.py``, which is also its command when run alone).

Measures, with 2 torch threads:
* training samples/s (forward + backward + Adam, batch 16, 128 px) for the default (~4.0 M) and
  the small (~1.9 M) U-Net, plain fp32 vs channels-last + bf16 autocast;
* planning latency (``planner.inference.plan``, all steps included) on settled, rendered piles of
  4, 7 and 12 logs with the default-width network, input vs decoder mask injection;
* what subset pre-selection (caps 32 and 64) costs against exhaustive search on 7-log piles with a
  trained checkpoint (``LOGGRASP_PLANNER_CKPT`` or ``--model``, default the shipped model): best-q
  ratio, whether the exhaustive best subset is kept, and the twin trial success of each chosen
  grasp on the same piles (``--pruning-only`` runs just that table, ~5-10 min on 2 cores).
Wall times are sensitive to other load on the 2 cores: each table states the load average.
"""

from __future__ import annotations

import os
import statistics
import time
from pathlib import Path

from experiments.measure import load_average
from planner.checkpoint import DEFAULT_MODEL
from planner.runtime import int8_kernels_available

ROOT = Path(__file__).resolve().parents[1]  # the repository (for model paths in the tables)


def training_throughput(batch: int = 16, steps: int = 3, size: int = 128) -> list[dict]:
    import torch

    from planner.loss import grasp_loss
    from planner.model import UNetConfig, build_unet, count_parameters

    torch.set_num_threads(2)
    rows = []
    for name, cfg in (("default", UNetConfig(size_px=size)), ("small", UNetConfig(base_channels=16, size_px=size))):
        for mode in ("fp32", "bf16+CL"):
            torch.manual_seed(0)
            m = build_unet(cfg)
            x = torch.rand(batch, 3, size, size)
            y = torch.rand(batch, 5, size, size)
            y[:, 3] = (y[:, 3] > 0.9).float()
            if mode != "fp32":
                m = m.to(memory_format=torch.channels_last)
                x = x.contiguous(memory_format=torch.channels_last)
            opt = torch.optim.Adam(m.parameters(), 1e-3)
            times, cpu = [], []
            for k in range(steps + 1):
                t0, c0 = time.perf_counter(), time.process_time()
                if mode == "fp32":
                    pred = m(x)
                else:
                    with torch.autocast("cpu", dtype=torch.bfloat16):
                        pred = m(x)
                loss, _ = grasp_loss(pred, y)
                opt.zero_grad()
                loss.backward()
                opt.step()
                if k:  # first step warms up
                    times.append(time.perf_counter() - t0)
                    cpu.append(time.process_time() - c0)
            rows.append({"model": name, "params": count_parameters(m), "mode": mode,
                         "samples_per_s": batch / statistics.median(times),
                         "cpu_s_per_sample": statistics.median(cpu) / batch})
    return rows


def _pile_observations(n_logs: int, count: int, size: int = 128, seed0: int = 100):
    from synth.scene.generate import GenerationConfig, generate_pile
    from synth.render.ortho import OrthoRenderConfig, render_ortho
    from synth.physics.world import World

    out = []
    for k in range(count):
        pile, _ = generate_pile(seed0 + 17 * n_logs + k, GenerationConfig(n_logs=n_logs, n_obstacles=2))
        with World(pile) as world:
            out.append((render_ortho(world, OrthoRenderConfig(size_px=size, n_renders=1)), pile))
    return out


def planning_latency(n_logs=(4, 7, 12), repeats: int = 3,
                     variants=(("default", 23, "input"), ("default", 23, "decoder"), ("small", 16, "input"))) -> list[dict]:
    import torch

    from planner.inference import Planner, plan
    from planner.model import UNetConfig, build_unet

    torch.set_num_threads(2)
    obs = {n: _pile_observations(n, 1)[0][0] for n in n_logs}
    rows = []
    for name, base, inj in variants:
        cfg = UNetConfig(base_channels=base, mask_injection=inj)
        torch.manual_seed(0)
        pl = Planner(build_unet(cfg), cfg, precision="bf16")
        plan(obs[n_logs[0]], pl)  # warm-up (oneDNN kernels)
        for n in n_logs:
            walls, cpus, p = [], [], None
            for _ in range(repeats):
                c0 = time.process_time()
                p = plan(obs[n], pl)
                walls.append(p.elapsed_s)
                cpus.append(time.process_time() - c0)
            rows.append({"model": name, "injection": inj, "logs": n, "subsets": p.subsets_evaluated,
                         "selection": p.info["selection"], "n_fit": p.info.get("n_fit"),
                         "wall_s": statistics.median(walls), "cpu_s": statistics.median(cpus)})
    return rows


def views_latency(n_logs=(4, 7), views=(1, 4, 8), repeats: int = 3) -> list[dict]:
    """Planning time of the shipped model with 1, 4 and 8 averaged test-time views (f3, 2 threads)."""
    import torch

    from planner.inference import Objective, load_planner, plan

    torch.set_num_threads(2)
    obs = {n: _pile_observations(n, 1)[0][0] for n in n_logs}
    rows = []
    for v in views:
        pl = load_planner(DEFAULT_MODEL, device="cpu", views=v, view_spread_k=2.0 if v > 1 else 0.0)
        plan(obs[n_logs[0]], pl)  # warm-up
        for n in n_logs:
            walls = [plan(obs[n], pl, Objective(kind="f3")).elapsed_s for _ in range(repeats)]
            rows.append({"views": v, "logs": n, "wall_s": statistics.median(walls)})
    return rows


def ranker_latency(n_logs=(4, 7), ks=(4, 8), repeats: int = 5) -> list[dict]:
    """Planning time of the shipped model (f3, all subsets, 2 threads) without and with re-ranking by a
    ranker (:mod:`planner.ranker`, untrained weights: the time does not depend on them) of the best k
    grasps by f1 and by f3: the re-ranking's own time is the crops plus one small forward pass."""
    import torch

    from planner.inference import Objective, load_planner, plan
    from planner.ranker import Ranker, RankerConfig, build_ranker, rerank

    torch.set_num_threads(2)
    torch.manual_seed(0)
    rk = Ranker(build_ranker(RankerConfig()).eval(), RankerConfig(), {})
    pl = load_planner(DEFAULT_MODEL, device="cpu")
    obs = {n: _pile_observations(n, 1)[0][0] for n in n_logs}
    f3 = Objective(kind="f3")
    plan(obs[n_logs[0]], pl)  # warm-up
    rows = []
    for n in n_logs:
        for k in (0,) + tuple(ks):
            walls, reranked = [], 0
            for _ in range(repeats):
                t0 = time.perf_counter()
                p = plan(obs[n], pl, f3)
                if k:
                    p = rerank(p, obs[n], rk, f3, k)
                    reranked = p.info["reranked"]
                walls.append(time.perf_counter() - t0)
            rows.append({"logs": n, "k": k, "reranked": reranked, "wall_s": statistics.median(walls)})
    return rows


def balance_latency(n_logs=(4, 7), repeats: int = 5) -> list[dict]:
    """Planning time of the shipped model (f3, all subsets, 2 threads) with f3's b from the network's B map
    and from the hang model (:mod:`planner.balance`: one distance raster per subset)."""
    import torch

    from planner.inference import Objective, f3_sigma_b, load_planner, plan

    torch.set_num_threads(2)
    pl = load_planner(DEFAULT_MODEL, device="cpu")
    obs = {n: _pile_observations(n, 1)[0][0] for n in n_logs}
    plan(obs[n_logs[0]], pl)  # warm-up
    rows = []
    for n in n_logs:
        for balance in ("network", "hang"):
            f3 = Objective(kind="f3", balance=balance, sigma_b=f3_sigma_b(balance))
            walls = [plan(obs[n], pl, f3).elapsed_s for _ in range(repeats)]
            rows.append({"logs": n, "balance": balance, "wall_s": statistics.median(walls)})
    return rows


def balance_markdown(rows: list[dict]) -> list[str]:
    lines = [f"Planning with f3's balance from the B map or the hang model (`--f3-balance hang`), shipped model, "
             f"all subsets, 2 threads, median of 5 ({load_average()}). Target: a 7-log pile (127 subsets) <= 0.5 s.",
             "", "| logs | f3's balance | wall s |", "|---|---|---|"]
    return lines + [f"| {r['logs']} | {r['balance']} | {r['wall_s']:.3f} |" for r in rows]


def plan_cost(n_logs=(4, 7), threads=(1, 2), repeats: int = 5) -> list[dict]:
    """Wall and CPU seconds of one plan with the shipped model as it loads by default ("auto"; f3, all
    subsets) with 1 and 2 torch threads, median of ``repeats`` (:func:`precision_cost`). The CPU
    seconds of the one-thread run are the figure another job's load on a shared machine barely
    moves; a two-thread wall time there measures the neighbours as much as the planner (a thread
    descheduled inside a parallel region stalls the other one)."""
    return [r for t in threads for r in precision_cost(("auto",), n_logs, rounds=1, repeats=repeats, threads=t)]


def precision_cost(precisions=("bf16", "int8"), n_logs: int | tuple[int, ...] = 7, rounds: int = 3,
                   repeats: int = 3, threads: int = 1) -> list[dict]:
    """CPU and wall seconds of an f3 plan (all subsets) of one pile of each of ``n_logs`` logs with the
    shipped model in each of ``precisions`` on ``threads`` torch threads, the precisions alternating
    within each of ``rounds`` (each round's figure the median of ``repeats`` plans). One thread's CPU
    seconds are the comparison other jobs on a shared machine move least; two threads' wall seconds are
    the target's figure, meaningful on idle cores only. Returns one row per precision and pile size:
    median, min and max over the rounds; ``precision`` is the format that ran ("auto" resolved)."""
    import torch

    from planner.inference import Objective, load_planner, plan
    from planner.runtime import masks_per_pass

    sizes = (n_logs,) if isinstance(n_logs, int) else tuple(n_logs)
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        obs = {n: _pile_observations(n, 1)[0][0] for n in sizes}
        planners = {p: load_planner(DEFAULT_MODEL, device="cpu", precision=p) for p in precisions}
        f3 = Objective(kind="f3")
        for pl in planners.values():
            plan(obs[sizes[0]], pl, f3)  # warm-up (oneDNN kernels)
        subsets = {n: plan(obs[n], planners[precisions[0]], f3).subsets_evaluated for n in sizes}
        batch = {p: masks_per_pass(pl.batch_size) for p, pl in planners.items()}  # at these threads
        cpu: dict = {(p, n): [] for p in precisions for n in sizes}
        wall: dict = {(p, n): [] for p in precisions for n in sizes}
        for _ in range(rounds):
            for n in sizes:
                for p, pl in planners.items():
                    cpus, walls = [], []
                    for _ in range(repeats):
                        c0 = time.process_time()
                        walls.append(plan(obs[n], pl, f3).elapsed_s)
                        cpus.append(time.process_time() - c0)
                    cpu[p, n].append(statistics.median(cpus))
                    wall[p, n].append(statistics.median(walls))
    finally:
        torch.set_num_threads(before)
    return [{"precision": planners[p].precision, "logs": n, "subsets": subsets[n], "rounds": rounds,
             "repeats": repeats, "threads": threads, "batch": batch[p],
             "cpu_s": statistics.median(v), "cpu_min_s": min(v), "cpu_max_s": max(v),
             "wall_s": statistics.median(wall[p, n]), "wall_min_s": min(wall[p, n]), "wall_max_s": max(wall[p, n]),
             "load": load_average("")} for (p, n), v in cpu.items()]


def precision_markdown(rows: list[dict]) -> list[str]:
    lines = ["Planning cost by precision (`--cost-only --precisions`): shipped model, f3, all subsets, CPU and "
             "wall s per plan; the precisions alternate, median (min-max) over the rounds of each round's median. "
             "Target: a 7-log pile (127 subsets) <= 0.5 s wall on 2 cores (2 threads, idle cores only).", "",
             "| precision | logs | subsets | torch threads | rounds x plans | CPU s | wall s | load |",
             "|---|---|---|---|---|---|---|---|"]
    return lines + [f"| {r['precision']} | {r['logs']} | {r['subsets']} | {r['threads']} | {r['rounds']} x {r['repeats']} | "
                    f"{r['cpu_s']:.3f} ({r['cpu_min_s']:.3f}-{r['cpu_max_s']:.3f}) | "
                    f"{r['wall_s']:.3f} ({r['wall_min_s']:.3f}-{r['wall_max_s']:.3f}) | {r['load']} |" for r in rows]


def cost_markdown(rows: list[dict]) -> list[str]:
    lines = ["Planning cost, shipped model as loaded by default, f3, all subsets, median of 5 (load average at "
             "each row: 1/5/15 min). Target: a 7-log pile (127 subsets) <= 0.5 s wall on 2 cores.", "",
             "| logs | subsets | torch threads | precision | batch | wall s | CPU s | load |",
             "|---|---|---|---|---|---|---|---|"]
    return lines + [f"| {r['logs']} | {r['subsets']} | {r['threads']} | {r['precision']} | {r['batch']} | "
                    f"{r['wall_s']:.3f} | {r['cpu_s']:.3f} | {r['load']} |" for r in rows]


def ranker_markdown(rows: list[dict]) -> list[str]:
    lines = [f"Planning with re-ranking (`--ranker R --rerank-k K`), shipped model, f3, all subsets, 2 threads, "
             f"median of 5 ({load_average()}); K 0 = no ranker. Target: a 7-log pile (127 subsets) <= 0.5 s.", "",
             "| logs | K | grasps re-scored | wall s |", "|---|---|---|---|"]
    return lines + [f"| {r['logs']} | {r['k']} | {r['reranked']} | {r['wall_s']:.3f} |" for r in rows]


def views_markdown(rows: list[dict]) -> list[str]:
    lines = [f"Planning with averaged test-time views (`--views V --view-spread 2`), shipped model, f3, all subsets, "
             f"2 threads, median of 3 ({load_average()}):", "", "| views | logs | wall s |", "|---|---|---|"]
    return lines + [f"| {r['views']} | {r['logs']} | {r['wall_s']:.2f} |" for r in rows]


class _SharedOutputs:
    """A planner whose network outputs are cached per input (image + one target mask): every
    plan on one pile (exhaustive, pre-selected, any objective) scores a subset with exactly the
    same output, computed once. A subset's output does not depend on the other subsets in its
    batch, so this changes no plan, only the CPU spent on repeated forward passes."""

    def __init__(self, planner) -> None:
        self._planner = planner
        self._cache: dict[bytes, object] = {}

    def __getattr__(self, name):
        return getattr(self._planner, name)

    def clear(self) -> None:
        self._cache.clear()

    def predict(self, x):
        import hashlib

        import numpy as np

        keys = [hashlib.blake2b(x[i].tobytes(), digest_size=16).digest() for i in range(len(x))]
        todo = [i for i, k in enumerate(keys) if k not in self._cache]
        if todo:
            for i, y in zip(todo, self._planner.predict(x[todo])):
                self._cache[keys[i]] = y
        if not keys:
            return self._planner.predict(x)
        return np.stack([self._cache[k] for k in keys])


def pruning_quality(checkpoint: str | Path | None = None, n_piles: int = 20, caps=(32, 64),
                    objectives=("f1", "f3"), seed0: int = 800_000, threads: int = 2,
                    cache_dir: str | Path | None = None, only_cached: bool = False) -> dict:
    """Subset pre-selection vs exhaustive search with a trained checkpoint, graded in the twin.

    ``n_piles`` fresh 7-log piles (seeds ``seed0 + k``; odd k with 1-7 obstacles, drawn as in
    :class:`planner.evaluate.EvalConfig`), each planned exhaustively (all 127 subsets) and with
    the pre-selection (``SubsetPolicy(mode="fit", max_subsets=cap)``) per cap and objective — real
    :func:`planner.inference.plan` calls, each chosen grasp tried once through
    :func:`planner.evaluate.evaluate_pile` (same pile, same trial code as the evaluation).
    Per pile and objective: best-q ratio (capped / exhaustive), whether the exhaustive best subset
    survived the pre-selection, and each variant's trial outcome. With ``cache_dir``, each pile's
    rows are kept there (keyed by model hash, caps and objectives) and a rerun resumes;
    ``only_cached`` tabulates the piles already there and computes nothing."""
    import json
    import torch

    from planner.evaluate import EvalConfig, PlannerSpec, evaluate_pile
    from planner.inference import Objective, load_planner, plan
    from planner.subsets import SubsetPolicy, choose_subsets
    from synth.common.files import sha256_file

    torch.set_num_threads(threads)
    path = Path(checkpoint or DEFAULT_MODEL)
    pl = _SharedOutputs(load_planner(path, device="cpu"))
    meta = pl.meta
    sha = sha256_file(path)
    model_note = (f"`{path.relative_to(ROOT) if path.resolve().is_relative_to(ROOT) else path}` "
                  f"(sha256 {sha[:12]}, {meta.get('n_parameters', '?')} parameters, "
                  f"epoch {meta.get('epoch', '?')}, val loss {meta.get('val_loss', float('nan')):.3f})")
    cfg = EvalConfig(logs=(7,), obstacles=(False, True), per_cell=1, trial="fast")
    policies = {"exhaustive": SubsetPolicy(mode="exhaustive", max_subsets=127),
                **{f"cap{c}": SubsetPolicy(mode="fit", max_subsets=c) for c in caps}}
    plans: dict[str, object] = {}

    def plan_fn(name: str, objective: str):
        def fn(obs, pile):
            p = plan(obs, pl, Objective(objective), subsets=policies[name], pile=pile)
            plans[f"{objective}/{name}"] = (p, obs)
            return None if p.best is None else (p.best.grasp, tuple(p.best.targets))
        return fn

    specs = [PlannerSpec("unet", model=str(path), objective=obj, label=f"{obj}/{name}")
             for obj in objectives for name in policies]
    fns = {s.label: plan_fn(s.label.split("/")[1], s.objective) for s in specs}
    rows = []
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(n_piles):
        task = (7, bool(k % 2), k, seed0 + k)
        cached = None
        if cache_dir is not None:
            key = f"{sha[:16]}-{'-'.join(map(str, caps))}-{'-'.join(objectives)}-{task[3]}"
            cached = Path(cache_dir) / f"{key}.json"
            if cached.exists():
                rows += [{**r, "full_targets": tuple(r["full_targets"])} for r in json.loads(cached.read_text())]
                continue
        if only_cached:
            continue
        first = len(rows)
        plans.clear()
        pl.clear()
        # one pile, every variant and objective through the evaluation's own pile and trial code
        recs = {r["planner"]: r for r in evaluate_pile(task, specs, cfg, planners=fns)}
        for obj in objectives:
            full, obs = plans[f"{obj}/exhaustive"]
            if full.best is None:
                raise RuntimeError(f"the model planned no grasp on pile {task[3]}")
            masks = {i: obs.instance == i + 1 for i in full.info["visible_logs"]}
            row = {"seed": task[3], "obstacles": task[1], "objective": obj, "visible": len(masks),
                   "n_subsets": full.subsets_evaluated, "full_q": full.best.quality,
                   "full_targets": tuple(full.best.targets), "full_s": full.elapsed_s,
                   "full_outcome": recs[f"{obj}/exhaustive"]["outcome"]}
            for c in caps:
                p, _ = plans[f"{obj}/cap{c}"]
                kept, info = choose_subsets(masks, obs.grid.pixel_m, policies[f"cap{c}"])
                row.update({f"cap{c}_q_ratio": p.best.quality / full.best.quality, f"cap{c}_subsets": len(kept),
                            f"cap{c}_n_fit": info.get("n_fit"), f"cap{c}_has_best": row["full_targets"] in kept,
                            f"cap{c}_same": p.best.grasp == full.best.grasp and p.best.targets == full.best.targets,
                            f"cap{c}_s": p.elapsed_s, f"cap{c}_outcome": recs[f"{obj}/cap{c}"]["outcome"]})
            rows.append(row)
        if cached is not None:
            from synth.common.files import atomic_write_bytes

            atomic_write_bytes(cached, json.dumps(rows[first:]).encode())
    return {"model": model_note, "rows": rows, "caps": tuple(caps), "objectives": tuple(objectives),
            "seed0": seed0, "n_piles": n_piles, "seeds": sorted({r["seed"] for r in rows}), "wall_s": time.perf_counter() - t0,
            "cpu_s": time.process_time() - c0, "load": load_average()}


def pruning_markdown(pc: dict) -> list[str]:
    caps, rows = pc["caps"], pc["rows"]
    n, seeds = pc["n_piles"], pc["seeds"]
    if len(seeds) == n:
        which = f"{n} fresh 7-log piles (seeds {pc['seed0']}..{pc['seed0'] + n - 1}, every second one with 1-7 obstacles)"
    else:
        which = (f"{len(seeds)} of {n} planned fresh 7-log piles (seeds {', '.join(map(str, seeds))}; odd seeds with "
                 "1-7 obstacles; the rest not run)")
    parts = [f"Subset pre-selection vs exhaustive search, graded in the twin: {which}, model {pc['model']}. "
             "Each variant is a real `plan()` call (exhaustive: all subsets of the visible logs, 127 when all 7 "
             "show; cap N: `SubsetPolicy(mode=\"fit\", max_subsets=N)`), its best grasp tried once with "
             "`planner.evaluate.evaluate_pile` (trial preset `fast`). q ratio = best q with the pre-selection / "
             "best q exhaustive; 'best kept' = the exhaustive best subset is among those pre-selected; "
             f"'same grasp' = identical chosen grasp (so an identical trial). Network outputs are computed once "
             "per (pile, subset) and shared by all variants (a subset's output does not depend on its batch), so "
             "the variants differ only in which subsets they plan; latency is in the table above. "
             f"Run: {pc['wall_s'] / 60:.1f} min wall, {pc['cpu_s'] / 60:.1f} min CPU of this process (piles resumed "
             f"from a cache count neither), {pc['load']}.", "",
             "| objective | variant | subsets planned (mean) | best q ratio: mean / min | best kept | same grasp "
             "| twin success |",
             "|---|---|---|---|---|---|---|"]
    for obj in pc["objectives"]:
        mine = [r for r in rows if r["objective"] == obj]
        m = len(mine)
        ok = sum(r["full_outcome"] == "success" for r in mine)
        parts.append(f"| {obj} | exhaustive | {statistics.mean(r['n_subsets'] for r in mine):.0f} | 1 / 1 | - | - "
                     f"| {ok}/{m} ({100 * ok / m:.0f} %) |")
        for c in caps:
            ratios = [r[f"cap{c}_q_ratio"] for r in mine]
            okc = sum(r[f"cap{c}_outcome"] == "success" for r in mine)
            parts.append(
                f"| {obj} | cap {c} | {statistics.mean(r[f'cap{c}_subsets'] for r in mine):.0f} | "
                f"{statistics.mean(ratios):.3f} / {min(ratios):.3f} | "
                f"{sum(r[f'cap{c}_has_best'] for r in mine)}/{m} | {sum(r[f'cap{c}_same'] for r in mine)}/{m} | "
                f"{okc}/{m} ({100 * okc / m:.0f} %) |")
    flips = []
    for c in caps:
        won = sum(r[f"cap{c}_outcome"] == "success" and r["full_outcome"] != "success" for r in rows)
        lost = sum(r[f"cap{c}_outcome"] != "success" and r["full_outcome"] == "success" for r in rows)
        flips.append(f"cap {c}: {lost} success(es) lost, {won} gained")
    parts += ["", "Paired over the same piles and objectives (exhaustive → pre-selected): " + "; ".join(flips) + ".",
              "", "<details><summary>per pile</summary>", "",
              "| seed | obstacles | objective | visible logs | exhaustive: best q [targets] → outcome | "
              + " | ".join(f"cap {c}: kept (fit) / q ratio / best kept → outcome" for c in caps) + " |",
              "|---|---|---|---|---|" + "---|" * len(caps)]
    for r in rows:
        cells = [f"{r[f'cap{c}_subsets']} ({r[f'cap{c}_n_fit']}) / {r[f'cap{c}_q_ratio']:.3f} / "
                 f"{'yes' if r[f'cap{c}_has_best'] else 'no'} → {r[f'cap{c}_outcome']}" for c in caps]
        parts.append(f"| {r['seed']} | {'yes' if r['obstacles'] else 'no'} | {r['objective']} | {r['visible']} | "
                     f"{r['full_q']:.3f} {list(r['full_targets'])} → {r['full_outcome']} | " + " | ".join(cells) + " |")
    parts += ["", "</details>"]
    return parts


def fit_note(r: dict) -> str:
    return "" if r["n_fit"] is None else f" ({r['n_fit']} fit)"


def markdown(repeats: int = 3) -> str:
    parts = ["### Planner (U-Net) — training throughput, planning latency, cost of subset pre-selection", ""]
    t = training_throughput()
    parts += [f"Training step (forward + backward + Adam, batch 16, 128 px, 2 threads; {load_average()}):", "",
              "| model | parameters | mode | samples/s | CPU s per sample |", "|---|---|---|---|---|"]
    parts += [f"| {r['model']} | {r['params'] / 1e6:.2f} M | {r['mode']} | {r['samples_per_s']:.1f} | "
              f"{r['cpu_s_per_sample']:.3f} |" for r in t]
    lat = planning_latency(repeats=repeats)
    parts += ["", f"Planning one settled, rendered pile (2 obstacles), bf16 + BN folded, "
              f"all subsets batched, median of {repeats} ({load_average()}). Targets: 7 logs (127 subsets) < 1 s; 12 logs with "
              "pre-selection < 2 s.", "",
              "| model | mask injection | logs | subsets evaluated | selection | wall s | CPU s |",
              "|---|---|---|---|---|---|---|"]
    parts += [f"| {r['model']} | {r['injection']} | {r['logs']} | {r['subsets']} | {r['selection']}"
              f"{fit_note(r)} | "
              f"{r['wall_s']:.2f} | {r['cpu_s']:.2f} |" for r in lat]
    if int8_kernels_available():
        parts += [""] + precision_markdown(precision_cost() + precision_cost(threads=2))
    parts += [""] + views_markdown(views_latency())
    parts += [""] + ranker_markdown(ranker_latency())
    parts += [""] + pruning_markdown(pruning_quality(
        os.environ.get("LOGGRASP_PLANNER_CKPT"), n_piles=int(os.environ.get("LOGGRASP_BENCH_PRUNING_PILES", "20"))))
    return "\n".join(parts)
