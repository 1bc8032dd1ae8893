"""Steady shear flow curves: loading them, fitting rheology laws to them and ranking the laws.

A fit minimises the (optionally weighted) sum of squared log-stress residuals

    r_i = sqrt(w_i) (log tau_model(g_i) - log tau_i)

over the unconstrained raw parameters with ``scipy.optimize.least_squares`` (Levenberg-Marquardt, exact Jacobian
from torch autograd, float64), from several data-driven starting points. Uncertainties are Gauss-Newton: with J
the Jacobian of r with respect to theta (theta = log value for log-scaled parameters, the value itself for linear
ones),

    cov(theta) = s^2 (J^T J)^-1,   s^2 = sum r_i^2 / (N - k),

and the 95 % interval is theta +- t_{0.975, N-k} sqrt(cov_ii), mapped back to SI (asymmetric for log-scaled
parameters). Model selection uses the Gaussian log-likelihood of the residuals with the variance at its maximum
likelihood value, with k the number of law parameters (counting the variance too would add the same constant to
every law's AIC and BIC):

    log L = -N/2 (log(2 pi RSS/N) + 1) + 1/2 sum log w_i,   AIC = 2k - 2 log L,   BIC = k log N - 2 log L.
"""

from __future__ import annotations

import copy
import csv
import io
import math
import os
import warnings
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from importlib import resources

import numpy as np
import torch
from numpy.typing import ArrayLike
from scipy import optimize, stats
from torch import Tensor

from diffstir.report_files import finite_or_none
from diffstir.rheology.laws import DEFAULT_SHEAR_RATE_REG, LAWS, RegularisedLaw, RheologyLaw
from diffstir.rheology.parameters import from_raw, to_raw

#: Column names of the flow-curve CSV format, with their units.
COLUMNS = {"sample_id": None, "shear_rate_1/s": "1/s", "stress_Pa": "Pa"}

#: The laws :func:`rank_laws` compares by default.
DEFAULT_LAWS = ("newtonian", "power_law", "carreau", "cross", "herschel_bulkley", "bingham")

#: A parameter is flagged not identifiable when its 95 % interval is wider than this relative width:
#: log(hi/lo) for log-scaled parameters (a factor e^2 = 7.4), (hi - lo)/|value| for linear ones.
MAX_RELATIVE_CI_WIDTH = 2.0

#: ... or when its value lies within this fraction of the bounds' range (on its scale) from a bound.
AT_BOUND_FRACTION = 1e-3

#: When a regularised law is fitted by name, g_c [1/s] is set to this fraction of the lowest measured shear rate
#: (or to the default g_c, if smaller), so that the regularisation moves the fitted stress by well under 1 %.
REGULARISATION_FRACTION = 1e-2


@dataclass(frozen=True, eq=False)
class FlowCurve:
    """A steady shear flow curve.

    Attributes:
        shear_rate: shear rates [1/s], 1-d, finite and > 0.
        stress: shear stresses [Pa], same length, finite and > 0.
        name: sample label.
        source: where the data come from (the file's comment header for loaded curves).
    """

    shear_rate: np.ndarray
    stress: np.ndarray
    name: str = ""
    source: str = ""

    def __post_init__(self) -> None:
        g = np.asarray(self.shear_rate, dtype=np.float64).ravel()
        tau = np.asarray(self.stress, dtype=np.float64).ravel()
        if len(g) != len(tau) or len(g) == 0:
            raise ValueError(f"flow curve {self.name!r}: shear_rate and stress need the same nonzero length")
        for field_name, values, unit in (("shear_rate", g, "1/s"), ("stress", tau, "Pa")):
            if not np.all(np.isfinite(values)) or np.any(values <= 0.0):
                raise ValueError(f"flow curve {self.name!r}: {field_name} must be finite and > 0 in {unit}")
        object.__setattr__(self, "shear_rate", g)
        object.__setattr__(self, "stress", tau)

    @property
    def viscosity(self) -> np.ndarray:
        """Apparent viscosity tau/g [Pa·s]."""
        return self.stress / self.shear_rate

    def __len__(self) -> int:
        return len(self.shear_rate)


