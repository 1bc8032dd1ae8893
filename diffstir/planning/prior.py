"""What a plan assumes before the stir: the candidate laws and the ranges of their parameters, as draws.

Every law is drawn by its apparent viscosity η_ref [Pa·s] at a reference shear rate γ̇_ref [1/s] (log-uniform over
``viscosity``) and its shape: a flow index p (uniform over ``flow_index``; ``power_law_index`` for the power law,
which may thicken), a time constant λ with λ γ̇_ref log-uniform over ``time_scale`` (Carreau, Cross), and the yield
stress's share y of the stress at γ̇_ref (uniform over ``yield_share``; Herschel-Bulkley, Bingham). The shape is
built at unit stress scale and then scaled (``FitModel.stress_scaled``) so that η(γ̇_ref) = η_ref:

    Carreau   η = η∞ + (η0 − η∞) (1 + (λ γ̇)²)^((p − 1) / 2),  η∞ = 1e-3 η0
    Cross     η = η∞ + (η0 − η∞) / (1 + (λ γ̇)^(1 − p)),       η∞ = 1e-3 η0  (its index is 1 − p)
    HB        τ = τ_y + k γ̇^p,  τ_y = y τ_ref                 Bingham   τ = τ_y + η_p γ̇

The draws are a scrambled Sobol sequence (``scipy.stats.qmc``), so a few of them cover the box evenly and the same
seed gives the same plan.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import qmc

from ..errors import ConfigError, check_choices, is_number, is_whole
from ..fitting import FitModel
from ..rheology import LAWS, within_bounds

#: The laws a plan tells apart by default: those the flow-curve analysis of the planned stir selects among
#: (``behaviour.JOINT_MODELS``), so the plan weighs the evidence its analysis will weigh.
PLAN_LAWS = ("newtonian", "power_law", "carreau", "cross", "herschel_bulkley")
#: Draws per law that set the prior's precision P (the spread of θ over the prior's box).
PRECISION_DRAWS = 64
#: Shape coordinates each law draws, after ln η_ref.
SHAPES = {"newtonian": (), "power_law": ("index",), "carreau": ("index", "time"), "cross": ("index", "time"),
          "herschel_bulkley": ("index", "yield"), "bingham": ("yield",)}


@dataclass(frozen=True)
class Prior:
    """The range of fluids a plan must work for.

    Attributes:
        viscosity: (low, high) apparent viscosity [Pa·s] at the reference shear rate.
        laws: candidate laws, of ``diffstir.rheology.LAWS``.
        flow_index: (low, high) flow index p [1] of the shear-thinning laws (Carreau, Cross, Herschel-Bulkley).
        power_law_index: (low, high) index n [1] of the power law (above 1: shear-thickening).
        time_scale: (low, high) λ γ̇_ref [1] of Carreau and Cross.
        yield_share: (low, high) share [1] of the stress at γ̇_ref carried by a yield stress.
        draws: fluids drawn per law.
        seed: the draws' random numbers.
    """

    viscosity: tuple[float, float] = (0.1, 10.0)
    laws: tuple[str, ...] = PLAN_LAWS
    flow_index: tuple[float, float] = (0.3, 0.9)
    power_law_index: tuple[float, float] = (0.4, 1.4)
    time_scale: tuple[float, float] = (0.1, 10.0)
    yield_share: tuple[float, float] = (0.05, 0.5)
    draws: int = 8
    seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "laws", tuple(self.laws))
        check_choices("prior.laws", list(self.laws), sorted(LAWS))
        if not self.laws:
            raise ConfigError("prior.laws is empty; give at least one of " + ", ".join(sorted(LAWS)))
        for name, unit, low, high in (("viscosity", "Pa s", 0.0, math.inf), ("flow_index", "1", 0.0, 1.0),
                                      ("power_law_index", "1", 0.0, 2.0), ("time_scale", "1", 0.0, math.inf),
                                      ("yield_share", "1", 0.0, 1.0)):
            value = tuple(getattr(self, name))
            object.__setattr__(self, name, value)
            if not (len(value) == 2 and all(is_number(v) for v in value) and low < value[0] <= value[1] < high):
                raise ConfigError(f"prior.{name} = {list(value)!r}; expected [low, high] in {unit} with "
                                  f"{low:g} < low <= high < {high:g}")
        for name, least in (("draws", 1), ("seed", 0)):
            if not is_whole(getattr(self, name), least):
                raise ConfigError(f"prior.{name} = {getattr(self, name)!r}; expected a whole number of at "
                                  f"least {least}")

    @property
    def reference_viscosity(self) -> float:
        """The geometric middle of ``viscosity`` [Pa·s]."""
        return math.sqrt(self.viscosity[0] * self.viscosity[1])

    def draw(self, name: str, reference_rate: float) -> list[FitModel]:
        """``draws`` fluids of law ``name`` for a stir whose reference shear rate is ``reference_rate`` [1/s]."""
        shape = SHAPES[name]
        sampler = qmc.Sobol(1 + len(shape), scramble=True, seed=self.seed + sorted(LAWS).index(name))
        units = sampler.random(self.draws) if self.draws > 1 else np.full((1, 1 + len(shape)), 0.5)
        return [self.fluid(name, reference_rate, *u) for u in units]

    def precision(self, name: str, reference_rate: float) -> np.ndarray:
        """The prior's precision P of law ``name``'s θ: 1 / the variance of each θ over ``PRECISION_DRAWS`` draws
        (floored at 1e-6), the diagonal."""
        wide = dataclasses.replace(self, draws=PRECISION_DRAWS)
        theta = np.array([m.theta() for m in wide.draw(name, reference_rate)])
        return 1.0 / np.maximum(theta.var(axis=0), 1e-6)

    def central(self, name: str, reference_rate: float) -> FitModel:
        """The law ``name`` at the middle of every range."""
        return self.fluid(name, reference_rate, *([0.5] * (1 + len(SHAPES[name]))))

    def fluid(self, name: str, reference_rate: float, viscosity: float, *shape: float) -> FitModel:
        """The law ``name`` at unit coordinates (each in [0, 1]) of ln η_ref and of its shape (module docstring)."""
        coords = dict(zip(SHAPES[name], shape))
        g = reference_rate
        p = _between(self.power_law_index if name == "power_law" else self.flow_index, coords.get("index", 0.5))
        lam = _log_between(self.time_scale, coords.get("time", 0.5)) / g
        y = _between(self.yield_share, coords.get("yield", 0.5))
        unit_shapes = {
            "newtonian": dict(eta=1.0),
            "power_law": dict(k=g ** (1.0 - p), n=p),
            "carreau": dict(eta0=1.0, eta_inf=1e-3, lam=lam, n=p),
            "cross": dict(eta0=1.0, eta_inf=1e-3, lam=lam, n=1.0 - p),
            "herschel_bulkley": dict(tau_y=y * g, k=(1.0 - y) * g ** (1.0 - p), n=p),
            "bingham": dict(tau_y=y * g, eta_p=1.0 - y),
        }
        model = FitModel.named(name, **within_bounds(name, unit_shapes[name]))
        eta_ref = _log_between(self.viscosity, viscosity)
        eta_unit = float(model.viscosity(np.array([g]))[0][0])
        return model.stress_scaled(eta_ref / eta_unit)


def _between(bounds: tuple[float, float], u: float) -> float:
    return bounds[0] + (bounds[1] - bounds[0]) * float(u)


def _log_between(bounds: tuple[float, float], u: float) -> float:
    return math.exp(math.log(bounds[0]) + (math.log(bounds[1]) - math.log(bounds[0])) * float(u))
