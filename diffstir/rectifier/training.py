"""Training the rectifier with Lightning: the pairs as a data module split by fluid, the network as a module.

Pairs are split by fluid (``fluid_id``), never by recording: every sensor reading of one truth simulation lands in
the same split, so validation and test fluids are fluids the network has never seen. Pairs whose recording does
not resolve viscosity (the reading is within the inertial floor of the ladder, ``resolves`` false) carry no
information about it and are left out of training; ``diffstir-fit`` reports them as not identifiable instead.
The loss is the mean squared error of standardised ln η.
"""

from __future__ import annotations

import gzip
import json
from collections.abc import Sequence
from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, TensorDataset

from .model import Rectifier


def load_pairs(path: str | Path) -> list[dict]:
    """The pairs of a ``pairs.jsonl`` file (``diffstir-pairs collect=true``), or of its gzip ``pairs.jsonl.gz``."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no pairs file; make one with diffstir-pairs (docs/rectifier.md)")
    raw = path.read_bytes()
    text = (gzip.decompress(raw) if path.suffix == ".gz" else raw).decode("utf-8")
    pairs = []
    for number, line in enumerate(text.splitlines(), 1):
        if line.strip():
            try:
                pairs.append(json.loads(line))
            except json.JSONDecodeError as exc:
                raise ValueError(f"{path}:{number}: not a JSON line ({exc})") from None
    if not pairs:
        raise ValueError(f"{path}: no pairs")
    return pairs


def split_fluids(pairs: Sequence[dict], fractions: Sequence[float], seed: int) -> list[list[dict]]:
    """Pairs split into len(fractions) + 1 parts by fluid: the last part takes what the fractions leave."""
    fluids = sorted({p["fluid_id"] for p in pairs})
    order = np.random.default_rng(seed).permutation(len(fluids))
    bounds = np.cumsum([0] + [round(f * len(fluids)) for f in fractions])
    parts = [{fluids[i] for i in order[a:b]} for a, b in zip(bounds[:-1], bounds[1:])]
    parts.append({fluids[i] for i in order[bounds[-1]:]})
    return [[p for p in pairs if p["fluid_id"] in part] for part in parts]


def tensors(pairs: Sequence[dict], inputs: Sequence[str]) -> tuple[torch.Tensor, torch.Tensor]:
    """(inputs (N, k), reference viscosity (N,)) of ``pairs`` [SI], float64."""
    x = torch.tensor([[p[name] for name in inputs] for p in pairs], dtype=torch.float64)
    y = torch.tensor([p["reference_viscosity"] for p in pairs], dtype=torch.float64)
    return x, y


class PairData(L.LightningDataModule):
    """Pairs of ``path`` split by fluid into train / validation / test (``val_fraction``, ``test_fraction`` of the
    fluids, drawn with ``seed``); only pairs that resolve viscosity."""

    def __init__(self, path: str | Path, inputs: Sequence[str], *, val_fraction: float = 0.1,
                 test_fraction: float = 0.2, batch_size: int = 64, seed: int = 0):
        super().__init__()
        self.path, self.inputs, self.batch_size = Path(path), tuple(inputs), batch_size
        self.all_pairs = load_pairs(self.path)
        usable = [p for p in self.all_pairs if p["resolves"]]
        self.test, self.val, self.train = split_fluids(usable, [test_fraction, val_fraction], seed)
        if not self.train or not self.val:
            raise ValueError(f"{self.path}: too few fluids ({len({p['fluid_id'] for p in usable})}) to split")

    def _loader(self, pairs: Sequence[dict], shuffle: bool) -> DataLoader:
        x, y = tensors(pairs, self.inputs)
        return DataLoader(TensorDataset(x.float(), y.float()), batch_size=self.batch_size, shuffle=shuffle)

    def train_dataloader(self) -> DataLoader:
        return self._loader(self.train, True)

    def val_dataloader(self) -> DataLoader:
        return self._loader(self.val, False)

    def test_dataloader(self) -> DataLoader:
        return self._loader(self.test, False)


class RectifierModule(L.LightningModule):
    """The ``Rectifier`` trained by Adam (``learning_rate``) on the MSE of standardised ln η."""

    def __init__(self, inputs: Sequence[str] = ("mean_stirring_speed", "preliminary_viscosity"),
                 hidden: Sequence[int] = (8,), activation: str = "tanh", learning_rate: float = 0.01,
                 metadata: dict | None = None, residual: bool = False):
        super().__init__()
        self.save_hyperparameters()
        self.rectifier = Rectifier(inputs, hidden, activation, residual)

    def _loss(self, batch) -> torch.Tensor:
        x, y = batch
        return torch.nn.functional.mse_loss(self.rectifier.log_output(x), self.rectifier.standardised_target(x, y))

    def training_step(self, batch, batch_idx):
        loss = self._loss(batch)
        self.log("train_loss", loss, on_epoch=True, on_step=False, batch_size=len(batch[0]))
        return loss

    def validation_step(self, batch, batch_idx):
        self.log("val_loss", self._loss(batch), on_epoch=True, prog_bar=True, batch_size=len(batch[0]))

    def test_step(self, batch, batch_idx):
        self.log("test_loss", self._loss(batch), on_epoch=True, batch_size=len(batch[0]))

    def configure_optimizers(self):
        return torch.optim.Adam(self.parameters(), lr=self.hparams.learning_rate)


def viscosity_errors(predicted: np.ndarray, reference: np.ndarray) -> dict:
    """MAE and RMSE [mPa·s] (the paper's Table V metrics) and the median and 90th-percentile relative error [1]."""
    error = np.asarray(predicted, float) - np.asarray(reference, float)
    relative = np.abs(error) / np.asarray(reference, float)
    return {"mae_mpas": float(np.mean(np.abs(error)) * 1e3), "rmse_mpas": float(np.sqrt(np.mean(error**2)) * 1e3),
            "median_relative": float(np.median(relative)), "p90_relative": float(np.quantile(relative, 0.9)),
            "n": int(error.size)}


def evaluate(rectifier: Rectifier, pairs: Sequence[dict]) -> dict:
    """Errors of the preliminary and of the refined viscosity against the reference on ``pairs``."""
    x, y = tensors(pairs, rectifier.inputs)
    with torch.no_grad():
        refined = rectifier(x.float()).double().numpy()
    prelim = np.array([p["preliminary_viscosity"] for p in pairs])
    return {"preliminary": viscosity_errors(prelim, y.numpy()), "refined": viscosity_errors(refined, y.numpy())}


def held_out_verdict(rectifier: Rectifier, pairs: Sequence[dict]) -> dict:
    """Whether the rectifier is to be applied, from its errors on held-out fluids ``pairs``: only if it lowers both
    the mean absolute error (the paper's metric, dominated by viscous fluids) and the median relative error (the
    typical fluid's) of the preliminary estimate. {applies, reason, metrics, by_law (the same per truth law)}."""
    metrics = evaluate(rectifier, pairs)
    before, after = metrics["preliminary"], metrics["refined"]
    lowers = {"MAE": after["mae_mpas"] < before["mae_mpas"],
              "median relative error": after["median_relative"] < before["median_relative"]}
    changes = (f"MAE {before['mae_mpas']:.1f} -> {after['mae_mpas']:.1f} mPa s, median relative error "
               f"{before['median_relative']:.3f} -> {after['median_relative']:.3f} on {after['n']} held-out readings")
    raised = [name for name, lower in lowers.items() if not lower]
    reason = (f"lowers the held-out error ({changes})" if not raised else
              f"does not lower the held-out {' and '.join(raised)} ({changes})")
    laws = sorted({p["law"] for p in pairs if "law" in p})
    return {"applies": not raised, "reason": reason, "metrics": metrics,
            "by_law": {law: evaluate(rectifier, [p for p in pairs if p.get("law") == law]) for law in laws}}


def train(data: PairData, *, hidden: Sequence[int] = (8,), activation: str = "tanh", learning_rate: float = 0.01,
          epochs: int = 50, early_stopping_patience: int | None = None, accelerator: str = "cpu",
          logger=False, metadata: dict | None = None, residual: bool = False) -> tuple[RectifierModule, L.Trainer]:
    """Train a rectifier on ``data``'s training fluids (standardised on them), validating on its validation
    fluids; early stopping on ``val_loss`` when ``early_stopping_patience`` is given. The module's metadata (saved
    with its checkpoint) gains ``held_out``, the verdict on its test fluids (``held_out_verdict``) that decides
    whether ``apply.refine`` uses it."""
    from lightning.pytorch.callbacks import EarlyStopping

    module = RectifierModule(data.inputs, hidden, activation, learning_rate, metadata=metadata, residual=residual)
    module.rectifier.fit_scaling(*tensors(data.train, module.rectifier.inputs))
    callbacks = [EarlyStopping("val_loss", patience=early_stopping_patience)] if early_stopping_patience else []
    trainer = L.Trainer(max_epochs=epochs, accelerator=accelerator, devices=1, logger=logger, callbacks=callbacks,
                        enable_checkpointing=False, deterministic=True, enable_progress_bar=False,
                        enable_model_summary=False, log_every_n_steps=1)
    trainer.fit(module, datamodule=data)
    module.rectifier.cpu().eval()
    module.hparams.metadata = {**(metadata or {}), "held_out": held_out_verdict(module.rectifier, data.test)}
    return module, trainer