def load_flow_curves(path: str | os.PathLike) -> dict[str, FlowCurve]:
    """Read a flow-curve CSV: ``#`` comment lines, then the columns ``sample_id,shear_rate_1/s,stress_Pa``.

    Returns:
        One :class:`FlowCurve` per ``sample_id``, in file order, named ``"<file stem>/<sample_id>"``; each curve's
        ``source`` is the comment block above the column names.

    Raises:
        ValueError: a missing column, or a value that is not a finite number > 0 (the message names the file,
            line, column and unit).
    """
    with open(path, encoding="utf-8") as file:
        return _parse_flow_curves(file.read(), os.fspath(path))


def bundled_flow_curves() -> dict[str, FlowCurve]:
    """All flow curves shipped in ``diffstir/data/flow-curves/``, keyed ``"<file stem>/<sample_id>"``.

    The sources and licenses are in each curve's ``source`` and in that folder's README.
    """
    folder = resources.files("diffstir") / "data" / "flow-curves"
    curves = {}
    for entry in sorted(folder.iterdir(), key=lambda item: item.name):
        if entry.name.endswith(".csv"):
            stem = entry.name[: -len(".csv")]
            for sample, curve in _parse_flow_curves(entry.read_text(encoding="utf-8"), entry.name).items():
                curves[f"{stem}/{sample}"] = curve
    return curves


def _parse_flow_curves(text: str, label: str) -> dict[str, FlowCurve]:
    lines = text.splitlines()
    numbered = [(number, line) for number, line in enumerate(lines, start=1) if line.strip() and line[0] != "#"]
    if not numbered:
        raise ValueError(f"{label}: no header line with columns {list(COLUMNS)}")
    header = [line[1:].strip() for line in lines[: numbered[0][0] - 1] if line.startswith("#")]
    reader = csv.reader(io.StringIO("\n".join(line for _, line in numbered)))
    columns = [name.strip() for name in next(reader)]
    for column in COLUMNS:
        if column not in columns:
            unit = f" [{COLUMNS[column]}]" if COLUMNS[column] else ""
            raise ValueError(f"{label}: missing column {column!r}{unit}; found {columns}")
    index = {column: columns.index(column) for column in COLUMNS}
    samples: dict[str, tuple[list[float], list[float]]] = {}
    for (number, _), row in zip(numbered[1:], reader):
        if len(row) < len(columns):
            raise ValueError(f"{label}, line {number}: expected {len(columns)} fields, got {len(row)}")
        values = [_positive_value(row[index[column]], label, number, column) for column in COLUMNS if COLUMNS[column]]
        rates, stresses = samples.setdefault(row[index["sample_id"]].strip(), ([], []))
        rates.append(values[0])
        stresses.append(values[1])
    if not samples:
        raise ValueError(f"{label}: no data rows")
    source = "\n".join(header)
    stem = os.path.splitext(os.path.basename(label))[0]
    return {
        name: FlowCurve(np.array(g), np.array(tau), f"{stem}/{name}", source) for name, (g, tau) in samples.items()
    }


def _positive_value(text: str, label: str, number: int, column: str) -> float:
    unit = COLUMNS[column]
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{label}, line {number}: column {column!r} = {text!r} is not a number in {unit}") from None
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{label}, line {number}: column {column!r} = {text.strip()} must be finite and > 0 {unit}")
    return value


