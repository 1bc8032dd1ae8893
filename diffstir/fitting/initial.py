"""Initial guesses: the Newtonian-equivalent viscosity of a recording and the stir's effective shear rate.

Metzner and Otto (1957) read a mixer's apparent viscosity at an effective shear rate proportional to its speed:
a power-law fluid (K, n) draws the power of a Newtonian fluid of viscosity K γ̇_eff^(n-1). Here the match is the
mean |reading| over the fitted samples, on the recording's own trajectory, instead of a constant from mixer tables.
Power-law probes of index n = 1 ± ε whose viscosity is η_N at the shear rate U/a read like Newtonian fluids of
viscosity η_N (γ̇_eff / (U/a))^(n-1); the pair measures d ln F / dn at n = 1, so γ̇_eff is the mean of ln γ̇ over the
flow of the Newtonian fluid η_N weighted by each region's share of the reading's sensitivity to viscosity: the
shear rate at which the stir measures a viscosity. Metzner and Otto's constant assumes γ̇_eff does not depend on n;
in a stirred cup it does, because part of the fluid barely shears (rigid swirl, corners), where a strongly thinning
power law's viscosity diverges, so a single probe far from n = 1 weighs those regions too much; the pair
n = 1 ± 0.15 measures the slope where every fluid the fit starts from lies.

The Newtonian-equivalent viscosity itself is read off a ladder of Newtonian simulations one decade apart
(``ViscosityLadder``): the tabulated estimate the Gauss-Newton fit starts from, and the preliminary estimate the
learned rectifier (``diffstir.rectifier``) refines. Each law then starts from parameters that give
η(γ̇_eff) = η_N with a typical shape, so a few Gauss-Newton steps suffice.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial
from typing import Callable

import numpy as np

from ..rheology import LAWS, has_yield_stress, within_bounds
from .models import FitModel
from .optimise import Readings
from .problem import StirProblem

PROBE_INDEX_STEP = 0.15  # ε: the power-law probes have indices 1 ± ε
VISCOSITY_STEP = 0.15    # h: Newtonian probes at η_N e^(±h/2) give the reading's sensitivity to ln η


def mean_stirring_speed(problem: StirProblem) -> float:
    """The rod's mean speed [m/s] over the fitted samples (the paper's "average stirring rate")."""
    return float(np.mean(np.linalg.norm(problem.velocity[problem.train], axis=1)))


def characteristic_shear_rate(problem: StirProblem) -> float:
    """U / a [1/s]: the rod's mean speed over its radius, the scale that γ̇_eff is measured against."""
    return max(mean_stirring_speed(problem), 1e-4) / problem.rig.rod.radius


#: How a list of models is simulated: their mean |reading| [N] over a problem's fitted samples, in order (in this
#: process by ``mean_readings``, or side by side by ``jobs.mean_readings_on``).
MeanReadings = Callable[[list[FitModel]], list[float]]


def mean_readings(problem: StirProblem, models: list[FitModel], on_evaluation=None) -> list[float]:
    """The mean |reading| [N] over ``problem``'s fitted samples of one simulation of each model, in order."""
    return [problem.mean_reading(Readings(problem, model, on_evaluation)(model.theta())) for model in models]


#: Probe viscosities [Pa·s] of the Newtonian ladder: one per decade over the liquids a cup is stirred with.
LADDER_VISCOSITIES = (1e-3, 1e-2, 1e-1, 1.0, 10.0)


