"""Uncertainty of a fit: the Laplace (Gauss-Newton) covariance of θ, corrected for correlated residuals, plus the
simulator's own error.

cov(θ) = s² (JᵀJ)⁻¹ · N / N_eff + Σ_w (σ_m² g_w g_wᵀ + σ_i² h_w h_wᵀ),
g_w = J⁺ p_w,   h_w = J⁺ (p_w − v_w),

with J = d readings / d θ on the fitted samples, s² = RSS / (N - k), N_eff = N (1 - ρ) / (1 + ρ) the effective
number of independent samples for residuals with lag-1 autocorrelation ρ (an AR(1) model: sensor lag, filtering and
model error make neighbouring residuals alike, and treating them as independent would make the intervals far too
narrow). The sum is the fitting simulator's discretisation error, which does not shrink with more data and which no
residual shows, because θ absorbs it. It has two parts:

- a common relative error ε of the whole force, ε ~ N(0, σ_m²): a reading p(1 + ε) moves the least-squares θ by
  ε J⁺ p (a grid that reads 3 % low returns a viscosity that much high); σ_m comes from the simulator's validation
  against closed forms and the viscous stir (``MODEL_FORCE_ERROR``);
- a relative error ε_i of the part of the force that does not scale with the fluid's stress, ε_i ~ N(0, σ_i²): the
  reading is p = v + (p − v), with v = Σ_j dp/dθ_j over the parameters that carry the law's stress scale (a
  viscosity, a consistency, a yield stress: ``FitModel.stress_direction``), the reading's viscous part; p − v is
  what the fluid's momentum carries (inertia), which the 2-D slice gets less right than its viscous part
  (``INERTIAL_FORCE_ERROR``). An error ε_i (p − v) moves θ by ε_i J⁺ (p − v). Where inertia carries most of the
  force (a viscous share v / p of e), this moves ln η by about ε_i (1 − e) / e, and the interval widens with it.

Readings of several speed windows (``windows``) each get their own ε_w and ε_i,w, independent between windows:
p_w and v_w are p and v on window w's samples and zero elsewhere. One window (the default) is the common error; a
law fitted to several speeds then also learns how the error's differences between speeds move its index.

A parameter is identifiable when its 95 % interval is narrower than a factor ``MAX_FACTOR`` each way (log-scaled)
or ``MAX_LINEAR_HALF_WIDTH`` (dimensionless indices) and it did not end on a bound: closer to it than both
``AT_BOUND`` of its θ range and its own 95 % half-width (a dead band of 9.9 ± 1.2 mN on a range of 0 to 10 N lies
within 1e-3 of the range from zero, but the bound does not cut its interval).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, is_number
from ..slice_correction import SliceCorrection
from .models import FitModel
from .parameters import ParameterSet

Z95 = 1.959963984540054
MAX_FACTOR = 3.0            # a log-scaled parameter known to within a factor 3 either way
MAX_LINEAR_HALF_WIDTH = 0.5  # a dimensionless index known to within ±0.5
AT_BOUND = 1e-3              # of the θ range: closer than this to a bound counts as on it

#: σ_m, the relative 1-σ error of the fine stage's force (``conf/sim/slice2d.yaml``: the 2-D slice, dx = 2.5 mm,
#: incompressible, a 2 ms step): the paper's stir against the finite-element reference reads +1.9, −3.0 and −3.9 %
#: at 0.2, 1 and 3 Pa·s (rms 3.1 %) and the closed forms are within 4.1 % from 0.5 to 3 Pa·s (docs/validation-stir.md,
#: docs/validation-closed-forms.md).
MODEL_FORCE_ERROR = 0.03
#: σ_m of the coarse grid (``conf/sim/coarse2d.yaml``, dx = 5 mm, compressible): the rms of its closed forms'
#: deficits, the Newtonian and power-law Couette torques 17.5 and 19.8 % low and the translating rod at 0.5 and
#: 1 Pa·s 14.5 and 16.4 % low, rms 17.2 % (docs/validation-closed-forms.md, Convergence under refinement).
COARSE_FORCE_ERROR = 0.17
#: σ_i, the relative 1-σ error of the fine stage's force in its part that does not scale with the fluid's stress
#: (module docstring): the paper's stir against the finite-element reference at 0.05, 0.1 and 0.2 Pa·s (Re 50, 25,
#: 12.5), the rms deviation of the force vector over the rms of the reference's inertial part, I = F − dF/d ln η,
#: rms over the three (``python scripts/validate_simulator.py --checks inertial_error``,
#: docs/validation-projection.md, How far off the inertial force is).
INERTIAL_FORCE_ERROR = 0.3


def force_error(model_error: float, correction: SliceCorrection | None) -> float:
    """The simulated force's relative 1-σ error [1]: the simulator's ``model_error`` and the slice correction's
    own uncertainty (``StirProblem.slice_correction``; none in 3-D), independent, in quadrature."""
    return model_error if correction is None else math.hypot(model_error, correction.sigma)


def checked_model_error(value: float, field: str) -> float:
    """``value`` if it is a relative force error σ_m in [0, 1); otherwise a ConfigError that names ``field``."""
    if not (is_number(value) and 0.0 <= value < 1.0):
        raise ConfigError(f"{field} = {value!r}; expected a relative force error in [0, 1)")
    return value


@dataclass
class Uncertainty:
    """Covariance of θ and what it implies.

    Attributes:
        covariance: cov(θ), (k, k); infinite rows/columns for directions the data do not see.
        ci95: 95 % interval of each parameter in SI units.
        identifiable: whether each parameter is determined by the recording (see the module docstring).
        at_bound: whether each parameter ended on a bound.
        effective_samples: N_eff.
        residual_std: s [N].
    """

    covariance: np.ndarray
    ci95: dict[str, tuple[float, float]]
    identifiable: dict[str, bool]
    at_bound: dict[str, bool]
    effective_samples: float
    residual_std: float

    def standard_error(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))


def effective_samples(residuals: np.ndarray) -> float:
    """N (1 - ρ) / (1 + ρ) with ρ the lag-1 autocorrelation of ``residuals`` (clipped to [0, 0.999])."""
    r = residuals - residuals.mean()
    denominator = float(r @ r)
    rho = float(r[1:] @ r[:-1]) / denominator if denominator > 0 else 0.0
    rho = min(max(rho, 0.0), 0.999)
    return max(len(r) * (1.0 - rho) / (1.0 + rho), 2.0)


def laplace(model: ParameterSet, theta: np.ndarray, jacobian: np.ndarray, residuals: np.ndarray,
            readings: np.ndarray | None = None, model_error: float = 0.0,
            windows: np.ndarray | None = None, viscous_readings: np.ndarray | None = None,
            inertial_error: float = 0.0) -> Uncertainty:
    """The covariance at ``theta`` from the fitted samples' ``jacobian`` (N, k) and ``residuals`` (N,) [N], with
    the simulator's relative force error ``model_error`` σ_m acting on its ``readings`` p (N,) [N] and its relative
    error ``inertial_error`` σ_i acting on their part p − v that does not scale with the stress
    (``viscous_readings`` v (N,) [N]), independently in each window of samples (``windows``: each sample's window
    label, (N,); default one window) (module docstring), and 95 % intervals, identifiability and bound flags."""
    n, k = jacobian.shape
    n_eff = min(effective_samples(residuals), float(n))
    s2 = float(residuals @ residuals) / max(n - k, 1)
    u, singular, vt = np.linalg.svd(jacobian, full_matrices=False)
    seen = singular > singular.max(initial=0.0) * 1e-8 if singular.size else np.zeros(0, bool)
    covariance = (vt[seen].T / singular[seen] ** 2) @ vt[seen] * s2 * n / n_eff
    errors = [(model_error, readings)]
    if inertial_error > 0.0 and readings is not None:
        if viscous_readings is None or np.shape(viscous_readings) != (n,):
            raise ValueError(f"viscous_readings: expected the readings' viscous part, one per sample ({n}), with "
                             "an inertial_error")
        errors.append((inertial_error, readings - viscous_readings))
    labels = np.zeros(n, dtype=int) if windows is None else np.asarray(windows)
    if labels.shape != (n,):
        raise ValueError(f"windows: {labels.shape} labels for {n} samples; expected one per sample")
    for sigma, part in errors:
        if sigma > 0.0 and part is not None:
            for label in np.unique(labels):
                p = np.where(labels == label, part, 0.0)
                shift = vt[seen].T @ ((u[:, seen].T @ p) / singular[seen])  # J⁺ p_w: dθ per unit relative error
                covariance = covariance + sigma**2 * np.outer(shift, shift)
    blind = np.any(np.abs(vt[~seen]) > 1e-6, axis=0) if (~seen).any() else np.zeros(k, bool)
    covariance[blind, :] = np.inf
    covariance[:, blind] = np.inf
    return uncertainty_of(model, theta, covariance, n_eff, math.sqrt(s2))


def uncertainty_of(model: ParameterSet, theta: np.ndarray, covariance: np.ndarray, effective_samples: float,
                   residual_std: float) -> Uncertainty:
    """The 95 % intervals, identifiability and bound flags (module docstring) that ``covariance`` of θ gives at
    ``theta`` (infinite rows and columns: directions the data do not see), with the fit's N_eff and residual
    scale ``residual_std``."""
    se = np.sqrt(np.diag(covariance))
    span = model.upper - model.lower
    near = np.minimum(AT_BOUND * span, Z95 * se)  # θ units
    at_bound = (theta - model.lower < near) | (model.upper - theta < near)
    ci95, identifiable, flags = {}, {}, {}
    with np.errstate(over="ignore", invalid="ignore"):
        lows, highs = model.si_of_theta(theta - Z95 * se), model.si_of_theta(theta + Z95 * se)
    for j, name in enumerate(model.names):
        ci95[name] = (float(lows[j]) if math.isfinite(se[j]) else (0.0 if model.scales[j] == "log" else -math.inf),
                      float(highs[j]) if math.isfinite(se[j]) else math.inf)
        identifiable[name] = bool(Z95 * se[j] <= identifiable_half_width(model.scales[j]) and not at_bound[j])
        flags[name] = bool(at_bound[j])
    return Uncertainty(covariance=covariance, ci95=ci95, identifiable=identifiable, at_bound=flags,
                       effective_samples=effective_samples, residual_std=residual_std)


def identifiable_half_width(scale: str) -> float:
    """The widest 95 % half-width in θ of an identifiable parameter on ``scale``: ln ``MAX_FACTOR`` for a
    log-scaled one, ``MAX_LINEAR_HALF_WIDTH`` for an index."""
    return math.log(MAX_FACTOR) if scale == "log" else MAX_LINEAR_HALF_WIDTH


def log_viscosity_interval(model: FitModel, theta: np.ndarray, covariance: np.ndarray,
                           shear_rate: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Apparent viscosity [Pa·s] at ``shear_rate`` [1/s] with its 95 % band (delta method on ln η):
    ln η ± 1.96 sqrt(g cov gᵀ), g = d ln η / d θ. Returns (η, lower, upper)."""
    eta, grad = model.viscosity(np.atleast_1d(shear_rate), theta)
    half = Z95 * np.sqrt(delta_variance(grad, covariance))
    with np.errstate(over="ignore"):  # an unresolved viscosity's band is [0, inf)
        return eta, eta * np.exp(-half), eta * np.exp(half)


def delta_variance(gradients: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """Delta-method variances g cov gᵀ of functions of θ with ``gradients`` g (S, k), ≥ 0; infinite where a
    gradient has a component along a direction the data do not see (an infinite row of ``covariance``)."""
    blind = ~np.isfinite(np.diag(covariance))
    seen = ~blind
    var = np.einsum("si,ij,sj->s", gradients[:, seen], covariance[np.ix_(seen, seen)], gradients[:, seen])
    var = np.where(np.abs(gradients[:, blind]).max(axis=1, initial=0.0) > 1e-9, np.inf, var)
    return np.maximum(var, 0.0)
