"""Planner speed: training throughput and planning latency on this machine (``make bench``
section "planner"; run alone: ``.venv/bin/python bench/bench_planner.py``).

Measures, with 2 torch threads:
* training samples/s (forward + backward + Adam, batch 16, 128 px) for the default (~4.0 M) and
  the small (~1.9 M) U-Net, plain fp32 vs channels-last + bf16 autocast;
* planning latency (``planner.inference.plan``, all steps included) on settled, rendered piles of
  4, 7 and 12 logs with the default-width network, input vs decoder mask injection;
* the cost of subset pre-selection in best q against exhaustive search on 7-log piles (with a
  trained checkpoint when ``LOGGRASP_PLANNER_CKPT`` names one, else the untrained network).
Wall times are sensitive to other load on the 2 cores: each table states the load average.
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _load() -> str:
    try:
        return "load average " + " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "load average ?"


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
    from synth.generate import GenerationConfig, generate_pile
    from synth.render import OrthoRenderConfig, render_ortho
    from synth.world import World

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


def pruning_cost(caps=(32, 64), n_piles: int = 3, checkpoint: str | None = None) -> dict:
    """Best q with pre-selection (max_subsets = cap) relative to exhaustive search, 7-log piles.

    Each subset's network output does not depend on the other subsets in the batch, so the
    exhaustive plan's per-subset best grasps are reused: the capped plan's best q is the best
    over the subsets the pre-selection keeps."""
    import torch

    from planner.inference import Objective, Planner, load_planner, plan
    from planner.model import UNetConfig, build_unet
    from planner.subsets import SubsetPolicy, choose_subsets

    torch.set_num_threads(2)
    if checkpoint:
        pl = load_planner(checkpoint, device="cpu")
        model_note = (f"checkpoint `{checkpoint}` ({pl.meta.get('n_parameters', '?')} parameters, "
                      f"epoch {pl.meta.get('epoch', '?')}, val loss {pl.meta.get('val_loss', float('nan')):.3f})")
    else:
        torch.manual_seed(0)
        cfg = UNetConfig(base_channels=16)
        pl = Planner(build_unet(cfg), cfg)
        model_note = "UNTRAINED network (quality numbers only exercise the mechanics)"
    rows = []
    for obs, pile in _pile_observations(7, n_piles, pl.config.size_px, seed0=500):
        grid = obs.grid
        masks = {i: obs.instance == i + 1 for i in range(pile.n_logs) if (obs.instance == i + 1).any()}
        for obj in ("f1", "f2"):
            full = plan(obs, pl, Objective(obj), subsets=SubsetPolicy(mode="exhaustive", max_subsets=127))
            by_subset = {g.targets: g.quality for g in full.grasps}
            row = {"objective": obj, "full_q": full.best.quality, "full_targets": full.best.targets,
                   "full_s": full.elapsed_s, "n_subsets": full.subsets_evaluated}
            for cap in caps:
                kept, info = choose_subsets(masks, grid.pixel_m, SubsetPolicy(mode="fit", max_subsets=cap))
                best = max(by_subset.get(t, 0.0) for t in kept)
                row[f"cap{cap}_q_ratio"] = best / full.best.quality
                row[f"cap{cap}_subsets"] = len(kept)
                row[f"cap{cap}_n_fit"] = info["n_fit"]
                row[f"cap{cap}_has_best"] = full.best.targets in kept
            rows.append(row)
    return {"model": model_note, "rows": rows, "caps": caps}


def fit_note(r: dict) -> str:
    return "" if r["n_fit"] is None else f" ({r['n_fit']} fit)"


def markdown(repeats: int = 3) -> str:
    parts = ["### Planner (U-Net) — training throughput and planning latency", ""]
    t = training_throughput()
    parts += [f"Training step (forward + backward + Adam, batch 16, 128 px, 2 threads; {_load()}):", "",
              "| model | parameters | mode | samples/s | CPU s per sample |", "|---|---|---|---|---|"]
    parts += [f"| {r['model']} | {r['params'] / 1e6:.2f} M | {r['mode']} | {r['samples_per_s']:.1f} | "
              f"{r['cpu_s_per_sample']:.3f} |" for r in t]
    lat = planning_latency(repeats=repeats)
    parts += ["", f"Planning one settled, rendered pile (2 obstacles), bf16 + BN folded, "
              f"all subsets batched, median of {repeats} ({_load()}). Targets: 7 logs (127 subsets) < 1 s; 12 logs with "
              "pre-selection < 2 s.", "",
              "| model | mask injection | logs | subsets evaluated | selection | wall s | CPU s |",
              "|---|---|---|---|---|---|---|"]
    parts += [f"| {r['model']} | {r['injection']} | {r['logs']} | {r['subsets']} | {r['selection']}"
              f"{fit_note(r)} | "
              f"{r['wall_s']:.2f} | {r['cpu_s']:.2f} |" for r in lat]
    pc = pruning_cost(checkpoint=os.environ.get("LOGGRASP_PLANNER_CKPT"))
    caps = pc["caps"]
    parts += ["", f"Subset pre-selection vs exhaustive search on 7-log piles — {pc['model']}:", "",
              "| pile | objective | exhaustive: subsets, best q [targets] | " + " | ".join(
                  f"cap {c}: kept (fit) / best q ratio / best subset kept" for c in caps) + " |",
              "|---|---|---|" + "---|" * len(caps)]
    for k, r in enumerate(pc["rows"]):
        cells = [f"{r[f'cap{c}_subsets']} ({r[f'cap{c}_n_fit']}) / {r[f'cap{c}_q_ratio']:.3f} / "
                 f"{'yes' if r[f'cap{c}_has_best'] else 'no'}" for c in caps]
        parts.append(f"| {k // 2} | {r['objective']} | {r['n_subsets']}, {r['full_q']:.3f} {list(r['full_targets'])} | "
                     + " | ".join(cells) + " |")
    return "\n".join(parts)


if __name__ == "__main__":
    print(markdown(int(os.environ.get("LOGGRASP_BENCH_REPEATS", "3"))))
