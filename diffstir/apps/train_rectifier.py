"""diffstir-train-rectifier: train the rectifier on a pairs file; write the Lightning checkpoint and a card with
the exact command, the data's SHA-256 and the metrics on held-out fluids.

    diffstir-train-rectifier                                   # into outputs/rectifier/<date>
    diffstir-train-rectifier data=outputs/pairs/pairs.jsonl out=outputs/rectifier-new
    diffstir-train-rectifier out=checkpoints/rectifier overwrite=true   # replace the shipped rectifier
"""

from __future__ import annotations

import hashlib
import json
import shlex
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import lightning as L
import torch
from hydra.utils import to_absolute_path
from lightning.pytorch.loggers import TensorBoardLogger
from omegaconf import DictConfig, OmegaConf

from diffstir.apps import Run, check_processes, command
from diffstir.errors import ConfigError, OutputError, check_choice
from diffstir.rectifier.settings import ACCELERATORS
from diffstir.rectifier.training import PairData, evaluate, train


OUTPUTS = ("rectifier.ckpt", "card.json")


@command("diffstir-train-rectifier", "rectifier")
def main(cfg: DictConfig) -> None:
    check_processes(cfg)
    model, training, split = (OmegaConf.to_object(cfg[key]) for key in ("model", "train", "split"))  # checked
    check_choice("device", cfg.device, ACCELERATORS)
    torch.set_num_threads(int(cfg.threads))
    data_path, out = Path(to_absolute_path(str(cfg.data))), Path(to_absolute_path(str(cfg.out)))
    if not data_path.is_file():
        raise ConfigError(f"data = {cfg.data}: no such file; give a pairs file (diffstir-pairs collect=true)")
    existing = [str(out / name) for name in OUTPUTS if (out / name).exists()]
    if existing and not cfg.overwrite:
        raise OutputError(f"{', '.join(existing)}: a trained rectifier is already there; give another out= or "
                          "overwrite=true")
    L.seed_everything(training.seed, workers=True)
    data = PairData(data_path, model.inputs, val_fraction=split.val_fraction, test_fraction=split.test_fraction,
                    batch_size=training.batch_size, seed=split.seed)
    estimators = {json.dumps(p["estimator_config"], sort_keys=True) for p in data.all_pairs}
    if len(estimators) != 1:
        raise ConfigError(f"{data_path}: pairs from {len(estimators)} estimator resolutions; train on one")
    manifest_path = data_path.parent / "manifest.json"
    metadata = {
        "data": str(cfg.data), "data_sha256": hashlib.sha256(data_path.read_bytes()).hexdigest(),
        "manifest": json.loads(manifest_path.read_text()) if manifest_path.exists() else None,
        "estimator": json.loads(estimators.pop()),
        "truth": data.all_pairs[0]["truth_config"],
    }
    if metadata["manifest"] is not None:
        metadata["manifest"] = {k: metadata["manifest"][k] for k in
                                ("design_digest", "pairs", "fluids", "complete", "sha256")}
    Run.writes(out)
    started = time.perf_counter()
    module, trainer = train(data, hidden=model.hidden, activation=model.activation, residual=model.residual,
                            learning_rate=training.learning_rate, epochs=training.epochs,
                            early_stopping_patience=training.patience if training.early_stopping else None,
                            accelerator=cfg.device, logger=TensorBoardLogger(str(out), name="tensorboard"),
                            metadata=metadata)
    seconds = time.perf_counter() - started
    trainer.save_checkpoint(out / "rectifier.ckpt")
    held_out = module.hparams.metadata["held_out"]  # the verdict on the test fluids, with their metrics
    card = {
        "command": " ".join(["diffstir-train-rectifier", *map(shlex.quote, sys.argv[1:])]),
        "trained": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "config": OmegaConf.to_container(cfg, resolve=True), **metadata,
        "fluids": {"train": len({p["fluid_id"] for p in data.train}), "val": len({p["fluid_id"] for p in data.val}),
                   "test": len({p["fluid_id"] for p in data.test})},
        "pairs": {"train": len(data.train), "val": len(data.val), "test": len(data.test),
                  "not_resolving": sum(not p["resolves"] for p in data.all_pairs)},
        "epochs": trainer.current_epoch, "seconds": seconds,
        "training_range": {name: [float(lo), float(hi)] for name, lo, hi in
                           zip(module.rectifier.inputs, module.rectifier.x_min, module.rectifier.x_max)},
        "metrics": {"val": evaluate(module.rectifier, data.val), "test": held_out["metrics"]},
        "held_out": held_out,
    }
    (out / "card.json").write_text(json.dumps(card, indent=1) + "\n")
    test = card["metrics"]["test"]
    print(f"test fluids: MAE {test['preliminary']['mae_mpas']:.1f} -> {test['refined']['mae_mpas']:.1f} mPa s, "
          f"RMSE {test['preliminary']['rmse_mpas']:.1f} -> {test['refined']['rmse_mpas']:.1f} mPa s; "
          f"{'applied' if held_out['applies'] else 'not applied'}: it {held_out['reason']}; "
          f"wrote {out / 'rectifier.ckpt'} and {out / 'card.json'}")


if __name__ == "__main__":
    main()
