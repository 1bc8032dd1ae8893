"""The behaviour class of a fluid from its apparent viscosities η_i ± σ_i (σ_i: standard error of ln η_i) at
effective shear rates γ̇_i, by two tests at the 95 % level:

1. **Slope.** Weighted least squares of ln η on ln γ̇ with weights 1/σ_i²,

       b = Σ w (x − x̄)(y − ȳ) / Σ w (x − x̄)²,   var b = B² / Σ w (x − x̄)²,   B² = max(1, χ²/(n − 2)),

   where B is the Birge ratio: scatter between the speeds beyond what the per-speed intervals allow (model and
   discretisation error that differs from speed to speed) widens the interval instead of being ignored. The 95 %
   interval is b ± 1.96 sqrt(var b). Containing 0: **newtonian**; above 0: **shear_thickening**; below 0: a
   viscosity that falls with shear rate, then
2. **Yield stress.** **yield_stress** when the slope's interval contains −1 (the stress does not grow with the
   shear rate over the speeds: a stress plateau), or, with at least four speeds, when a Herschel-Bulkley flow curve
   τ = τ_y + k γ̇ⁿ beats the power law τ = K γ̇ⁿ (τ_y = 0, the slope's straight line) in a likelihood-ratio test:
   Λ = (χ²_PL − χ²_HB) / B_HB² above 2.71, the 95 % point of the ½χ²₀ + ½χ²₁ law of a parameter on its bound
   (Self and Liang 1987). Otherwise **shear_thinning**.

The confidence is the share of parametric-bootstrap replicates (ln η_i* = ln η_i + B σ_i ε_i, ε ~ N(0, 1)) that
the same two tests put in the same class: 0.95 for a Newtonian fluid measured without bias, lower for borderline
ones. B is the Birge ratio of the better description of the points: the Herschel-Bulkley curve's where it was
fitted (a curved flow curve inflates the straight line's χ² with misfit, not noise), else the line's.

3. **Yield stress from the joint fit** (``with_joint_yield_test``). The per-speed points are Newtonian-equivalent
   viscosities, and a yield-stress fluid's are not on its flow curve: the unyielded fluid away from the rod does
   not enter a viscosity at one effective shear rate, and on the lab's yield-stress fluids the points' slope fell
   short of the law's chord with no curvature left to test (docs/accuracy.md). The laws fitted to every speed at
   once through the simulator (``joint.joint_fit``) model the plug itself. When they include laws with and
   without a yield stress, their Schwarz weights w_j = exp(−BIC_j/2) / Σ_l exp(−BIC_l/2) (BIC as −2 ln evidence,
   equal prior odds; Kass and Raftery 1995, Wagenmakers and Farrell 2004) give the weight W of the laws with a
   yield stress, and decide the yield stress in place of the points' test for any viscosity that does not rise:
   **yield_stress** when W > 1/2, else the slope's class (the points' **yield_stress** then reads **shear_thinning**).
   The confidence is then the bootstrap share of the replicates that do not rise times W, or the share of the
   slope's class times 1 − W. A yield stress counts only where it is material: its share of the stress at the
   slowest probed shear rate, τ_y / (η(γ̇_min) γ̇_min), must exceed ``YIELD_SHARE_SIGMAS`` = 2 times the
   simulator's relative force error σ_m, below which the simulator's own error could stand in for it; a law whose
   yield stress carries less is a liquid at the stirred rates and is weighed with the laws without one. (On
   glycerol on the 5 mm grid a Herschel-Bulkley fit with 2.7 % of the slowest stress as yield stress, ΔBIC 2.4,
   otherwise called the liquid a yield-stress fluid, docs/accuracy.md.)
4. **Slope from the joint fit** (``with_slope_estimate``; ``slope_test`` in ``pipeline``). With the power law
   τ = k γ̇ⁿ among the joint laws, its index is a second read of the slope, b_J = n − 1, with the standard error
   s_J of n from the joint fit's Laplace covariance, which holds the simulator's relative force error σ_m as an
   amplitude error of each speed window, independent between windows (``fitting.uncertainty.laplace``), as the
   points' intervals hold it. The points are Newtonian-equivalent viscosities, each read at one effective shear
   rate, where the fluid around the rod is sheared over a band of rates; the joint fit simulates the law itself
   at every speed, and the windows' waveforms, not only their levels, pin its n. The two reads are combined
   (``combined_slope``, the default) by inverse-variance weights, b = (b_P/s_P² + b_J/s_J²) / (1/s_P² + 1/s_J²),
   s = S / sqrt(1/s_P² + 1/s_J²), with the Particle Data Group's scale factor S = max(1, |z|),
   z = (b_J − b_P) / sqrt(s_P² + s_J²), for measurements that disagree beyond their errors (for two,
   S² = χ²/(N − 1) = z²; PDG, Review of Particle Physics, Introduction, "Averaging"): where the two reads
   disagree, model error that neither interval holds is there, and the class is only as sure as they agree. Test
   1's rule then applies to b ± 1.96 s (``slope_test="joint_index"``: to b_J ± 1.96 s_J alone); a viscosity that
   falls keeps the points' yield-stress verdict until the joint yield test (3) decides. The confidence is the
   share of replicates b* ~ N(b, s²) that the rule puts in the same class (Φ the standard normal CDF, z' = b/s):
   Φ(1.96 − z') − Φ(−1.96 − z') newtonian, 1 − Φ(1.96 − z') rising, Φ(−1.96 − z') falling. On the 5 mm grid the
   points read five liquids' slopes 0.09-0.16 low and the joint index erred by −0.01 to +0.06, about 0.15 above
   the points each time (z = 2-7), the truth between them on four; the index's own interval, ±0.015-0.02 with
   σ_m per window, did not hold its error, nor the points' interval theirs (docs/accuracy.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import stats

from ..fitting import Z95, schwarz_weights
from ..rheology import FlowCurve, fit_flow_curve, has_yield_stress

CLASSES = ("newtonian", "shear_thinning", "shear_thickening", "yield_stress")
#: 95 % point of the ½χ²₀ + ½χ²₁ mixture: the χ²₁ 90 % point.
YIELD_CRITICAL = float(stats.chi2.ppf(0.90, 1))
#: Fewest speeds for the Herschel-Bulkley test (three parameters, one degree of freedom left).
MIN_POINTS_YIELD_TEST = 4
#: A joint fit's yield stress counts when its share of the slowest stress exceeds this many σ_m (module docstring).
YIELD_SHARE_SIGMAS = 2.0


@dataclass(frozen=True)
class Slope:
    """d ln η / d ln γ̇ [1] by weighted least squares: ``value``, ``std`` (Birge-scaled), ``ci95``, ``intercept``
    ln η at γ̇ = 1 1/s, ``chi2`` of the line with the given σ, ``birge`` B [1]."""

    value: float
    std: float
    intercept: float
    chi2: float
    birge: float

    @property
    def ci95(self) -> tuple[float, float]:
        return self.value - Z95 * self.std, self.value + Z95 * self.std


@dataclass(frozen=True)
class SlopeEstimate:
    """A read of the slope d ln η / d ln γ̇ [1], ``value``, with its standard error ``std`` [1] and what it was
    read from (``source``): the joint power law's n − 1, or that combined with the points' slope (module
    docstring, 4)."""

    value: float
    std: float
    source: str = "joint power law index (n - 1)"

    @property
    def ci95(self) -> tuple[float, float]:
        return self.value - Z95 * self.std, self.value + Z95 * self.std

    def shares(self) -> dict[str, float]:
        """The probabilities that a replicate b* ~ N(value, std²) is called newtonian, rising and falling."""
        z = self.value / self.std
        return {"newtonian": float(stats.norm.cdf(Z95 - z) - stats.norm.cdf(-Z95 - z)),
                "rising": float(stats.norm.sf(Z95 - z)), "falling": float(stats.norm.cdf(-Z95 - z))}


@dataclass(frozen=True)
class JointYieldTest:
    """The joint fit's evidence for a yield stress: ``weight`` W, the Schwarz weight of the laws with a material
    one [0-1], and the best law with (``best_yield``) and without (``best_other``) a yield stress with
    ``delta_bic`` = BIC(best_other) − BIC(best_yield), positive where the yield stress is preferred;
    ``yield_shares`` each yield law's τ_y / τ(γ̇_min) [1] and ``min_share`` [1] the share that counts as material
    (module docstring, 3)."""

    weight: float
    best_yield: str
    best_other: str
    delta_bic: float
    yield_shares: dict[str, float] | None = None
    min_share: float = 0.0

    def summary(self) -> dict:
        return {"weight": self.weight, "best_yield": self.best_yield, "best_other": self.best_other,
                "delta_bic": self.delta_bic, "yield_shares": self.yield_shares, "min_share": self.min_share}


@dataclass(frozen=True)
class Classification:
    """The class, its ``confidence`` [0-1], the points' slope, the yield-stress test statistic Λ (None with fewer
    than four speeds or a viscosity that does not fall), the Herschel-Bulkley fit's parameters, the share of
    replicates in each class (``shares``), the joint fit's yield test when it decided (``joint``), and the slope
    estimate that decided the slope test in the points' place (``estimate``)."""

    label: str
    confidence: float
    slope: Slope
    yield_statistic: float | None
    herschel_bulkley: dict | None
    replicates: int
    shares: dict[str, float]
    joint: JointYieldTest | None = None
    estimate: SlopeEstimate | None = None
    laws: dict | None = None

    def with_slope_estimate(self, estimate: SlopeEstimate | None) -> "Classification":
        """The class with the slope test decided by ``estimate`` (module docstring, 4); unchanged without one or
        where its error is not finite and > 0 (a slope the readings do not see)."""
        if estimate is None or not (math.isfinite(estimate.value) and math.isfinite(estimate.std)
                                    and estimate.std > 0):
            return self
        lo, hi = estimate.ci95
        falling = "yield_stress" if self.label == "yield_stress" else "shear_thinning"
        label = "shear_thickening" if lo > 0 else "newtonian" if hi >= 0 else falling
        p = estimate.shares()
        shares = {"newtonian": p["newtonian"], "shear_thinning": p["falling"] if falling == "shear_thinning" else 0.0,
                  "shear_thickening": p["rising"], "yield_stress": p["falling"] if falling == "yield_stress" else 0.0}
        return replace(self, label=label, confidence=shares[label], shares=shares, estimate=estimate)

    def with_joint_yield_test(self, test: JointYieldTest | None) -> "Classification":
        """The class with the yield stress decided by the joint fit's ``test`` (module docstring, 3); unchanged
        without one or for a viscosity that rises."""
        if test is None or self.label == "shear_thickening":
            return self
        if test.weight > 0.5:
            label, confidence = "yield_stress", (1.0 - self.shares["shear_thickening"]) * test.weight
        else:
            label = "shear_thinning" if self.label == "yield_stress" else self.label
            falls = self.shares["shear_thinning"] + self.shares["yield_stress"]
            confidence = (falls if label == "shear_thinning" else self.shares[label]) * (1.0 - test.weight)
        return replace(self, label=label, confidence=confidence, joint=test)

    def with_law_families(self, families: dict[str, str], bics: dict[str, float]) -> "Classification":
        """The class of the law with the lowest BIC among laws fitted to the points (``families``: each law's class
        over the probed shear rates, ``fitting.law_family``), its confidence the Schwarz weight of the laws of
        that class, w_j = exp(−BIC_j/2) / Σ_l exp(−BIC_l/2) (``behaviour.flow_laws``)."""
        weights = schwarz_weights(bics)
        shares = {label: sum(w for name, w in weights.items() if families[name] == label) for label in CLASSES}
        label = families[min(bics, key=bics.get)]
        laws = {"families": dict(families), "weights": weights, "class_weights": shares}
        return replace(self, label=label, confidence=shares[label], laws=laws)

    def summary(self) -> dict:
        if self.laws is not None:
            return {**self._slope_summary(), "laws": self.laws,
                    "method": "the class of the law the points select by BIC over the probed shear rates "
                              "(fitting.family); confidence: the Schwarz weight of the laws of that class"}
        return self._slope_summary()

    def _slope_summary(self) -> dict:
        slope = self.slope if self.estimate is None else self.estimate
        return {"class": self.label, "confidence": self.confidence, "slope": slope.value,
                "slope_ci95": list(slope.ci95), "slope_std": slope.std,
                "slope_source": "points" if self.estimate is None else self.estimate.source,
                "points_slope": {"value": self.slope.value, "ci95": list(self.slope.ci95), "std": self.slope.std},
                "birge_ratio": self.slope.birge,
                "yield_test": {"statistic": self.yield_statistic, "critical": YIELD_CRITICAL,
                               "herschel_bulkley": self.herschel_bulkley,
                               "joint": None if self.joint is None else self.joint.summary()},
                "bootstrap_replicates": self.replicates, "bootstrap_shares": self.shares,
                "method": ("slope of ln eta vs ln shear rate (weighted, Birge-scaled, 95 %)" if self.estimate is None
                           else f"slope from the {self.estimate.source} (95 %)") + "; yield stress: the "
                          + ("Schwarz weight of the joint fit's yield-stress laws above 1/2" if self.joint else
                             "slope interval holds -1 or Herschel-Bulkley beats the power law (likelihood ratio, "
                             "95 %)")}