@dataclass
class FlowCurveFit:
    """The result of :func:`fit_flow_curve`.

    Attributes:
        law: the fitted law (float64).
        curve_name: name of the fitted curve.
        params: fitted values in SI units.
        units: unit of each parameter.
        ci95: 95 % confidence interval (lo, hi) of each parameter in SI units (may extend beyond the bounds;
            infinite where the data do not constrain the parameter at all).
        at_bound: whether each parameter ended on (within :data:`AT_BOUND_FRACTION` of) a bound.
        identifiable: False where the parameter is at a bound or its interval is wider than
            :data:`MAX_RELATIVE_CI_WIDTH`.
        covariance: Gauss-Newton covariance of theta (log value for log-scaled, value for linear parameters),
            in the order of ``params``.
        residuals: unweighted log-stress residuals log tau_model - log tau_data, per point.
        rms_log_residual: root mean square of ``residuals`` (about the relative rms error of the stress).
        aic, bic: Akaike and Bayesian information criteria (see the module docstring).
        n_points: number of data points N.
        success, message, nfev: from ``scipy.optimize.least_squares`` for the best start.
    """

    law: RheologyLaw
    curve_name: str
    params: dict[str, float]
    units: dict[str, str]
    ci95: dict[str, tuple[float, float]]
    at_bound: dict[str, bool]
    identifiable: dict[str, bool]
    covariance: np.ndarray
    residuals: np.ndarray
    rms_log_residual: float
    aic: float
    bic: float
    n_points: int
    success: bool
    message: str
    nfev: int

    @property
    def n_params(self) -> int:
        """Number of fitted parameters k."""
        return len(self.params)

    def correlation(self) -> np.ndarray:
        """Correlation matrix of theta (see ``covariance``); NaN where a variance is infinite."""
        sd = np.sqrt(np.diag(self.covariance))
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.covariance / np.outer(sd, sd)

    def summary(self) -> dict:
        """A JSON-serialisable dict of the result (infinite interval ends become None)."""
        shear_rate_reg = getattr(self.law, "shear_rate_reg", None)
        return {
            "law": self.law.name,
            "curve": self.curve_name,
            "params": dict(self.params),
            "units": dict(self.units),
            "ci95": {key: [finite_or_none(lo), finite_or_none(hi)] for key, (lo, hi) in self.ci95.items()},
            "at_bound": dict(self.at_bound),
            "identifiable": dict(self.identifiable),
            "shear_rate_reg": shear_rate_reg,
            "rms_log_residual": self.rms_log_residual,
            "aic": self.aic,
            "bic": self.bic,
            "n_points": self.n_points,
            "n_params": self.n_params,
            "success": self.success,
            "message": self.message,
        }

    def report(self, min_correlation: float = 0.9) -> str:
        """A readable report: statistics, each parameter with its 95 % interval, and strong correlations."""
        lines = [
            f"[[Fit of {self.law.name} to {self.curve_name or 'flow curve'}]]",
            f"    data points      = {self.n_points}",
            f"    parameters       = {self.n_params}",
            f"    rms log residual = {self.rms_log_residual:.4g}",
            f"    AIC              = {self.aic:.4g}",
            f"    BIC              = {self.bic:.4g}",
            f"    converged        = {self.success} ({self.message})",
        ]
        if isinstance(self.law, RegularisedLaw):
            lines.append(f"    shear_rate_reg   = {self.law.shear_rate_reg:.4g} 1/s (fixed)")
        lines.append("[[Parameters]] (95 % confidence interval)")
        for key, value in self.params.items():
            lo, hi = self.ci95[key]
            unit = "" if self.units[key] == "1" else f" {self.units[key]}"
            notes = ["at bound"] if self.at_bound[key] else []
            if not self.identifiable[key]:
                notes.append("not identifiable")
            suffix = f"  ({', '.join(notes)})" if notes else ""
            lines.append(f"    {key:8s} = {value:.5g}{unit}  [{lo:.4g}, {hi:.4g}]{suffix}")
        correlation = self.correlation()
        names = list(self.params)
        pairs = [
            f"    C({names[i]}, {names[j]}) = {correlation[i, j]:+.3f}"
            for i in range(len(names))
            for j in range(i + 1, len(names))
            if abs(correlation[i, j]) >= min_correlation
        ]
        if pairs:
            lines.append(f"[[Correlations]] (|C| >= {min_correlation}, of log values for log-scaled parameters)")
            lines.extend(pairs)
        return "\n".join(lines)


