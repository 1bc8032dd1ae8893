"""What a stirring programme tells about a law: the Fisher information of its steady speed windows.

Segment k of a programme holds speed U_k for d_k [s]; after the ramp and ``settle_time`` its steady window has
n_k = (d_k − t_ramp − t_settle) f samples at the sensor's rate f [Hz]. Through Metzner and Otto's apparent viscosity
(``planning.calibration``) the window's mean |reading| is ln M_k = ln M_{U_k}(η(γ̇_k; θ)), γ̇_k = k_s U_k / a, with
the error

    σ_k² = σ_e² / (n_k M_k²) + σ_m² + (σ_i (1 − s_k))²,      s_k = d ln M_{U_k} / d ln η at η(γ̇_k),

the sensor's noise σ_e [N] (at least its resolution / √12) over the window's samples, the simulator's relative
force error σ_m and its inertial part's σ_i on the share 1 − s_k of the reading: the errors the behaviour
experiment's windows carry, independent between windows (``fitting.uncertainty``). So, for the law's parameters θ
(``FitModel.theta``: log-scaled where positive),

    I(θ) = Σ_k g_k g_kᵀ / σ_k²,      g_k = s_k ∂ ln η(γ̇_k; θ) / ∂θ,

and the window's apparent viscosity ln η_k has the standard error σ_k / s_k. A window where the reading does not
respond to viscosity (s_k = 0: the inertial floor) adds nothing.

The design criterion is Lindley's expected information gain of a Gaussian prior of precision P (the spread of the
prior's draws, ``Prior``) under this information, per parameter:

    G(θ) = ½ log det(𝟙 + P^(−½) I(θ) P^(−½)) / k       [nats per parameter],

finite even where the programme leaves a direction of θ unidentified (Bayesian D-optimality, Chaloner and
Verdinelli 1995). The predicted 95 % interval of θ_j is θ_j ± 1.96 √(I⁻¹)_jj, with no prior in it.

The evidence a programme gives between laws is the expected ΔBIC of the window points' flow-curve fit: for a fluid
of law A, law B's best fit to its points leaves

    χ²_B = min_θB Σ_k (ln η_A(γ̇_k) − ln η_B(γ̇_k; θ_B))² s_k² / σ_k²,     ΔBIC_B−A = χ²_B + (k_B − k_A) ln S

over S windows; above 10 the evidence against B is very strong (``fitting.selection.EVIDENCE``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ..fitting import Z95, FitModel, identifiable_half_width, value_of
from .calibration import Calibration


#: Past this condition number of I a direction of θ counts as unidentified: its variance would be 1e12 times the
#: best-determined direction's.
MAX_CONDITION = 1e12


@dataclass(frozen=True)
class WindowErrors:
    """The errors of a window's mean |reading|: the sensor's 1-σ ``noise`` [N] and ``resolution`` [N], the
    simulator's relative force error ``model_error`` σ_m [1] and its inertial part's ``inertial_error`` σ_i [1]."""

    noise: float
    resolution: float
    model_error: float
    inertial_error: float

    @property
    def sample_noise(self) -> float:
        """σ_e [N]: the noise, at least the resolution's quantisation noise resolution / √12."""
        return max(self.noise, self.resolution / math.sqrt(12.0))


@dataclass(frozen=True)
class Window:
    """A programme's steady window at ``speed`` [m/s] with ``samples`` samples."""

    speed: float
    samples: int


@dataclass(frozen=True)
class WindowPoint:
    """What one window reads of a fluid: its shear rate γ̇_k [1/s], apparent viscosity η_k [Pa·s], mean |reading|
    M_k [N], s_k = d ln M / d ln η [1], the error σ_k of ln M_k [1], and g_k = d ln M_k / dθ."""

    shear_rate: float
    viscosity: float
    mean_abs: float
    log_slope: float
    log_error: float
    gradient: np.ndarray

    @property
    def viscosity_error(self) -> float:
        """The standard error of ln η_k [1], σ_k / s_k (inf where the reading does not respond to viscosity)."""
        return self.log_error / self.log_slope if self.log_slope > 0 else math.inf