@dataclass(frozen=True)
class ViscosityLadder:
    """The mean |reading| [N] over a recording's fitted samples, simulated for Newtonian fluids of ``viscosities``
    [Pa·s]; ``invert`` reads a Newtonian-equivalent viscosity off it.

    Between neighbouring probes the reading is taken as linear in η (a Stokes drag ∝ η on top of an inertial
    part), and the top segment is extended beyond the last probe. Probes whose reading does not exceed every lower
    probe's (inertia-dominated, thin fluids) carry no viscosity information and are dropped, so readings below the
    lowest informative probe map to its viscosity: ``resolves`` says whether a reading is above it.
    """

    viscosities: tuple[float, ...]
    mean_abs: tuple[float, ...]

    @classmethod
    def simulate(cls, problem: StirProblem, viscosities: tuple[float, ...] = LADDER_VISCOSITIES,
                 on_evaluation=None, evaluate: MeanReadings | None = None) -> "ViscosityLadder":
        """One forward simulation per probe viscosity on ``problem`` (``on_evaluation`` as for ``Readings``;
        ``evaluate``: how the simulations are run, ``mean_readings`` by default)."""
        models = [FitModel.named("newtonian", eta=eta) for eta in viscosities]
        means = (evaluate or partial(mean_readings, problem, on_evaluation=on_evaluation))(models)
        return cls(tuple(float(v) for v in viscosities), tuple(means))

    def _informative(self) -> tuple[np.ndarray, np.ndarray]:
        """(readings, viscosities) of the informative probes; the first is the floor: the highest viscosity of
        the flat start, with the highest reading seen on it."""
        force, eta = [self.mean_abs[0]], [self.viscosities[0]]
        for f, v in zip(self.mean_abs[1:], self.viscosities[1:]):
            if f > force[-1]:
                force.append(f)
                eta.append(v)
            elif len(force) == 1:  # still on the flat, inertia-dominated start: move the floor up
                eta[0] = v
        return np.array(force), np.array(eta)

    def resolves(self, mean_abs: float) -> bool:
        """Whether a mean |reading| [N] lies above the lowest informative probe's."""
        force, _ = self._informative()
        return bool(len(force) > 1 and mean_abs > force[0])

    def invert(self, mean_abs: float, upper: float = 1e3) -> float:
        """The Newtonian viscosity [Pa·s] (at most ``upper``) whose simulated mean |reading| is ``mean_abs`` [N]."""
        force, eta = self._informative()
        if len(force) == 1 or mean_abs <= force[0]:
            return float(eta[0])
        if mean_abs > force[-1]:
            slope = (eta[-1] - eta[-2]) / (force[-1] - force[-2])
            return float(min(eta[-1] + slope * (mean_abs - force[-1]), upper))
        return float(np.interp(mean_abs, force, eta))

    def reading(self, eta: float) -> tuple[float, float]:
        """The mean |reading| M [N] of the Newtonian fluid ``eta`` [Pa·s] and s = d ln M / d ln η [1] there: linear
        in η between the informative probes, the top segment extended above them, and flat (s = 0) below the
        lowest, where the reading carries no viscosity information."""
        force, visc = self._informative()
        if len(force) == 1 or eta <= visc[0]:
            return float(force[0]), 0.0
        k = min(int(np.searchsorted(visc, eta)), len(visc) - 1)
        slope = (force[k] - force[k - 1]) / (visc[k] - visc[k - 1])
        mean_abs = float(force[k - 1] + slope * (eta - visc[k - 1]))
        return mean_abs, float(slope * eta / mean_abs)

    def estimate(self, problem: StirProblem) -> float:
        """The Newtonian-equivalent viscosity [Pa·s] of ``problem``'s measured readings (fitted samples)."""
        upper = math.exp(FitModel.named("newtonian", eta=1.0).upper[0])
        return self.invert(problem.mean_reading(), upper)


#: The simulations ``effective_shear_rate`` spends: two Newtonian and two power-law probes.
SHEAR_RATE_PROBES = 4


def effective_shear_rate(problem: StirProblem, eta_n: float, on_evaluation=None,
                         evaluate: MeanReadings | None = None) -> float:
    """γ̇_eff [1/s] at Newtonian-equivalent viscosity ``eta_n`` [Pa·s] (module docstring), from four simulations
    and their mean |reading| F over the fitted samples: Newtonian fluids at η_N e^(±h/2) give the sensitivity
    s = d ln F / d ln η, and power laws of index 1 ± ε with K (U/a)^(n-1) = η_N give
    ln(γ̇_eff / (U/a)) = ln(F₊ / F₋) / (2 ε s)  (h = ``VISCOSITY_STEP``, ε = ``PROBE_INDEX_STEP``).
    Kept within [0.1, 10] U/a, where Metzner-Otto constants of stirrers lie; U/a itself where the reading does not
    respond to viscosity (s ≤ 0: thin, inertia-dominated fluids)."""
    rate0 = characteristic_shear_rate(problem)
    h, eps = VISCOSITY_STEP, PROBE_INDEX_STEP
    probes = [FitModel.named("newtonian", eta=eta_n * math.exp(h / 2)),
              FitModel.named("newtonian", eta=eta_n * math.exp(-h / 2)),
              FitModel.named("power_law", k=eta_n * rate0 ** eps, n=1.0 - eps),
              FitModel.named("power_law", k=eta_n * rate0 ** -eps, n=1.0 + eps)]
    thicker, thinner, thinning, thickening = (
        evaluate or partial(mean_readings, problem, on_evaluation=on_evaluation))(probes)
    sensitivity = math.log(thicker / thinner) / h
    if not sensitivity > 0.0:
        return rate0
    rate = rate0 * math.exp(math.log(thickening / thinning) / (2.0 * eps * sensitivity))
    return float(min(max(rate, 0.1 * rate0), 10.0 * rate0))