def decide(points: Classification, index: SlopeEstimate | None, yield_test: JointYieldTest | None,
           slope_test: str) -> Classification:
    """The class of the points' ``classify`` result with the slope test read as ``slope_test`` says (``"points"``,
    ``"joint_index"``: the joint power law's ``index`` alone, ``"combined"``: it and the points combined, the
    points alone without an index) and the yield stress decided by the joint fit's ``yield_test`` (module
    docstring, 3 and 4)."""
    if slope_test == "joint_index":
        points = points.with_slope_estimate(index)
    elif slope_test == "combined" and index is not None:
        points = points.with_slope_estimate(combined_slope(points.slope, index))
    return points.with_joint_yield_test(yield_test)


def combined_slope(points: Slope, index: SlopeEstimate) -> SlopeEstimate:
    """The inverse-variance mean of the points' slope and the joint power law's, its standard error scaled by
    S = max(1, |z|) where the two disagree (module docstring, 4)."""
    weights = np.array([points.std, index.std]) ** -2.0
    value = float(weights @ [points.value, index.value] / weights.sum())
    scale = max(1.0, abs(slope_agreement(points, index)["z"]))
    return SlopeEstimate(value, scale / math.sqrt(weights.sum()),
                         f"points and joint power law index combined (scale factor {scale:.2f})")