def window_points(windows: list[Window], model: FitModel, calibration: Calibration, errors: WindowErrors,
                  theta: np.ndarray | None = None) -> list[WindowPoint]:
    """Each window's reading of the fluid ``model`` (at ``theta``, default its own), as the module docstring."""
    points = []
    for window in windows:
        rate = calibration.shear_rate(window.speed)
        eta, d_log_eta = model.viscosity(np.array([rate]), theta)
        mean_abs, s = calibration.ladder(window.speed).reading(float(eta[0]))
        s = min(max(s, 0.0), 1.0)
        variance = (errors.sample_noise**2 / (max(window.samples, 1) * mean_abs**2) + errors.model_error**2
                    + (errors.inertial_error * (1.0 - s)) ** 2)
        points.append(WindowPoint(rate, float(eta[0]), mean_abs, s, math.sqrt(variance), s * d_log_eta[0]))
    return points


def fisher_information(points: list[WindowPoint]) -> np.ndarray:
    """I = Σ_k g_k g_kᵀ / σ_k², (k, k)."""
    return sum(np.outer(p.gradient, p.gradient) / p.log_error**2 for p in points)


def information_gain(information: np.ndarray, prior_precision: np.ndarray) -> float:
    """½ log det(𝟙 + P^(−½) I P^(−½)) / k [nats per parameter] for a diagonal prior precision P (its diagonal)."""
    scale = 1.0 / np.sqrt(prior_precision)
    sign, logdet = np.linalg.slogdet(np.eye(len(scale)) + scale[:, None] * information * scale[None, :])
    return 0.5 * logdet / len(scale) if sign > 0 else 0.0


def predicted_intervals(model: FitModel, information: np.ndarray) -> dict[str, dict]:
    """Each of ``model``'s parameters' predicted 95 % interval [SI], θ_j ± 1.96 √(I⁻¹)_jj mapped to its unit, and
    whether it would be identifiable by the fit's rule (``fitting.identifiable_half_width``: within a factor 3
    each way, or ±0.5 for an index). The interval is (None, None) where the information leaves
    θ_j unidentified (a condition number of I beyond ``MAX_CONDITION``)."""
    theta = model.theta()
    covariance = np.linalg.inv(information) if np.linalg.cond(information) < MAX_CONDITION else None
    out = {}
    for j, (name, scale) in enumerate(zip(model.names, model.scales)):
        variance = math.nan if covariance is None else float(covariance[j, j])
        if not variance > 0:
            out[name] = {"ci95": [None, None], "identifiable": False}
            continue
        half = Z95 * math.sqrt(variance)
        out[name] = {"ci95": [_si(theta[j] - half, scale), _si(theta[j] + half, scale)],
                     "identifiable": bool(half <= identifiable_half_width(scale))}
    return out


def _si(theta: float, scale: str) -> float | None:
    """The SI value of ``theta`` on ``scale``; None where it is beyond a float (an interval without that end)."""
    try:
        return value_of(theta, scale)
    except OverflowError:
        return None


def expected_delta_bic(truth: FitModel, rival: FitModel, starts: list[FitModel], windows: list[Window],
                       calibration: Calibration, errors: WindowErrors) -> float:
    """ΔBIC of ``rival``'s law against ``truth``'s on the windows' points (module docstring), its best fit found
    from the best of ``starts`` (models of the rival's law)."""
    points = window_points(windows, truth, calibration, errors)
    rates = np.array([p.shear_rate for p in points])
    target = np.log([p.viscosity for p in points])
    weight = np.array([p.log_slope / p.log_error for p in points])

    def residuals(theta: np.ndarray) -> np.ndarray:
        return (target - np.log(np.maximum(rival.viscosity_values(rates, theta), np.finfo(float).tiny))) * weight

    def jacobian(theta: np.ndarray) -> np.ndarray:
        return -rival.viscosity(rates, theta)[1] * weight[:, None]

    best = min((s.theta() for s in starts), key=lambda t: float(np.sum(residuals(t) ** 2)))
    fit = least_squares(residuals, np.clip(best, rival.lower, rival.upper), jac=jacobian,
                        bounds=(rival.lower, rival.upper), method="trf")
    chi2 = min(float(np.sum(fit.fun**2)), float(np.sum(residuals(best) ** 2)))
    return chi2 + (rival.size - truth.size) * math.log(len(windows))
