"""The rectifier network: a small MLP on standardised logarithms of positive SI inputs.

    z = (ln x − μ_x) / σ_x,     ln η_refined = μ_y + σ_y · MLP(z)                 (absolute, the paper's)
                                ln η_refined = ln η_p + μ_y + σ_y · MLP(z)        (residual)

The paper's network has inputs (mean stirring speed [m/s], preliminary viscosity [Pa·s]), one hidden layer of 8
neurons and one output; viscosities span four decades, so inputs and output are taken in log space (an error of
10 % costs the same at 1 mPa·s as at 1 Pa·s). The residual form learns the correction ln(η_ref / η_p) instead of
ln η_ref, so an untrained or data-starved network stays near the preliminary estimate rather than near the
training set's mean (docs/rectifier.md). The standardisation and the range of the training inputs are buffers,
saved with the weights, so a trained rectifier is self-contained and can say when it would extrapolate.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

#: Inputs a rectifier can take: fields of a training pair and their units.
INPUT_UNITS = {"mean_stirring_speed": "m/s", "preliminary_viscosity": "Pa s", "density_estimate": "kg/m^3"}
ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "silu": nn.SiLU}


class Rectifier(nn.Module):
    """Refined viscosity [Pa·s] from positive SI ``inputs`` (names of ``INPUT_UNITS``), through an MLP with
    ``hidden`` layer widths and ``activation``; ``residual``: the MLP gives the correction to the preliminary
    viscosity's logarithm (which must then be an input)."""

    def __init__(self, inputs: Sequence[str] = ("mean_stirring_speed", "preliminary_viscosity"),
                 hidden: Sequence[int] = (8,), activation: str = "tanh", residual: bool = False):
        super().__init__()
        unknown = sorted(set(inputs) - set(INPUT_UNITS))
        if unknown or not inputs:
            raise ValueError(f"rectifier inputs {unknown or list(inputs)}: expected names from {list(INPUT_UNITS)}")
        if activation not in ACTIVATIONS:
            raise ValueError(f"rectifier activation {activation!r}: expected one of {list(ACTIVATIONS)}")
        if residual and "preliminary_viscosity" not in inputs:
            raise ValueError(f"a residual rectifier corrects the preliminary viscosity: inputs {list(inputs)} lack "
                             "'preliminary_viscosity'")
        self.inputs = tuple(inputs)
        self.residual = residual
        widths = [len(self.inputs), *hidden]
        layers: list[nn.Module] = []
        for a, b in zip(widths[:-1], widths[1:]):
            layers += [nn.Linear(a, b), ACTIVATIONS[activation]()]
        self.mlp = nn.Sequential(*layers, nn.Linear(widths[-1], 1))
        k = len(self.inputs)
        for name, value in (("x_mean", torch.zeros(k)), ("x_std", torch.ones(k)), ("y_mean", torch.zeros(())),
                            ("y_std", torch.ones(())), ("x_min", torch.zeros(k)), ("x_max", torch.zeros(k))):
            self.register_buffer(name, value)

    def fit_scaling(self, x: Tensor, y: Tensor) -> None:
        """Standardise on training inputs ``x`` (N, k) and references ``y`` (N,) [SI], and keep their range."""
        if (x <= 0).any() or (y <= 0).any():
            raise ValueError("rectifier: inputs and references must be positive SI values")
        lx, ly = x.log(), y.log() - self.log_base(x)
        self.x_mean.copy_(lx.mean(0))
        self.x_std.copy_(lx.std(0).clamp_min(1e-6))
        self.y_mean.copy_(ly.mean())
        self.y_std.copy_(ly.std().clamp_min(1e-6))
        self.x_min.copy_(x.min(0).values)
        self.x_max.copy_(x.max(0).values)

    def log_base(self, x: Tensor) -> Tensor | float:
        """What the network's output is added to: ln η_p [ln Pa·s] (residual), else 0."""
        return x[:, self.inputs.index("preliminary_viscosity")].log() if self.residual else 0.0

    def standardised_target(self, x: Tensor, y: Tensor) -> Tensor:
        """The value ``log_output`` is trained towards for inputs ``x`` (N, k) and references ``y`` (N,) [SI]."""
        return (y.log() - self.log_base(x) - self.y_mean) / self.y_std

    def standardise(self, x: Tensor) -> Tensor:
        return (x.log() - self.x_mean) / self.x_std

    def log_output(self, x: Tensor) -> Tensor:
        """The MLP's standardised output for inputs ``x`` (N, k) [SI]: what training compares."""
        return self.mlp(self.standardise(x)).squeeze(-1)

    def forward(self, x: Tensor) -> Tensor:
        """Refined viscosity [Pa·s], (N,), for inputs ``x`` (N, k) [SI] in the order of ``self.inputs``."""
        return torch.exp(self.log_base(x) + self.y_mean + self.y_std * self.log_output(x))

    def outside_range(self, x: Tensor) -> list[str]:
        """The inputs of the single sample ``x`` (k,) that lie outside the training range, as readable lines."""
        return [f"{name} = {float(v):.4g} {INPUT_UNITS[name]} is outside the training range "
                f"[{float(lo):.4g}, {float(hi):.4g}]"
                for name, v, lo, hi in zip(self.inputs, x, self.x_min, self.x_max) if not lo <= v <= hi]