def slope_agreement(points: Slope, index: SlopeEstimate) -> dict:
    """The points' slope and the joint power law's, their difference d = b_index − b_points [1] in units of
    sqrt(s_points² + s_index²) (``z``), and whether they agree at the 95 % level (|z| ≤ 1.96): two reads of one
    slope through the same simulator, whose disagreement is model error that neither interval holds."""
    difference = index.value - points.value
    z = difference / math.hypot(points.std, index.std)
    return {"points_slope": points.value, "joint_index_slope": index.value, "joint_index_ci95": list(index.ci95),
            "difference": difference, "z": z, "agree": bool(abs(z) <= Z95)}


def joint_yield_test(bics: dict[str, float], yield_shares: dict[str, float] | None = None,
                     min_share: float = 0.0) -> JointYieldTest | None:
    """The Schwarz weight of the laws with a yield stress (``rheology.has_yield_stress``) among the finite ``bics``
    of a joint fit, by law name (module docstring, 3); None unless laws with and without one were both fitted.
    With ``yield_shares`` (τ_y / τ(γ̇_min) [1] by yield law), a law whose share is below ``min_share`` [1] counts
    as one without a yield stress."""
    finite = {name: b for name, b in bics.items() if math.isfinite(b)}
    with_yield = {name: b for name, b in finite.items() if has_yield_stress(name)}
    others = {name: b for name, b in finite.items() if not has_yield_stress(name)}
    if not with_yield or not others:
        return None
    shares = yield_shares or {}
    material = [name for name in with_yield if shares.get(name, math.inf) >= min_share]
    weights = schwarz_weights(finite)
    best_yield, best_other = min(with_yield, key=with_yield.get), min(others, key=others.get)
    return JointYieldTest(weight=sum(weights[n] for n in material),
                          best_yield=best_yield, best_other=best_other,
                          delta_bic=others[best_other] - with_yield[best_yield],
                          yield_shares=None if yield_shares is None else {n: float(shares[n]) for n in with_yield},
                          min_share=float(min_share))


