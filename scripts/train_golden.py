"""Golden for planner.train.train: a tiny deterministic run (fp32, one thread, deterministic
algorithms) from scratch and one extended by a resume, printed as JSON (weight hashes and the
epoch log without times). Record it before a refactor of the training loop and compare after:

    PYTHONPATH=.:tests/planner .venv/bin/python scripts/train_golden.py /tmp/gt > before.json   # ... refactor ...
    PYTHONPATH=.:tests/planner .venv/bin/python scripts/train_golden.py /tmp/gt > after.json && cmp before.json after.json
"""
import hashlib
import json
import shutil
import sys
from pathlib import Path
import torch
torch.set_num_threads(1)
torch.use_deterministic_algorithms(True)
from planner_helpers import make_dataset  # the tests' tiny data set (tests/planner on PYTHONPATH)
from planner.data import DataConfig
from planner.model import UNetConfig
from planner.train import TrainConfig, train
from safetensors.torch import load_file

out = Path(sys.argv[1]); out.mkdir(parents=True, exist_ok=True)
data = out / "data"
if not data.exists():
    make_dataset(data, n_piles=9)
cfg = TrainConfig(model=UNetConfig.tiny(), epochs=3, batch_size=4, lr=3e-3, precision="fp32", num_threads=1,
                  data=DataConfig(val_fraction=0.34, split_seed=1, shuffle_buffer=8), checkpoint_every_steps=2)
res = {}
for name, epochs, sub in (("full", 3, "run"), ("resumed", 2, "run2")):
    run = out / sub
    shutil.rmtree(run, ignore_errors=True)
    train(data, run, cfg if name == "full" else TrainConfig(**{**cfg.__dict__, "epochs": 2}))
    if name == "resumed":
        train(data, run, cfg)  # extend to 3 epochs: resume
    w = load_file(str(run / "model.safetensors"))
    res[name] = {"weights": hashlib.sha256(b"".join(w[k].numpy().tobytes() for k in sorted(w))).hexdigest(),
                 "log": [{k: v for k, v in e.items() if k not in ("wall_s", "samples_per_s", "compute_samples_per_s")}
                         for e in json.loads((run / "log.json").read_text())["epochs"]]}
print(json.dumps(res, indent=1, sort_keys=True, default=str))