def fit_flow_curve(
    law_or_name: RheologyLaw | str,
    curve: FlowCurve,
    *,
    weights: ArrayLike | None = None,
) -> FlowCurveFit:
    """Fit a rheology law to a flow curve by least squares on log-stress residuals.

    Args:
        law_or_name: a name in :data:`~diffstir.rheology.laws.LAWS`, or a law whose bounds, regularisation and
            current values (as one extra starting point) are used; it is copied, not modified. By name, regularised
            laws get g_c = min(default, :data:`REGULARISATION_FRACTION` x lowest shear rate).
        curve: the data.
        weights: optional positive relative weights of the squared log residuals (inverse variances up to a
            common factor), one per point.

    Returns:
        The best fit over the starting points.

    Raises:
        ValueError: unknown law name, bad weights, or no more points than parameters.
    """
    law = _prepare_law(law_or_name, curve.shear_rate)
    n_points, k = len(curve), len(law.params)
    if n_points <= k:
        raise ValueError(f"{law.name} has {k} parameters; fitting needs more points, got {n_points}")
    w = _check_weights(weights, n_points)
    problem = _LogStressResiduals(law, curve, w)

    best = None
    for start in _starting_points(law, curve, include_current=not isinstance(law_or_name, str)):
        result = optimize.least_squares(
            lambda x: problem.of_raw(torch.from_numpy(x)).detach().numpy(),
            problem.raw_from_si(start),
            jac=lambda x: _pointwise_jacobian(problem.of_raw, x, n_points),
            method="lm",
            xtol=1e-12,
            ftol=1e-12,
            gtol=1e-12,
        )
        if best is None or result.cost < best.cost:
            best = result
    with torch.no_grad():
        for param, raw in zip(law.params.values(), best.x):
            param.raw.fill_(float(raw))

    params = law.parameters_si()
    with torch.no_grad():
        residuals = problem.unweighted(law.constrained()).numpy()
    weighted_rss = float(np.sum(w * residuals**2))
    theta = np.array([_to_theta(params[key], param.scale) for key, param in law.params.items()])
    covariance = _gauss_newton_covariance(_pointwise_jacobian(problem.of_theta, theta, n_points), weighted_rss)
    half_width = stats.t.ppf(0.975, n_points - k) * np.sqrt(np.diag(covariance))

    ci95, at_bound, identifiable = {}, {}, {}
    for i, (key, param) in enumerate(law.params.items()):
        lo, hi = theta[i] - half_width[i], theta[i] + half_width[i]
        if param.scale == "log":
            with np.errstate(over="ignore"):
                ci95[key] = (float(np.exp(lo)), float(np.exp(hi)))
            width = hi - lo
        else:
            ci95[key] = (float(lo), float(hi))
            width = (hi - lo) / abs(theta[i]) if theta[i] != 0.0 else math.inf
        at_bound[key] = min(param.fraction(), 1.0 - param.fraction()) < AT_BOUND_FRACTION
        identifiable[key] = bool(not at_bound[key] and width <= MAX_RELATIVE_CI_WIDTH)

    log_likelihood = -0.5 * n_points * (math.log(2.0 * math.pi * weighted_rss / n_points) + 1.0)
    log_likelihood += 0.5 * float(np.sum(np.log(w)))
    return FlowCurveFit(
        law=law,
        curve_name=curve.name,
        params=params,
        units=dict(law.units),
        ci95=ci95,
        at_bound=at_bound,
        identifiable=identifiable,
        covariance=covariance,
        residuals=residuals,
        rms_log_residual=float(np.sqrt(np.mean(residuals**2))),
        aic=2.0 * k - 2.0 * log_likelihood,
        bic=k * math.log(n_points) - 2.0 * log_likelihood,
        n_points=n_points,
        success=bool(best.success),
        message=str(best.message),
        nfev=int(best.nfev),
    )


def rank_laws(
    curve: FlowCurve,
    laws: Iterable[str | RheologyLaw] = DEFAULT_LAWS,
    *,
    weights: ArrayLike | None = None,
) -> list[FlowCurveFit]:
    """Fit each law to ``curve`` and return the fits sorted by BIC, best (lowest) first; each carries its AIC too."""
    fits = [fit_flow_curve(law, curve, weights=weights) for law in laws]
    return sorted(fits, key=lambda fit: fit.bic)


def _prepare_law(law_or_name: RheologyLaw | str, shear_rate: np.ndarray) -> RheologyLaw:
    """A float64 law to fit: built by name (with g_c below the data), or a copy of the given law."""
    g_min = float(shear_rate.min())
    if isinstance(law_or_name, str):
        if law_or_name not in LAWS:
            raise ValueError(f"unknown rheology law {law_or_name!r}; valid names: {sorted(LAWS)}")
        cls = LAWS[law_or_name]
        kwargs = {"dtype": torch.float64}
        if issubclass(cls, RegularisedLaw):
            kwargs["shear_rate_reg"] = min(DEFAULT_SHEAR_RATE_REG, REGULARISATION_FRACTION * g_min)
        return cls(**kwargs)
    if not isinstance(law_or_name, RheologyLaw):
        raise TypeError(f"expected a RheologyLaw or a law name in {sorted(LAWS)}, got {type(law_or_name).__name__}")
    if not law_or_name.specs:
        raise ValueError(f"{type(law_or_name).__name__} has no parameters to fit")
    if isinstance(law_or_name, RegularisedLaw) and law_or_name.shear_rate_reg > REGULARISATION_FRACTION * g_min:
        warnings.warn(
            f"{law_or_name.name}: shear_rate_reg = {law_or_name.shear_rate_reg:g} 1/s is not far below the lowest "
            f"shear rate {g_min:g} 1/s; the fit sees the regularised law",
            stacklevel=3,
        )
    values = law_or_name.parameters_si()
    law = copy.deepcopy(law_or_name).double()
    law.set_parameters_si(**values)  # restores the digits lost if the law was float32
    return law


