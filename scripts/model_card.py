"""Write docs/model.md (the shipped model's training record) from a training run folder.

Usage: .venv/bin/python scripts/model_card.py RUN_DIR DATA_DIR COMMAND
(DATA_DIR: a rendered data set with manifest.json, or a committed grasp store with store.json)
"""

import json
import sys
from pathlib import Path

run, data, command = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
log = json.loads((run / "log.json").read_text())
store = (data / "store.json").is_file()  # a committed grasp store (data/paper-v3) or a rendered data set
manifest = json.loads((data / ("store.json" if store else "manifest.json")).read_text())
epochs = log["epochs"]
best = min(epochs, key=lambda e: e["val_loss"])
cfg = log["config"]
s = manifest["summary"]
skip = bool(cfg.get("data", {}).get("skip_no_candidates"))
if store:
    kept = s["subsets"] - (s["no_candidate_subsets"] if skip else 0)
    negatives = s["negatives"] - (s["no_candidate_subsets"] if skip else 0)
    data_line = (f"- Data: `{data}` — {s['piles']} piles of 4 logs ({s['piles_with_obstacles']} with obstacles), "
                 f"{s['subsets']} (pile, subset) samples, {s['grasps']} grasps; trained on the {kept} subsets "
                 f"{'with at least one admissible candidate (`--skip-no-candidates`) ' if skip else ''}× 3 renders "
                 f"= {3 * kept} samples, {100 * negatives / kept:.1f} % negatives; split 80/20 by pile "
                 f"(seed {cfg['seed']}). See docs/dataset.md.")
else:
    data_line = (f"- Data: `{data}` — {s['piles']} piles of 4 logs ({s['piles_with_obstacles']} with obstacles), "
                 f"{s['map_samples']} (pile, subset) samples × 3 renders = {s['samples']} samples, {s['grasps']} "
                 f"grasps, {100 * s['negative_fraction']:.0f} % negatives; split 80/20 by pile (seed {cfg['seed']}). "
                 "See docs/dataset.md.")
lines = [
    "# The shipped planner model (`planner/weights/default.safetensors`)",
    "",
    f"- Architecture: U-Net, inputs (I, D, M_T), outputs (C, S, W, U, B); base channels "
    f"{cfg['model']['base_channels']}, depth {cfg['model']['depth']}, {log['n_parameters']:,} parameters, "
    f"{cfg['model']['size_px']} px. (The paper's 4.1 M width is `--base-channels 23`; the smaller width was chosen "
    "for planning latency on a 2-core CPU.) Width and length measured on half the store and the learning curve's "
    "240 piles: the 4.0 M width gave f1 +5.0 pp (95 % CI -0.7..+10.7) and f3 +0.0 pp, 32 epochs instead of 16 "
    "f1 +1.2 and f3 -0.4 pp (docs/results/README.md, learning-curve): f3, the field's objective, moves with "
    "neither, so the shipped width and length stay.",
    f"- Mask injection: {cfg['model'].get('mask_injection', 'input')} (`input`: the target mask is an input "
    "channel, as in the paper). The encode-once `decoder` variant, same recipe on half the store, lost 10 pp (f1) "
    "and 17 pp (f3) on the learning curve's 240 piles for a 13 % faster plan (docs/results/README.md, "
    "learning-curve).",
    data_line,
    f"- Training: Adam lr {cfg['lr']}, batch {cfg['batch_size']}, {cfg['precision']} autocast on {log['device']}, "
    f"loss weights λ_B, λ_S, λ_C, λ_W = {cfg['loss']['lambda_b']}, {cfg['loss']['lambda_s']}, "
    f"{cfg['loss']['lambda_c']}, {cfg['loss']['lambda_w']}, BCE weight of positive U pixels "
    f"{cfg['loss'].get('u_pos_weight', 1.0)}; learning rate schedule {cfg.get('lr_schedule', 'constant')}; "
    "augmentations: flips, rotations, colour/light, noise.",
    f"- Epochs run: {len(epochs)} (of {cfg['epochs']} planned); best validation loss "
    f"{best['val_loss']:.4f} at epoch {best['epoch']} (train loss then {best['train_loss']:.4f}). "
    f"Throughput {max(e['samples_per_s'] for e in epochs):.0f} samples/s at best on this 2-core CPU "
    "(lower while other jobs shared the cores).",
    f"- Command: `{command}`",
    "- Evaluations in the twin: docs/results/README.md (the learning curve, and the paper-protocol "
    "evaluations eval-v*, the newest first).",
    "",
    "![training curve](img/training_curve.png)",
    "",
    "| epoch | train loss | val loss | samples/s |",
    "|---|---|---|---|",
]
lines += [f"| {e['epoch']} | {e['train_loss']:.4f} | {e['val_loss']:.4f} | {e['samples_per_s']:.1f} |" for e in epochs]
Path("docs/model.md").write_text("\n".join(lines) + "\n")
print("wrote docs/model.md")
