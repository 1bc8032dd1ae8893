"""A law fitted to apparent-viscosity points, as a rheometer's flow curve is fitted: weighted least squares in ln η.

For points η_k [Pa·s] at shear rates γ̇_k [1/s] with standard errors σ_k of ln η_k,

    χ²(θ) = Σ_k (ln η_k − ln η(γ̇_k; θ))² / σ_k²,

minimised within the law's bounds (θ of ``FitModel``: log-scaled where positive) from the best of its starts
(``point_starts``). The covariance of θ is B² (Jᵀ W J)⁺, W = diag(1/σ_k²), J = d ln η / dθ at the points, with
the Birge ratio B² = max(1, χ² / (S − k)) for S points and k parameters (1 where S ≤ k): scatter beyond the points'
errors widens it, a fit closer than they allow does not narrow it. A direction of θ the points do not see (fewer
points than parameters, a bend outside the points' range) gets an infinite variance and its parameters an open
interval (``uncertainty.uncertainty_of``). Laws are compared by BIC = χ² + k ln S, the Gaussian likelihood with
known errors (−2 ln L = χ² up to a constant common to every law); a difference above 10 is very strong evidence
(``selection.EVIDENCE``).

The covariance's intervals θ_j ± 1.96 σ_j assume χ² quadratic in θ. A law with as many parameters as points
(Carreau or Cross on four windows) is far from that: it can pass through every point, and the curvature at its
fit then says nothing of how far a parameter can move while the others follow. ``profiled`` gives each parameter
the profile-likelihood interval instead (Venzon and Moolgavkar 1988; Raue et al. 2009): the θ_j at which
χ²_p(θ_j) = min over the other parameters of χ²(θ) rises Z95² B² above its minimum, B² the Birge ratio, searched
outward on each side; a side on which χ²_p stays below that up to the law's bound is open. For a law linear in θ
(the power law in ln η) it is the covariance's interval exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from .initial import initial_models, newtonian_embedding
from .models import FitModel
from .uncertainty import Z95, Uncertainty, identifiable_half_width, uncertainty_of

#: Relative singular value below which a direction of θ counts as unseen by the points.
UNSEEN = 1e-8
#: Bisections of a profile interval's end once bracketed: its θ to 2⁻¹⁶ of the bracket.
PROFILE_BISECTIONS = 16


@dataclass(frozen=True)
class PointsFit:
    """A law's fit to viscosity points: ``model`` at its best ``theta``, its ``chi2`` [1], ``bic`` [1] and
    ``uncertainty`` (covariance of θ, 95 % intervals, identifiability; its ``residual_std`` is the Birge ratio B
    [1], its ``effective_samples`` the number of points)."""

    model: FitModel
    theta: np.ndarray
    chi2: float
    bic: float
    uncertainty: Uncertainty


def point_starts(name: str, shear_rate: np.ndarray, viscosity: np.ndarray) -> list[FitModel]:
    """Starts of law ``name`` for points (γ̇ [1/s], η [Pa·s]): the identification's starts and the Newtonian
    embedding at the points' middle, and, for laws with a time constant λ [s], the first start with λ at the
    reciprocal of the slowest and of the fastest shear rate (the bend at either end of the points)."""
    rate = float(np.exp(np.mean(np.log(shear_rate))))
    eta = float(np.exp(np.mean(np.log(viscosity))))
    starts = initial_models(name, eta, rate)
    if name != "newtonian":
        starts.append(newtonian_embedding(name, eta, rate))
    if "lam" in starts[0].names:
        j = starts[0].names.index("lam")
        for g in (float(np.min(shear_rate)), float(np.max(shear_rate))):
            theta = starts[0].theta().copy()
            theta[j] = math.log(1.0 / g)
            start = FitModel.named(name, **starts[0].params_si())
            start.set_theta(np.clip(theta, start.lower, start.upper))
            starts.append(start)
    return starts


def fit_points(name: str, shear_rate, viscosity, log_std) -> PointsFit:
    """Law ``name`` fitted to the points (γ̇_k [1/s], η_k [Pa·s], σ_k of ln η_k [1]) (module docstring)."""
    rates = np.asarray(shear_rate, dtype=np.float64)
    eta = np.asarray(viscosity, dtype=np.float64)
    sigma = np.asarray(log_std, dtype=np.float64)
    if not (rates.shape == eta.shape == sigma.shape and rates.size >= 1):
        raise ValueError(f"fit_points: {rates.size} shear rates, {eta.size} viscosities and {sigma.size} errors; "
                         "expected one of each per point")
    finite = np.all(np.isfinite(rates)) and np.all(np.isfinite(eta)) and np.all(np.isfinite(sigma))
    if not (finite and np.all(rates > 0) and np.all(eta > 0) and np.all(sigma > 0)):
        raise ValueError("fit_points: expected positive shear rates [1/s], positive viscosities [Pa s] and finite "
                         "positive errors of ln η")
    starts = point_starts(name, rates, eta)
    model = starts[0]
    residuals, jacobian = _objective(model, rates, eta, sigma)
    best = None
    for start in starts:
        fit = least_squares(residuals, np.clip(start.theta(), model.lower, model.upper), jac=jacobian,
                            bounds=(model.lower, model.upper), method="trf")
        if best is None or fit.cost < best.cost:
            best = fit
    theta = best.x
    model.set_theta(theta)
    chi2 = float(np.sum(residuals(theta) ** 2))
    k, s = model.size, rates.size
    birge = max(1.0, chi2 / (s - k)) if s > k else 1.0
    _, singular, vt = np.linalg.svd(jacobian(theta), full_matrices=True)  # vt (k, k): the unseen rows too
    seen = np.zeros(k, dtype=bool)
    seen[:singular.size] = singular > singular.max(initial=0.0) * UNSEEN
    covariance = (vt[seen].T / singular[seen[:singular.size]] ** 2) @ vt[seen] * birge
    blind = np.any(np.abs(vt[~seen]) > 1e-6, axis=0)
    covariance[blind, :] = np.inf
    covariance[:, blind] = np.inf
    uncertainty = uncertainty_of(model, theta, covariance, float(s), math.sqrt(birge))
    return PointsFit(model, theta, chi2, chi2 + k * math.log(s), uncertainty)


def _objective(model: FitModel, rates: np.ndarray, eta: np.ndarray, sigma: np.ndarray):
    """The weighted residuals (ln η_k − ln η(γ̇_k; θ)) / σ_k and their Jacobian in θ."""
    target = np.log(eta)

    def residuals(theta: np.ndarray) -> np.ndarray:  # a law can underflow to η = 0 at a trial θ: a huge residual
        return (target - np.log(np.maximum(model.viscosity_values(rates, theta), np.finfo(float).tiny))) / sigma

    def jacobian(theta: np.ndarray) -> np.ndarray:
        return -model.viscosity(rates, theta)[1] / sigma[:, None]

    return residuals, jacobian


def profiled(fit: PointsFit, shear_rate, viscosity, log_std) -> PointsFit:
    """``fit`` (of the points γ̇_k [1/s], η_k [Pa·s], σ_k of ln η_k) with each parameter's 95 % interval from its
    profile likelihood (module docstring), identifiable when both ends are within the covariance's rule
    (``uncertainty.identifiable_half_width``) and it is not on a bound; the covariance is kept."""
    rates, eta, sigma = (np.asarray(v, dtype=np.float64) for v in (shear_rate, viscosity, log_std))
    model = fit.model
    residuals, jacobian = _objective(model, rates, eta, sigma)
    k = model.size
    rise = Z95**2 * fit.uncertainty.residual_std**2  # Z95² B², B the fit's Birge ratio
    ci95, identifiable = {}, {}
    for j, name in enumerate(model.names):
        ends = [_profile_end(residuals, jacobian, model, fit.theta, fit.chi2 + rise, j, side) for side in (-1, 1)]
        half = max(abs(end - fit.theta[j]) for end in ends)
        low, high = (float(model.si_of_theta(np.full(k, end))[j]) for end in ends)
        ci95[name] = (low, high)
        identifiable[name] = bool(half <= identifiable_half_width(model.scales[j])
                                  and not fit.uncertainty.at_bound[name])
    return replace(fit, uncertainty=replace(fit.uncertainty, ci95=ci95, identifiable=identifiable))


def _profile_end(residuals, jacobian, model: FitModel, theta: np.ndarray, level: float, j: int, side: int
                 ) -> float:
    """The θ_j on ``side`` (−1, +1) of ``theta`` at which the profile χ² reaches ``level``: steps doubling from
    0.05 in θ until it does, then bisection; ∓inf (an open end) where it stays below up to the law's bound."""
    bound = model.lower[j] if side < 0 else model.upper[j]
    inner, start, step = float(theta[j]), np.delete(theta, j), 0.05
    while True:
        outer = float(np.clip(theta[j] + side * step, min(bound, theta[j]), max(bound, theta[j])))
        chi2, rest = _profile(residuals, jacobian, model, theta, j, outer, start)
        if chi2 >= level:
            break
        if outer == bound:
            return -math.inf if side < 0 else math.inf
        inner, start, step = outer, rest, 2.0 * step
    for _ in range(PROFILE_BISECTIONS):
        middle = 0.5 * (inner + outer)
        chi2, rest = _profile(residuals, jacobian, model, theta, j, middle, start)
        if chi2 >= level:
            outer = middle
        else:
            inner, start = middle, rest
    return 0.5 * (inner + outer)


def _profile(residuals, jacobian, model: FitModel, theta: np.ndarray, j: int, value: float, start: np.ndarray
             ) -> tuple[float, np.ndarray]:
    """min over the parameters other than j of χ² with θ_j = ``value``, from ``start`` and from ``theta``'s; the
    minimum and the other parameters there."""
    others = [i for i in range(model.size) if i != j]
    full = theta.copy()
    full[j] = value
    if not others:
        return float(np.sum(residuals(full) ** 2)), start

    def sub_residuals(rest: np.ndarray) -> np.ndarray:
        full[others] = rest
        return residuals(full)

    def sub_jacobian(rest: np.ndarray) -> np.ndarray:
        full[others] = rest
        return jacobian(full)[:, others]

    best = None
    for guess in (start, theta[others]):
        result = least_squares(sub_residuals, np.clip(guess, model.lower[others], model.upper[others]),
                               jac=sub_jacobian, bounds=(model.lower[others], model.upper[others]), method="trf")
        if best is None or result.cost < best.cost:
            best = result
    return 2.0 * float(best.cost), best.x