def log_slope(shear_rate: np.ndarray, viscosity: np.ndarray, log_std: np.ndarray) -> Slope:
    """The weighted slope of ln η [Pa·s] on ln γ̇ [1/s] with standard errors ``log_std`` of ln η (module
    docstring)."""
    x, y, w = _checked(shear_rate, viscosity, log_std)
    xm, ym = np.average(x, weights=w), np.average(y, weights=w)
    sxx = float(np.sum(w * (x - xm) ** 2))
    if not sxx > 0:
        raise ValueError("behaviour: all windows have the same effective shear rate; stir at two speeds or more")
    b = float(np.sum(w * (x - xm) * (y - ym)) / sxx)
    a = ym - b * xm
    chi2 = float(np.sum(w * (y - a - b * x) ** 2))
    birge = math.sqrt(max(1.0, chi2 / (len(x) - 2))) if len(x) > 2 else 1.0
    return Slope(value=b, std=birge / math.sqrt(sxx), intercept=float(a), chi2=chi2, birge=birge)


def classify(shear_rate, viscosity, log_std, *, replicates: int = 200, seed: int = 0) -> Classification:
    """The behaviour class of points (γ̇_i [1/s], η_i [Pa·s], σ_i of ln η_i) with its bootstrap confidence from
    ``replicates`` replicates drawn with ``seed`` (module docstring)."""
    g = np.asarray(shear_rate, dtype=np.float64)
    eta = np.asarray(viscosity, dtype=np.float64)
    sigma = np.asarray(log_std, dtype=np.float64)
    label, slope, statistic, hb = _decide(g, eta, sigma)
    scale = min(slope.birge, hb["birge_ratio"]) if hb else slope.birge  # the better description's scatter
    rng = np.random.default_rng(seed)
    labels = [_decide(g, eta * np.exp(scale * sigma * rng.normal(size=g.size)), sigma)[0] for _ in range(replicates)]
    shares = {c: labels.count(c) / replicates if replicates else math.nan for c in CLASSES}
    return Classification(label, shares[label], slope, statistic, hb, replicates, shares)


