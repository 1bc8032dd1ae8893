"""Choosing the law: the paper's lowest loss, and two guards against over-fitting.

* ``loss``: the lowest paper loss (mean |ΔF| [N]) on the fitted samples, as the paper does; a law with more
  parameters never loses on this, so it alone over-fits.
* ``bic``: the Bayesian information criterion of a Gaussian residual model with N_eff effective samples,
  BIC = N_eff ln(RSS/N) + k ln N_eff, which charges each parameter ln N_eff.
* ``holdout``: the lowest paper loss on the held-out samples, which the fit never saw.

Whatever the criterion, the report gives the BIC margin of the best law over the runner-up and its strength on
Kass and Raftery's (1995) scale of 2 ln B ≈ ΔBIC: under 2 not worth more than a bare mention, 2-6 positive, 6-10
strong, over 10 very strong. A margin under 2 means the recording does not tell the two laws apart.

Laws that fit the same force can still disagree on the apparent viscosity, where their slice corrections or shapes
differ. The reported interval therefore holds the selection's uncertainty: it is the 95 % interval of the mixture of
the laws' log-normal estimates weighted by their BIC evidence (``bic_weights``, ``averaged_interval``), a law ruled
out very strongly (ΔBIC > 10) weighing nothing. With one law in it, it is that law's interval.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import brentq
from scipy.stats import norm

from .uncertainty import Z95

CRITERIA = ("bic", "holdout", "loss")

#: Kass and Raftery's scale: the weakest ΔBIC of each grade of evidence.
EVIDENCE = ((10.0, "very strong"), (6.0, "strong"), (2.0, "positive"), (0.0, "weak"))

#: ΔBIC over the best law beyond which the evidence against a law is very strong: it gets no weight.
RULED_OUT_DELTA_BIC = 10.0


def bic(residuals: np.ndarray, n_params: int, n_effective: float) -> float:
    """N_eff ln(RSS / N) + k ln N_eff for fitted-sample ``residuals`` [N]."""
    return bic_of_rss(float(residuals @ residuals), len(residuals), n_params, n_effective)


def bic_of_rss(rss: float, n_samples: int, n_params: int, n_effective: float) -> float:
    """N_eff ln(RSS / N) + k ln N_eff for a residual sum of squares ``rss`` [N²] over ``n_samples`` samples."""
    return n_effective * math.log(max(rss / n_samples, 1e-300)) + n_params * math.log(n_effective)


def rank(scores: dict[str, float]) -> list[str]:
    """Names ordered from best (lowest score) to worst; NaN scores last."""
    return sorted(scores, key=lambda k: (math.isnan(scores[k]), scores[k]))


def select(losses: dict[str, float], bics: dict[str, float], holdout: dict[str, float | None],
           criterion: str = "bic") -> dict:
    """The selected law by ``criterion`` and the ranking under every criterion."""
    if criterion not in CRITERIA:
        raise ValueError(f"fit.selection = {criterion!r}; expected one of {CRITERIA}")
    rankings = {"loss": rank(losses), "bic": rank(bics)}
    if all(v is not None for v in holdout.values()):
        rankings["holdout"] = rank({k: float(v) for k, v in holdout.items()})
    elif criterion == "holdout":
        raise ValueError("fit.selection = 'holdout' needs held-out samples; set fit.holdout_fraction > 0")
    return {"criterion": criterion, "selected": rankings[criterion][0], "lowest_loss": rankings["loss"][0],
            "rankings": rankings, "bic_margin": bic_margin(bics)}


def bic_margin(bics: dict[str, float]) -> dict | None:
    """ΔBIC of the best law by BIC over the runner-up, and its grade of evidence (``EVIDENCE``); None with fewer
    than two finite BICs."""
    ordered = [name for name in rank(bics) if math.isfinite(bics[name])]
    if len(ordered) < 2:
        return None
    margin = bics[ordered[1]] - bics[ordered[0]]
    grade = next(label for bound, label in EVIDENCE if margin >= bound)
    return {"best": ordered[0], "runner_up": ordered[1], "delta_bic": margin, "evidence": grade}


def schwarz_weights(bics: dict[str, float]) -> dict[str, float]:
    """Each law's probability given the data, equal priors, by Schwarz's approximation of the evidence:
    w_k = exp(−BIC_k / 2) / Σ_l exp(−BIC_l / 2) [1] over finite ``bics``."""
    best = min(bics.values())
    raw = {name: math.exp(-(b - best) / 2.0) for name, b in bics.items()}
    total = sum(raw.values())
    return {name: w / total for name, w in raw.items()}


def bic_weights(bics: dict[str, float]) -> dict[str, float]:
    """The laws' probabilities given the recording (``schwarz_weights``) among those within ``RULED_OUT_DELTA_BIC``
    of the best; a law further above it, or with no finite BIC, gets 0."""
    finite = {name: b for name, b in bics.items() if math.isfinite(b)}
    if not finite:
        return {name: 0.0 for name in bics}
    best = min(finite.values())
    weights = schwarz_weights({name: b for name, b in finite.items() if b - best <= RULED_OUT_DELTA_BIC})
    return {name: weights.get(name, 0.0) for name in bics}


def averaged_interval(estimates: dict[str, tuple[float, float, float]], weights: dict[str, float],
                      z: float = Z95) -> tuple[float, float]:
    """The central 95 % interval [lower, upper] of Σ_k p_k LogNormal(ln η_k, s_k²), the laws' estimates
    ``estimates`` {name: (η_k, lower_k, upper_k)} (each a central 95 % interval, s_k = ln(upper_k / lower_k) / (2z))
    weighted by ``weights`` p_k. A law whose interval is open ([0, ∞)) carries half its weight to each end, so the
    interval is open where that weight exceeds the 5 % outside it (bound 0 or inf)."""
    mus, sigmas, ps = [], [], []
    for name, (value, lower, upper) in estimates.items():
        p = weights.get(name, 0.0)
        if p <= 0.0:
            continue
        mus.append(math.log(value))
        sigmas.append(math.log(upper / lower) / (2.0 * z) if lower > 0.0 and math.isfinite(upper) else math.inf)
        ps.append(p)
    mu, sigma, p = np.array(mus), np.array(sigmas), np.array(ps) / sum(ps)

    def cdf(x: float) -> float:
        with np.errstate(invalid="ignore"):
            standard = np.where(np.isfinite(sigma), (x - mu) / sigma, 0.0)
        return float(p @ norm.cdf(standard))

    finite = np.isfinite(sigma)
    spread = float(np.max(np.where(finite, sigma, 0.0))) + 1.0
    low_end, high_end = float(mu.min()) - 12.0 * spread, float(mu.max()) + 12.0 * spread
    tail = float(norm.sf(z))  # 2.5 % each side
    lower = 0.0 if cdf(low_end) >= tail else math.exp(brentq(lambda x: cdf(x) - tail, low_end, high_end))
    upper = math.inf if cdf(high_end) <= 1.0 - tail else math.exp(brentq(lambda x: cdf(x) - (1.0 - tail),
                                                                           low_end, high_end))
    return lower, upper
