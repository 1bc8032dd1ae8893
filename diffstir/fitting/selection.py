"""Choosing the law: the paper's lowest loss, and two guards against over-fitting.

* ``loss``: the lowest paper loss (mean |ΔF| [N]) on the fitted samples, as the paper does; a law with more
  parameters never loses on this, so it alone over-fits.
* ``bic``: the Bayesian information criterion of a Gaussian residual model with N_eff effective samples,
  BIC = N_eff ln(RSS/N) + k ln N_eff, which charges each parameter ln N_eff.
* ``holdout``: the lowest paper loss on the held-out samples, which the fit never saw.

Whatever the criterion, the report gives the BIC margin of the best law over the runner-up and its strength on
Kass and Raftery's (1995) scale of 2 ln B ≈ ΔBIC: under 2 not worth more than a bare mention, 2-6 positive, 6-10
strong, over 10 very strong. A margin under 2 means the recording does not tell the two laws apart.
"""

from __future__ import annotations

import math

import numpy as np

CRITERIA = ("bic", "holdout", "loss")

#: Kass and Raftery's scale: the weakest ΔBIC of each grade of evidence.
EVIDENCE = ((10.0, "very strong"), (6.0, "strong"), (2.0, "positive"), (0.0, "weak"))


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
