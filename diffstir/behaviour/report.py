"""The behaviour's report.md and plots (``Behaviour.report``, ``Behaviour.plots``): ``viscosity_vs_speed.png``
(the paper's Fig. 5, with 95 % error bars) and ``flow_curve.png`` (η against the effective shear rate with the
points' slope line and the laws fitted to all speeds)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..fitting import log_viscosity_interval
from ..plots import pyplot, save_figure, viscosity_band
from ..report_files import format_param
from .flow_laws import FlowCurveLaws


def markdown(summary: dict) -> str:
    """report.md of a behaviour's ``summary`` (``Behaviour.summary``)."""
    b = summary["behaviour"]
    lo, hi = b["slope_ci95"]
    lines = [f"# Behaviour: **{b['class']}** (confidence {b['confidence']:.2f})", "",
             f"- slope d ln η / d ln γ̇ = {b['slope']:.3f} (95 % CI {lo:.3f} to {hi:.3f}; from the "
             f"{b['slope_source']})",
             f"- the per-speed points' slope {b['points_slope']['value']:.3f} (95 % CI "
             f"{b['points_slope']['ci95'][0]:.3f} to {b['points_slope']['ci95'][1]:.3f}; Birge ratio "
             f"{b['birge_ratio']:.2f})",
             f"- density {summary['density']['value']:.1f} kg/m³ ({summary['density']['source']})"]
    if b.get("laws") is not None:
        weights = ", ".join(f"{label} {w:.3f}" for label, w in b["laws"]["class_weights"].items() if w > 5e-4)
        lines.insert(2, f"- class of the law the points select by BIC ({summary['joint_fit']['selected']}); Schwarz "
                        f"weight of each class: {weights}")
    check = b.get("slope_check")
    if check is not None:
        verdict = ("they agree" if check["agree"] else "they disagree beyond both intervals: the simulator's error "
                   "between speeds exceeds its stated force error")
        lines.append(f"- the joint power law's slope n − 1 = {check['joint_index_slope']:.3f} (95 % CI "
                     f"{check['joint_index_ci95'][0]:.3f} to {check['joint_index_ci95'][1]:.3f}), "
                     f"{check['z']:+.1f} σ from the points' slope; {verdict}")
    if b["yield_test"]["statistic"] is not None:
        lines.append(f"- yield-stress test on the points: Λ = {b['yield_test']['statistic']:.2f} (critical "
                     f"{b['yield_test']['critical']:.2f})")
    joint_test = b["yield_test"]["joint"]
    if joint_test is not None:
        lines.append(f"- yield stress by the joint fit: weight of the yield-stress laws {joint_test['weight']:.3f} "
                     f"(decides above 0.5); {joint_test['best_yield']} against {joint_test['best_other']}, "
                     f"ΔBIC {joint_test['delta_bic']:+.1f}")
        if joint_test["yield_shares"] is not None:
            shares = ", ".join(f"{name} {share:.1%}" for name, share in joint_test["yield_shares"].items())
            lines.append(f"  - yield stress's share of the slowest stress: {shares} (counts from "
                         f"{joint_test['min_share']:.1%}, twice the simulator's force error)")
    lines += [f"- Metzner-Otto constant k_s = {summary['metzner_otto']['value']:.3g} (γ̇_eff = k_s U / a)", "",
              "| window | speed [m/s] | γ̇_eff [1/s] (measured) | η [Pa·s] (95 % CI) | classified |",
              "|---|---|---|---|---|"]
    for p in summary["points"]:
        lines.append(f"| {p['window']} | {p['speed']:.4g} | {p['shear_rate']:.3g} ({p['measured_shear_rate']:.3g}) | "
                     f"{p['viscosity']:.4g} ({p['viscosity_ci95'][0]:.4g}-{p['viscosity_ci95'][1]:.4g}) | "
                     f"{_classified(p)} |")
    joint = summary["joint_fit"]
    if joint:
        points = joint.get("fitted_to") == "points"
        title = "Laws fitted to the points' flow curve" if points else "Joint fit over all speeds"
        lines += ["", f"{title}, selected by BIC: **{joint['selected']}**", "",
                  f"| law | {'χ²' if points else 'loss [N]'} | BIC | parameters (95 % CI) |", "|---|---|---|---|"]
        for name, law in joint["laws"].items():
            params = "; ".join(format_param(k, v, law["units"][k], law["ci95"][k]) for k, v in law["params"].items())
            misfit = f"{law['chi2']:.3g}" if points else f"{law['loss']:.4g}"
            lines.append(f"| {name} | {misfit} | {law['bic']:.1f} | {params} |")
    return "\n".join(lines) + "\n"


def _classified(point: dict) -> str:
    """Whether a window's point is classified, and why not: read at the simulator's viscosity cap (at least that
    thick), or not resolved by the sensor."""
    if point["classified"]:
        return "yes"
    return "no: at the viscosity cap" if point.get("capped") else "no: not resolved"


def plot_all(result, out: Path) -> dict[str, Path]:
    """viscosity_vs_speed.png and flow_curve.png of the ``Behaviour`` ``result`` in ``out``."""
    plt = pyplot()
    points = result.points
    speed = np.array([p.speed for p in points])
    eta = np.array([p.viscosity for p in points])
    lo, hi = np.array([p.ci95 for p in points]).T
    rate = result.shear_rates(points)
    cls = result.classification
    paths = {}

    fig, ax = plt.subplots(figsize=(5.5, 4), constrained_layout=True)
    order = np.argsort(speed)
    ax.errorbar(speed[order], 1e3 * eta[order], yerr=1e3 * np.array([eta - lo, hi - eta])[:, order], fmt="o-",
                capsize=3, label=f"{cls.label} ({cls.confidence:.2f})")
    ax.set_xlabel("stirring speed [m/s]")
    ax.set_ylabel("apparent viscosity [mPa·s]")
    ax.legend(fontsize=8)
    paths["viscosity_vs_speed"] = save_figure(fig, out / "viscosity_vs_speed.png")

    fig, ax = plt.subplots(figsize=(6, 4.2), constrained_layout=True)
    ax.errorbar(rate, eta, yerr=[eta - lo, hi - eta], fmt="ko", capsize=3, label="per speed (95 %)")
    grid = np.logspace(np.log10(rate.min()) - 0.3, np.log10(rate.max()) + 0.3, 100)
    ax.loglog(grid, np.exp(cls.slope.intercept) * grid**cls.slope.value, "k:",
              label=f"points' slope {cls.slope.value:.2f} [{cls.slope.ci95[0]:.2f}, {cls.slope.ci95[1]:.2f}]")
    if result.joint is not None:
        for name, fit in result.joint.fits.items():
            kind = "points' fit" if isinstance(result.joint, FlowCurveLaws) else "joint fit"
            label = f"{name} ({kind})" + (" *" if name == result.joint.selected else "")
            band = log_viscosity_interval(fit.model, fit.theta, result.joint.uncertainty[name].covariance, grid)
            viscosity_band(ax, grid, *band, label, 0.12)
    ax.set_xlabel("effective shear rate [1/s]")
    ax.set_ylabel("apparent viscosity [Pa·s]")
    ax.legend(fontsize=7)
    paths["flow_curve"] = save_figure(fig, out / "flow_curve.png")
    return paths
