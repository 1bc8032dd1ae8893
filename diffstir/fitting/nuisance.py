"""The force sensor's own parameters as nuisances of a fit: a baseline offset b [N] and a first-order lag τ [s].

A real sensor reads y = L_τ p + b, where p [N] is the simulated reading (``StirProblem.simulate``) and L_τ the
first-order response τ dy/dt = p − y, y(t_0) = p(t_0). Both are left over after calibration (the dry-run
subtraction leaves an offset of about the resolution; a thin-film sensor behind an ADC filter responds in tens of
ms), and left unmodelled they put a structured residual into every law's fit, which no law can remove and which
hides the differences between laws (docs/identification.md, step 6).

They cost no simulation. For every simulated p(θ) they are profiled out on the fitted samples,

    τ̂, b̂ = argmin_{τ ∈ [0, τ_max], b} Σ_train (m − L_τ p − b)²,   b̂(τ) = mean_train(m − L_τ p),

τ by a bounded scalar search, and θ's Gauss-Newton Jacobian is the variable-projection one (Kaufman 1975),
J = P⊥ L_τ̂ ∂p/∂θ with P⊥ the projector orthogonal to the nuisance columns [∂y/∂b, ∂y/∂τ] = [1, ∂(L_τ p)/∂τ]:
the Laplace covariance on it is θ's marginal covariance with the nuisances free (the Schur complement). The
nuisances minimise least squares while θ minimises the fit's robust cost; the two agree where the residuals are
within the robust scale, which is what that scale is chosen for (``optimise.residual_scale``).

Neither is fitted by default (docs/accuracy.md measures both ways): where the simulator's own force error is
left (thin fluids, Re ≈ 25), a free lag or offset absorbs part of it into a wrong sensor setting, moves the
viscosity further and, with the residual whitened, narrows the intervals that should hold that error. The dry-run
subtraction bounds a real offset by about the resolution.

L_τ is the sensor's response of ``recording.first_order_response``, exact for p linear between samples
(first-order hold) on any increasing sample times. A recording whose sensor block states a ``time_constant``
already has that response in p (``StirProblem.simulate``); a fitted lag is then the sensor's response beyond it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy import optimize

from ..errors import is_number
from ..recording.sensor import first_order_response

NUISANCES = ("offset", "lag")

#: What a fit profiles out unless told otherwise: nothing (module docstring: what the lag costs, and why never the
#: offset by default).
DEFAULT_NUISANCES = ()
UNITS = {"offset": "N", "lag": "s"}

#: Longest lag τ [s] a fit considers: ten times a thin-film sensor's, a quarter of a slow stir's period.
MAX_LAG = 0.25

#: Lags [s] evaluated before the bounded search, which then refines around the best of them.
LAG_GRID = (0.0, 0.005, 0.01, 0.02, 0.04, 0.08, 0.16, MAX_LAG)

#: Step in τ [s] of the finite difference ∂(L_τ p)/∂τ (forward at τ = 0).
LAG_STEP = 1e-4


def lag_response(x: np.ndarray, times: np.ndarray, tau: float) -> np.ndarray:
    """L_τ x [unit of x], (M,) or (M, k), at the sample ``times`` [s]: ``recording.first_order_response`` in
    float64 numpy (module docstring). τ = 0 returns x."""
    x = np.asarray(x, dtype=np.float64)
    return first_order_response(torch.from_numpy(x), times, tau).numpy().copy()


@dataclass(frozen=True)
class SensorNuisance:
    """Which sensor parameters a fit profiles out (``fitted``, a subset of ``NUISANCES``) and the longest lag
    ``max_lag`` [s] it considers."""

    fitted: tuple[str, ...] = DEFAULT_NUISANCES
    max_lag: float = MAX_LAG

    def __post_init__(self) -> None:
        fitted = tuple(self.fitted)
        unknown = [n for n in fitted if n not in NUISANCES]
        if unknown:
            raise ValueError(f"fit.sensor_nuisance = {list(fitted)}: {unknown} unknown; expected a subset of "
                             f"{list(NUISANCES)}")
        if not (is_number(self.max_lag) and self.max_lag > 0):
            raise ValueError(f"max_lag = {self.max_lag!r}; expected a positive time in s")
        object.__setattr__(self, "fitted", tuple(n for n in NUISANCES if n in fitted))

    @property
    def size(self) -> int:
        return len(self.fitted)

    def apply(self, simulated: np.ndarray, times: np.ndarray, values: dict[str, float]) -> np.ndarray:
        """The reading y = L_τ p + b [N] of the simulated reading ``simulated`` p [N] at ``times`` [s]."""
        return lag_response(simulated, times, values.get("lag", 0.0)) + values.get("offset", 0.0)

    def profile(self, simulated: np.ndarray, measured: np.ndarray, times: np.ndarray,
                train: np.ndarray) -> dict[str, float]:
        """τ̂ [s] and b̂ [N] that best explain the fitted samples (``train``) of ``measured`` by ``simulated``."""
        if not self.fitted:
            return {}

        def rss(tau: float) -> float:
            residual = (measured - lag_response(simulated, times, tau))[train]
            if "offset" in self.fitted:
                residual = residual - residual.mean()
            return float(residual @ residual)

        tau = 0.0
        if "lag" in self.fitted:
            grid = [t for t in LAG_GRID if t < self.max_lag] + [self.max_lag]
            costs = [rss(t) for t in grid]
            best = int(np.argmin(costs))
            lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
            search = optimize.minimize_scalar(rss, bounds=(lo, hi), method="bounded", options={"xatol": 1e-5})
            tau = float(search.x) if search.fun < costs[best] else grid[best]
        values = {"lag": tau} if "lag" in self.fitted else {}
        if "offset" in self.fitted:
            values["offset"] = float(np.mean((measured - lag_response(simulated, times, tau))[train]))
        return values

    def columns(self, simulated: np.ndarray, times: np.ndarray, values: dict[str, float]) -> np.ndarray:
        """∂y/∂(nuisances) [N per SI unit], (M, size), in ``fitted`` order."""
        out = []
        for name in self.fitted:
            if name == "offset":
                out.append(np.ones(len(simulated)))
            else:
                tau = values["lag"]
                lo, hi = max(tau - LAG_STEP, 0.0), tau + LAG_STEP
                out.append((lag_response(simulated, times, hi) - lag_response(simulated, times, lo)) / (hi - lo))
        return np.stack(out, axis=1) if out else np.zeros((len(simulated), 0))

    def projected(self, jacobian: np.ndarray, simulated: np.ndarray, times: np.ndarray, values: dict[str, float],
                  train: np.ndarray) -> np.ndarray:
        """P⊥ J on the fitted samples: the part of ``jacobian`` d y / d θ (M, k) that the nuisances cannot
        mimic, (N_train, k) (module docstring)."""
        jac = jacobian[train]
        if not self.fitted:
            return jac
        nuisance = self.columns(simulated, times, values)[train]
        coefficients, *_ = np.linalg.lstsq(nuisance, jac, rcond=None)
        return jac - nuisance @ coefficients


#: No sensor parameters fitted: the reading is the simulated one.
NO_NUISANCE = SensorNuisance(fitted=())