class _LogStressResiduals:
    """Weighted log-stress residuals sqrt(w_i) (log tau_model(g_i) - log tau_i) of a law on a curve, as functions
    of the raw parameters or of theta (log value for log-scaled, value for linear parameters).

    Parameter tensors may carry a leading point dimension (shape (N, k)); see :func:`_pointwise_jacobian`.
    """

    def __init__(self, law: RheologyLaw, curve: FlowCurve, weights: np.ndarray) -> None:
        self.law = law
        self.bounded = list(law.params.items())
        self.shear_rate = torch.from_numpy(curve.shear_rate)
        self.log_stress = torch.from_numpy(np.log(curve.stress))
        self.sqrt_w = torch.from_numpy(np.sqrt(weights))

    def unweighted(self, params: Mapping[str, Tensor]) -> Tensor:
        model = torch.log(self.law.viscosity(self.shear_rate, params)) + torch.log(self.shear_rate)
        return model - self.log_stress

    def of_raw(self, raw: Tensor) -> Tensor:
        params = {key: from_raw(raw[..., i], p.lo, p.hi, p.scale) for i, (key, p) in enumerate(self.bounded)}
        return self.sqrt_w * self.unweighted(params)

    def of_theta(self, theta: Tensor) -> Tensor:
        params = {
            key: theta[..., i].exp() if p.scale == "log" else theta[..., i] for i, (key, p) in enumerate(self.bounded)
        }
        return self.sqrt_w * self.unweighted(params)

    def raw_from_si(self, values: Mapping[str, float]) -> np.ndarray:
        return np.array([to_raw(values[key], p.lo, p.hi, p.scale) for key, p in self.bounded])


def _to_theta(value: float, scale: str) -> float:
    return math.log(value) if scale == "log" else value


def _check_weights(weights: ArrayLike | None, n_points: int) -> np.ndarray:
    if weights is None:
        return np.ones(n_points)
    w = np.asarray(weights, dtype=np.float64).ravel()
    if len(w) != n_points or not np.all(np.isfinite(w)) or np.any(w <= 0.0):
        raise ValueError(f"weights must be {n_points} finite positive numbers (dimensionless), one per point")
    return w


def _pointwise_jacobian(residuals: Callable[[Tensor], Tensor], x: np.ndarray, n_points: int) -> np.ndarray:
    """Jacobian d residuals / d x of a residual function whose i-th entry depends on the data only through point i.

    Every point gets its own copy of x (a row of an (N, k) tensor), so one backward pass of the summed residuals
    yields all N rows; laws broadcast their parameters against the shear rate, which makes this possible.
    """
    rows = torch.from_numpy(x).expand(n_points, -1).clone().requires_grad_(True)
    residuals(rows).sum().backward()
    return rows.grad.numpy()


def _gauss_newton_covariance(jacobian: np.ndarray, weighted_rss: float) -> np.ndarray:
    """s^2 (J^T J)^-1 through the SVD of J; parameters in a direction J cannot see get infinite variance."""
    n_points, k = jacobian.shape
    _, singular, vt = np.linalg.svd(jacobian, full_matrices=False)
    seen = singular > singular.max() * max(n_points, k) * np.finfo(float).eps
    covariance = (vt[seen].T / singular[seen] ** 2) @ vt[seen] * (weighted_rss / (n_points - k))
    blind = np.any(np.abs(vt[~seen]) > 1e-6, axis=0)
    covariance[blind, :] = np.inf
    covariance[:, blind] = np.inf
    return covariance


def _starting_points(law: RheologyLaw, curve: FlowCurve, include_current: bool) -> list[dict[str, float]]:
    """Data-driven guesses for the six standard laws (and the law's current values if asked or if the law is not
    one of them), moved inside the bounds."""
    guess = _GUESSES.get(law.name)
    starts = [law.parameters_si()] if include_current or guess is None else []
    if guess is not None:
        order = np.argsort(curve.shear_rate)
        starts += guess(np.log(curve.shear_rate[order]), np.log(curve.stress[order]))
    bounds = law.bounds()
    return [{key: _inside(value, bounds[key], law.params[key].scale) for key, value in s.items()} for s in starts]