def metzner_otto_constant(problem: StirProblem, eta_n: float, evaluate: MeanReadings | None = None) -> float:
    """Metzner and Otto's k_s = γ̇_eff / (U/a) [1] of ``problem``'s stir at Newtonian-equivalent viscosity ``eta_n``
    [Pa·s] (``effective_shear_rate``, its four simulations run by ``evaluate``): a constant of the stirrer and cup
    in laminar flow."""
    return effective_shear_rate(problem, eta_n, evaluate=evaluate) / characteristic_shear_rate(problem)


#: Shares of the stress at γ̇_eff that a yield-stress law's start gives its yield stress: that of a paste and that
#: of a liquid near its Newtonian limit. Its loss has a basin near each: from the paste's start alone the bundled
#: (Carreau) example's fit ran to a nearly plastic index, from the liquid's alone ketchup's lost its yield stress
#: (docs/accuracy.md). ``initial_models`` offers both, and the identification fits both.
YIELD_SHARES = (0.2, 0.02)


def initial_model(name: str, eta_n: float, shear_rate: float, dt: float | None = None,
                  yield_share: float = YIELD_SHARES[0]) -> FitModel:
    """A model named ``name`` whose apparent viscosity at ``shear_rate`` [1/s] is ``eta_n`` [Pa·s], with a
    typical shape (shear-thinning index 0.6, time constant 1/γ̇_eff, a yield stress carrying ``yield_share`` of
    the stress); values are clipped into the law's bounds."""
    if name == "corotated":
        return FitModel.named("corotated", dt=dt, shear_modulus=eta_n / dt)
    g, y = shear_rate, yield_share
    guesses = {
        "newtonian": dict(eta=eta_n),
        "power_law": dict(k=eta_n * g ** 0.4, n=0.6),
        "carreau": dict(eta0=eta_n * 2 ** 0.2, eta_inf=eta_n * 1e-3, lam=1.0 / g, n=0.6),
        "cross": dict(eta0=2.0 * eta_n, eta_inf=eta_n * 1e-3, lam=1.0 / g, n=0.8),
        "herschel_bulkley": dict(tau_y=y * eta_n * g, k=(1.0 - y) * eta_n * g ** 0.2, n=0.8),
        "bingham": dict(tau_y=y * eta_n * g, eta_p=(1.0 - y) * eta_n),
    }
    if name not in guesses:
        raise ValueError(f"model {name!r} is unknown; choose from {sorted(LAWS) + ['corotated']}")
    return FitModel.named(name, **within_bounds(name, guesses[name]))


def newtonian_embedding(name: str, eta_n: float, shear_rate: float) -> FitModel:
    """The law ``name`` as the Newtonian fluid ``eta_n`` [Pa·s]: exactly (an index n = 1) or, where a bound keeps a
    parameter off zero, within 0.1 % at ``shear_rate`` [1/s] (a yield stress carrying 0.1 % of the stress, Cross's
    λγ̇ = 1e-3). A law that contains the Newtonian one, started here, cannot end above the Newtonian fit's loss."""
    g = shear_rate
    embeddings = {
        "power_law": dict(k=eta_n, n=1.0),
        "carreau": dict(eta0=eta_n, eta_inf=eta_n * 1e-3, lam=1.0 / g, n=1.0),
        "cross": dict(eta0=eta_n, eta_inf=eta_n * 1e-3, lam=1e-3 / g, n=1.0),
        "herschel_bulkley": dict(tau_y=1e-3 * eta_n * g, k=(1.0 - 1e-3) * eta_n, n=1.0),
        "bingham": dict(tau_y=1e-3 * eta_n * g, eta_p=(1.0 - 1e-3) * eta_n),
    }
    if name not in embeddings:
        raise ValueError(f"model {name!r} has no Newtonian embedding; choose from {sorted(embeddings)}")
    return FitModel.named(name, **within_bounds(name, embeddings[name]))


def initial_models(name: str, eta_n: float, shear_rate: float, dt: float | None = None) -> list[FitModel]:
    """The starts :func:`initial_model` offers for ``name``: one per ``YIELD_SHARES`` for a yield-stress law,
    one otherwise."""
    if has_yield_stress(name):
        return [initial_model(name, eta_n, shear_rate, dt, share) for share in YIELD_SHARES]
    return [initial_model(name, eta_n, shear_rate, dt)]