def _decide(g: np.ndarray, eta: np.ndarray, sigma: np.ndarray) -> tuple[str, Slope, float | None, dict | None]:
    slope = log_slope(g, eta, sigma)
    lo, hi = slope.ci95
    if lo <= 0.0 <= hi:
        return "newtonian", slope, None, None
    if lo > 0.0:
        return "shear_thickening", slope, None, None
    statistic, hb = _yield_test(g, eta, sigma, slope) if g.size >= MIN_POINTS_YIELD_TEST else (None, None)
    if lo <= -1.0 or (statistic is not None and statistic > YIELD_CRITICAL):
        return "yield_stress", slope, statistic, hb
    return "shear_thinning", slope, statistic, hb


def _yield_test(g: np.ndarray, eta: np.ndarray, sigma: np.ndarray, slope: Slope) -> tuple[float, dict]:
    """Λ = (χ²_PL − χ²_HB) / B_HB² for the Herschel-Bulkley law against the power law, in ln η with weights
    1/σ²; the power law's χ² is the slope's."""
    w = 1.0 / sigma**2
    fit = fit_flow_curve("herschel_bulkley", FlowCurve(g, eta * g), weights=w / w.max())
    chi2 = float(np.sum(w * fit.residuals**2))
    birge2 = max(1.0, chi2 / (g.size - 3))
    return max(slope.chi2 - chi2, 0.0) / birge2, {"params": fit.params, "units": fit.units,
                                                    "ci95": {k: list(v) for k, v in fit.ci95.items()},
                                                    "birge_ratio": math.sqrt(birge2)}


def _checked(shear_rate, viscosity, log_std) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    g, eta, s = (np.asarray(v, dtype=np.float64).ravel() for v in (shear_rate, viscosity, log_std))
    if not g.size == eta.size == s.size:
        raise ValueError(f"behaviour: {g.size} shear rates, {eta.size} viscosities and {s.size} standard errors; "
                         "expected one of each per speed")
    if g.size < 2:
        raise ValueError(f"behaviour: {g.size} speed window(s); classifying needs at least two speeds")
    for name, values, unit in (("shear rate", g, "1/s"), ("viscosity", eta, "Pa s"), ("log_std", s, "1")):
        if not (np.all(np.isfinite(values)) and np.all(values > 0)):
            raise ValueError(f"behaviour: every {name} must be finite and > 0 ({unit}); got {values.tolist()}")
    return np.log(g), np.log(eta), 1.0 / s**2