def _inside(value: float, bounds: tuple[float, float], scale: str) -> float:
    lo, hi = bounds
    if scale == "log":
        margin = (math.log(hi) - math.log(lo)) * 1e-3
        return math.exp(min(max(math.log(value), math.log(lo) + margin), math.log(hi) - margin))
    margin = (hi - lo) * 1e-3
    return min(max(value, lo + margin), hi - margin)


def _ends(log_g: np.ndarray, log_eta: np.ndarray) -> tuple[float, float, float, float]:
    """Low- and high-shear viscosity [Pa·s], the high-shear slope d log eta / d log g, and the shear rate [1/s]
    where log eta is halfway between the two ends."""
    third = max(len(log_g) // 3, 2)
    eta_low, eta_high = math.exp(np.mean(log_eta[:3])), math.exp(np.mean(log_eta[-3:]))
    slope = float(np.polyfit(log_g[-third:], log_eta[-third:], 1)[0])
    halfway = 0.5 * (math.log(eta_low) + math.log(eta_high))
    crossing = np.flatnonzero(np.diff(np.sign(log_eta - halfway)) != 0)
    g_mid = math.exp(log_g[crossing[0]] if len(crossing) else float(np.median(log_g)))
    return eta_low, eta_high, slope, g_mid


def _guess_newtonian(log_g: np.ndarray, log_tau: np.ndarray) -> list[dict[str, float]]:
    return [{"eta": math.exp(np.mean(log_tau - log_g))}]


def _guess_power_law(log_g: np.ndarray, log_tau: np.ndarray) -> list[dict[str, float]]:
    n, log_k = np.polyfit(log_g, log_tau, 1)
    return [{"k": math.exp(log_k), "n": float(n)}]


def _guess_plateau_laws(
    index_from_slope: Callable[[float], float],
) -> Callable[[np.ndarray, np.ndarray], list[dict[str, float]]]:
    """Carreau/Cross guesses; ``index_from_slope`` maps the high-shear slope d log eta / d log g to n."""

    def guess(log_g: np.ndarray, log_tau: np.ndarray) -> list[dict[str, float]]:
        eta_low, eta_high, slope, g_mid = _ends(log_g, log_tau - log_g)
        n = index_from_slope(slope)
        return [
            {"eta0": eta_low, "eta_inf": eta_high, "lam": factor / g_mid, "n": n}
            for factor in (0.1, 1.0, 10.0)
        ]

    return guess


def _hb_like(log_g: np.ndarray, log_tau: np.ndarray, fraction: float) -> tuple[float, np.ndarray, np.ndarray]:
    """A yield stress [Pa] a ``fraction`` of the lowest-shear stress, and the log shear rates and log excess
    stresses tau - tau_y where that excess is positive."""
    tau = np.exp(log_tau)
    tau_y = fraction * float(tau[0])
    keep = tau > tau_y * (1.0 + 1e-6)
    return tau_y, log_g[keep], np.log(tau[keep] - tau_y)


def _guess_herschel_bulkley(log_g: np.ndarray, log_tau: np.ndarray) -> list[dict[str, float]]:
    starts = []
    for fraction in (1e-3, 0.9):
        tau_y, lg, lexcess = _hb_like(log_g, log_tau, fraction)
        n, log_k = np.polyfit(lg, lexcess, 1) if len(lg) >= 2 else (1.0, float(np.mean(log_tau - log_g)))
        starts.append({"tau_y": tau_y, "k": math.exp(log_k), "n": float(n)})
    return starts


def _guess_bingham(log_g: np.ndarray, log_tau: np.ndarray) -> list[dict[str, float]]:
    starts = []
    for fraction in (1e-3, 0.9):
        tau_y, lg, lexcess = _hb_like(log_g, log_tau, fraction)
        upper = lexcess[len(lexcess) // 2 :] - lg[len(lg) // 2 :]
        eta_p = math.exp(float(np.median(upper))) if len(upper) else math.exp(float(np.mean(log_tau - log_g)))
        starts.append({"tau_y": tau_y, "eta_p": eta_p})
    return starts


_GUESSES = {
    "newtonian": _guess_newtonian,
    "power_law": _guess_power_law,
    "carreau": _guess_plateau_laws(lambda slope: 1.0 + slope),
    "cross": _guess_plateau_laws(lambda slope: -slope),
    "herschel_bulkley": _guess_herschel_bulkley,
    "bingham": _guess_bingham,
}
