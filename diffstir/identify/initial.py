"""Initial guesses: the Newtonian-equivalent viscosity of a recording and the stir's effective shear rate.

Metzner and Otto (1957) read a mixer's apparent viscosity at an effective shear rate proportional to its speed.
Here the proportionality is measured on the recording's own trajectory instead of taken from a table: a power-law
fluid (index ``PROBE_INDEX``) whose simulated readings equal those of a Newtonian fluid of viscosity η_N has
η_N = K γ̇_eff^(n-1), which defines the effective shear rate γ̇_eff [1/s]. Each law then starts from parameters
that give η(γ̇_eff) = η_N with a typical shape, so a few Gauss-Newton steps suffice.
"""

from __future__ import annotations

import math

import numpy as np

from ..rheology import LAWS
from .models import FitModel
from .optimise import FitResult, Readings
from .problem import StirProblem

PROBE_INDEX = 0.5  # flow index n of the power-law probe


def characteristic_shear_rate(problem: StirProblem) -> float:
    """U / a [1/s]: the rod's mean speed over its radius, the scale that γ̇_eff is measured against."""
    speed = np.linalg.norm(problem.velocity, axis=1)
    return max(float(np.mean(speed)), 1e-4) / problem.rig.rod.radius


def newtonian_start(problem: StirProblem, probes: tuple[float, float] = (0.01, 1.0)) -> float:
    """A first Newtonian viscosity [Pa·s] from two forward simulations: the mean |reading| is taken as linear in
    η between the probe viscosities (Stokes drag plus an inertial offset) and solved for the measured one."""
    model = FitModel.named("newtonian", eta=probes[0])
    readings = Readings(problem, model)
    low, high = (float(np.mean(np.abs(readings(np.log([eta]))[problem.train]))) for eta in probes)
    target = float(np.mean(np.abs(problem.measured[problem.train])))
    slope = (high - low) / (probes[1] - probes[0])
    eta = probes[0] + (target - low) / slope if slope > 0 else probes[0]
    lo, hi = (math.exp(b) for b in (model.lower[0], model.upper[0]))
    return float(min(max(eta, 10 * lo), hi / 10))


def effective_shear_rate(problem: StirProblem, newtonian: FitResult) -> float:
    """γ̇_eff [1/s] (see the module docstring) from one power-law simulation and the Newtonian fit's Jacobian:
    the probe's readings R_p are matched by the Newtonian readings R_N + J Δ, Δ = ln(η_N'/η_N) by least squares."""
    eta_n = newtonian.model.params_si()["eta"]
    rate0 = characteristic_shear_rate(problem)
    k = eta_n * rate0 ** (1.0 - PROBE_INDEX)
    probe = FitModel.named("power_law", k=k, n=PROBE_INDEX)
    probe_readings = Readings(problem, probe)(probe.theta())
    train = problem.train
    j = newtonian.jacobian[train, 0]
    if not float(j @ j) > 0:
        return rate0
    delta = float(j @ (probe_readings[train] - newtonian.predicted[train])) / float(j @ j)
    eta_equivalent = eta_n * math.exp(max(min(delta, 5.0), -5.0))
    return float((eta_equivalent / k) ** (1.0 / (PROBE_INDEX - 1.0)))


def initial_model(name: str, eta_n: float, shear_rate: float, dt: float | None = None) -> FitModel:
    """A model named ``name`` whose apparent viscosity at ``shear_rate`` [1/s] is ``eta_n`` [Pa·s], with a
    typical shape (shear-thinning index 0.6, time constant 1/γ̇_eff, a yield stress carrying a fifth of the
    stress); values are clipped into the law's bounds."""
    if name == "corotated":
        return FitModel.named("corotated", dt=dt, shear_modulus=eta_n / dt)
    g = shear_rate
    guesses = {
        "newtonian": dict(eta=eta_n),
        "power_law": dict(k=eta_n * g ** 0.4, n=0.6),
        "carreau": dict(eta0=eta_n * 2 ** 0.2, eta_inf=eta_n * 1e-3, lam=1.0 / g, n=0.6),
        "cross": dict(eta0=2.0 * eta_n, eta_inf=eta_n * 1e-3, lam=1.0 / g, n=0.8),
        "herschel_bulkley": dict(tau_y=0.2 * eta_n * g, k=0.8 * eta_n * g ** 0.2, n=0.8),
        "bingham": dict(tau_y=0.2 * eta_n * g, eta_p=0.8 * eta_n),
    }
    if name not in guesses:
        raise ValueError(f"model {name!r} is unknown; choose from {sorted(LAWS) + ['corotated']}")
    bounds = LAWS[name].specs
    values = {key: min(max(v, bounds[key].bounds[0]), bounds[key].bounds[1]) for key, v in guesses[name].items()}
    return FitModel.named(name, **values)
