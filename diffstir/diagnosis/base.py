"""The fit that a diagnosis starts from, and whether a fit needs one.

The base is the identification's selected law with its simulated reading p0 on the diagnosis's samples and the
reading's derivative with respect to the law's viscosity scale, d p / d ln s = Σ_j ∂p/∂θ_j over the law's stress
parameters (θ_j = ln value). Both are taken from the identification when it simulated the same samples at the same
resolution without sensor nuisances, and otherwise simulated (two runs: the law, and the law with every stress
parameter 5 % higher). The diagnosis models the sensor itself (``sensor_lag``, ``sensor_drift``), so its base is
the law's bare simulation even when the identification profiled out a sensor offset and lag.

The noise level σ of a reading is estimated from its second differences, x_{k+1} − 2 x_k + x_{k−1}, whose variance
is 6 σ² for white noise and which cancel the signal's slope (first differences keep it: a stirring force changes by
several noise levels per sample at 100 Hz): σ = 1.4826 MAD / sqrt(6), at least the quantisation noise q/sqrt(12).

A fit needs a diagnosis when its residual is both larger than the noise and structured: RSS/(N σ²) above
1 + 3 sqrt(2/N) (the χ²_N/N statistic of white noise of level σ, three standard deviations) and a lag-1
autocorrelation above 3/sqrt(N) (three standard errors of white noise's).
"""

from __future__ import annotations

import copy
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..fitting import Identification, StirProblem
from ..rheology import LAWS, RheologyLaw, make_law
from .candidates import scaled_law

#: Relative step of the viscosity scale for its finite-difference column.
SCALE_STEP = 0.05


@dataclass
class BaseFit:
    """The law the identification selected, on the diagnosis's samples.

    Attributes:
        law: the fitted law (a copy).
        density: the fluid's density [kg/m³] the identification used.
        predicted: its simulated reading p0 [N], (M,).
        scale_column: d p0 / d ln s [N], (M,).
        simulations: forward simulations spent to get them (0 when reused).
        source: where the law came from (report path or "identification").
    """

    law: RheologyLaw
    density: float
    predicted: np.ndarray
    scale_column: np.ndarray
    simulations: int
    source: str

    @property
    def params(self) -> dict[str, float]:
        return self.law.parameters_si()


def stress_columns(law: RheologyLaw) -> list[int]:
    """Indices of the law's stress parameters (unit in Pa), whose common factor scales η(γ̇)."""
    return [i for i, k in enumerate(law.params) if "Pa" in law.units[k]]


def simulated_reading(problem: StirProblem, law: RheologyLaw) -> np.ndarray:
    """``problem``'s simulated readings [N] for ``law``, without gradient, (M,) float64."""
    with torch.no_grad():
        return problem.simulate(law).double().numpy()


def simulate_base(problem: StirProblem, law: RheologyLaw, density: float, source: str) -> BaseFit:
    """The base reading and its viscosity-scale column by simulation (two runs)."""
    p0 = simulated_reading(problem, law)
    p1 = simulated_reading(problem, scaled_law(law, 1.0 + SCALE_STEP))
    return BaseFit(copy.deepcopy(law), density, p0, (p1 - p0) / math.log(1.0 + SCALE_STEP), 2, source)


def base_from_identification(identification: Identification, problem: StirProblem) -> BaseFit:
    """The selected law of ``identification``; its simulated readings are reused when it compared the same samples
    at the same resolution as ``problem``."""
    fit = identification.selected
    if not isinstance(fit.model.material, RheologyLaw):
        raise ValueError("diagnose: the selected model is the corotated baseline; diagnose a rheology law")
    law, density = fit.model.material, identification.density["value"]
    same = (identification.problem.config == problem.config
            and np.array_equal(identification.problem.times, problem.times))
    if not same or fit.sensor:
        return simulate_base(problem, law, density, "identification")
    column = fit.jacobian[:, stress_columns(law)].sum(axis=1)
    return BaseFit(copy.deepcopy(law), density, fit.predicted.copy(), column, 0, "identification")


def law_from_report(path: str | Path) -> tuple[RheologyLaw, float, str]:
    """The selected law and the density [kg/m³] of a ``diffstir-fit`` report (``report.json`` or its directory)."""
    path = Path(path)
    if path.is_dir():
        path = path / "report.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no identification report; run diffstir-fit first or set identification="
                                "null to fit the Newtonian law here")
    try:
        report = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    try:
        name = report["selected"]
        params = report["laws"][name]["params"]
        density = float(report["density"]["value"])
    except (KeyError, TypeError) as exc:
        raise ValueError(f"{path}: field {exc} is missing; expected a diffstir-fit report.json with selected, "
                         "laws.<selected>.params and density.value (kg/m^3)") from None
    if name not in LAWS:
        raise ValueError(f"{path}: selected = {name!r} is not a rheology law; expected one of {sorted(LAWS)}")
    return make_law(name, **params), density, str(path)


def noise_level(measured: np.ndarray, resolution: float | None) -> float:
    """The white-noise level σ [N] of readings ``measured`` [N] (see the module docstring)."""
    d2 = np.diff(measured, 2)
    mad = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / math.sqrt(6.0)
    return max(mad, (resolution or 0.0) / math.sqrt(12.0), 1e-12)


def residual_test(residual: np.ndarray, noise: float) -> dict:
    """Whether ``residual`` [N] is larger than white noise of level ``noise`` [N] and structured (see the module
    docstring): {"needed", "excess" (RSS/(N σ²)), "excess_limit", "autocorrelation", "autocorrelation_limit",
    "noise" [N]}."""
    n = residual.size
    excess = float(residual @ residual) / (n * noise**2)
    r = residual - residual.mean()
    rho = float(r[1:] @ r[:-1]) / float(r @ r) if float(r @ r) > 0 else 0.0
    excess_limit, rho_limit = 1.0 + 3.0 * math.sqrt(2.0 / n), 3.0 / math.sqrt(n)
    return {"needed": bool(excess > excess_limit and rho > rho_limit), "excess": excess,
            "excess_limit": excess_limit, "autocorrelation": rho, "autocorrelation_limit": rho_limit,
            "noise": noise, "unit": "N"}


def needs_diagnosis(identification: Identification) -> dict:
    """``residual_test`` of the selected fit's residual on its fitted samples, at the reading's noise level."""
    problem, fit = identification.problem, identification.selected
    residual = (problem.measured - fit.predicted)[problem.train]
    return residual_test(residual, noise_level(problem.measured, problem.recording.sensor.resolution))
