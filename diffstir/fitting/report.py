"""The identification's report.md and plots (``Identification.report``, ``Identification.plots``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..plots import pyplot, save_figure, viscosity_band
from ..report_files import format_bound, format_param
from .uncertainty import log_viscosity_interval


def markdown(summary: dict) -> str:
    """report.md of an identification's ``summary`` (``Identification.summary``)."""
    sel = summary["selected"]
    av = summary["apparent_viscosity"]
    d = summary["density"]
    ci = (f" (95 % CI {d['ci95'][0]:.1f}-{d['ci95'][1]:.1f}, uncertainty from {d.get('uncertainty_source')})"
          if d["ci95"] else "")
    lines = [f"# Identification of {summary['recording']}", "",
             f"- density: {d['value']:.1f} kg/m³{ci}, from {d['source']}",
             f"- selected law: **{sel}** by {summary['selection']['criterion']}; lowest paper loss: "
             f"{summary['selection']['lowest_loss']}{_margin(summary['selection'].get('bic_margin'))}",
             f"- effective shear rate of the stir: {av['effective_shear_rate']:.3g} 1/s; probed band "
             f"{summary['shear_rate_range'][0]:.3g}-{summary['shear_rate_range'][1]:.3g} 1/s",
             f"- apparent viscosity at the effective shear rate: {av['at_effective_shear_rate']:.4g} Pa·s "
             f"(95 % CI {av['at_effective_shear_rate_ci95'][0]:.4g}-{av['at_effective_shear_rate_ci95'][1]:.4g}"
             f"{_averaged(av)}); at zero shear: {av['zero_shear']:.4g} Pa·s"]
    family = summary["family"]
    if family is not None:
        lo, hi = family["slope_ci95"]
        lines.append(f"- over the probed band the selected law is **{family['class'].replace('_', '-')}**: "
                     f"d ln η / d ln γ̇ = {family['slope']:.3g} (95 % CI {format_bound(lo)} to {format_bound(hi)})")
    sensor = summary["laws"].get(sel, summary.get("baseline") or {}).get("sensor") or {}
    if any(k != "units" for k in sensor):
        lines.append("- sensor nuisances fitted with it: " + ", ".join(
            f"{k} {v:.3g} {sensor['units'][k]}" for k, v in sensor.items() if k != "units"))
    pre, refined = summary["preliminary"], av["refined"]
    lines.append(f"- preliminary (Newtonian ladder, {pre['estimator']['dim']}-D dx = {pre['estimator']['dx']} m) "
                 f"viscosity: {pre['viscosity']:.4g} Pa·s at a mean stirring speed of "
                 f"{pre['mean_stirring_speed']:.3g} m/s")
    if refined is not None:
        value = "-" if refined["value"] is None else f"{refined['value']:.4g} Pa·s"
        lines.append(f"- learned sim-to-real rectifier: {value} ({refined['note']})")
    correction = summary.get("slice_correction")
    if correction is not None:
        where = "inside" if correction["inside_study"] else "**outside** (clamped, σ widened)"
        lines.append(f"- 2-D slice read as the cup's rod: F = F' h C, C = {correction['factor']:.4g} "
                     f"± {100 * correction['sigma']:.2g} % (1σ) at flow index {correction['flow_index']:.3g}, "
                     f"Re {correction['reynolds']:.3g}; the rig lies {where} the 3-D study's ranges")
    elif summary.get("force_scale", "").startswith("F' h ("):
        lines.append("- 2-D slice read as F = F' h (fit.slice_correction=false): the paper's extruded slice, without "
                     "the cup's tip, bottom and free surface")
    dead = summary["dead_start"]
    if dead["detected"]:
        lines.append(f"- the sensor reads one value until {dead['until_s']:.3g} s while the rod moves (a dead start): "
                     "the fit window starts there, the simulation at the first sample")
    if not summary["resolvable"]["viscosity"]:
        lines.append("- **not identifiable** from the waveform: doubling the viscosity changes the reading by "
                     f"{summary['resolvable']['reading_change_per_doubling']:.3g} N rms, below the noise "
                     f"({summary['resolvable']['noise']:.3g} N); the fitted numbers are not measurements")
    if summary["resolvable"].get("inertia_dominated"):
        inertial = summary.get("simulation", {}).get("inertial_force_error", 0.0)
        lines.append(f"- **inertia-dominated** stir: the part of the reading that scales with the viscosity is "
                     f"{100 * summary['resolvable']['viscous_share']:.0f} % of it, so a relative error of the "
                     "simulated force's inertial part moves the viscosity by about that error times the inertial "
                     "over the viscous share; the intervals hold it "
                     + (f"(fit.inertial_error, {100 * inertial:.0f} % of the inertial part) and are wide for that "
                        "reason" if inertial > 0 else "not (fit.inertial_error = 0) and are too narrow for such a "
                        "stir")
                     + "; " + _slower_stir(summary["resolvable"]))
    magnitude = summary.get("magnitude")
    if magnitude is not None:
        lo, hi = magnitude["ci95"]
        lines.append(f"- Newtonian viscosity from the reading's size (mean |reading| "
                     f"{magnitude['mean_abs_reading']:.3g} N): {magnitude['viscosity']:.4g} Pa·s "
                     f"(95 % CI {format_bound(lo)}-{format_bound(hi)})"
                     + ("" if magnitude["resolved"] else "; **not resolved**: the size of the reading does not fix "
                        "the viscosity within a factor 2"))
    lines += ["", "| law | loss [N] | held-out loss [N] | BIC | parameters (95 % CI) |", "|---|---|---|---|---|"]
    rows = dict(summary["laws"])
    if summary.get("baseline"):
        rows["corotated (baseline)"] = summary["baseline"]
    for name, law in rows.items():
        params = "; ".join(format_param(k, v, law["units"][k], law["ci95"][k]) for k, v in law["params"].items())
        holdout = "-" if law["holdout_loss"] is None else f"{law['holdout_loss']:.4g}"
        lines.append(f"| {name} | {law['loss']:.4g} | {holdout} | {law['bic']:.1f} | {params} |")
    lines += ["", "Rankings: " + "; ".join(f"{k}: {', '.join(v)}" for k, v in
                                             summary["selection"]["rankings"].items()),
              f"Fitted {summary['windows']['start']:.3g}-{summary['windows']['split']:.3g} s, held out "
              f"{summary['windows']['split']:.3g}-{summary['windows']['end']:.3g} s; simulation "
              f"{summary['simulation']['dim']}-D, dx = {summary['simulation']['dx']} m; {summary['seconds']:.0f} s.",
              ""]
    return "\n".join(lines)


def plot_all(result, out: Path) -> dict[str, Path]:
    """forces.png (measured versus simulated readings per law), flow_curves.png (each law's flow curve with its
    95 % band) and losses.png (each fit's loss per simulation) of the ``Identification`` ``result`` in ``out``."""
    plt = pyplot()
    problem = result.problem
    paths = {}
    fig, axes = plt.subplots(len(result.fits), 1, figsize=(8, 1.8 * len(result.fits) + 0.6), sharex=True,
                             constrained_layout=True, squeeze=False)
    for ax, (name, fit) in zip(axes[:, 0], result.fits.items()):
        ax.plot(problem.times, problem.measured, color="0.6", lw=0.7, label="measured")
        ax.plot(problem.times, fit.predicted, lw=1.0, label=f"{name} (loss {fit.loss:.3g} N)")
        ax.axvline(problem.windows.split, color="k", ls=":", lw=0.8)
        ax.set_ylabel("reading [N]")
        ax.legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("time [s] (dotted: start of the held-out part)")
    paths["forces"] = save_figure(fig, out / "forces.png")

    lo, hi = result.probed_shear_rates()
    rates = np.logspace(np.log10(lo) - 2, np.log10(hi) + 2, 120)
    fig, ax = plt.subplots(figsize=(6, 4.2), constrained_layout=True)
    ax.axvspan(lo, hi, color="0.9", label="probed by the stir")
    for name, fit in result.fits.items():
        band = log_viscosity_interval(fit.model, fit.theta, result.uncertainty[name].covariance, rates)
        viscosity_band(ax, rates, *band, name)
    ax.axvline(result.effective_shear_rate, color="k", ls=":", lw=0.8)
    ax.set_xlabel("shear rate [1/s] (dotted: effective)")
    ax.set_ylabel("apparent viscosity [Pa·s]")
    ax.legend(fontsize=7)
    paths["flow_curves"] = save_figure(fig, out / "flow_curves.png")

    fig, ax = plt.subplots(figsize=(6, 3.5), constrained_layout=True)
    for name, fit in result.fits.items():
        if fit.history:
            ax.semilogy([h["evaluation"] for h in fit.history], [h["loss"] for h in fit.history], "o-", ms=3,
                        label=name)
    ax.set_xlabel("forward simulations")
    ax.set_ylabel("paper loss mean |ΔF| [N]")
    ax.legend(fontsize=7)
    paths["losses"] = save_figure(fig, out / "losses.png")
    return paths


def _averaged(apparent: dict) -> str:
    """Where more than one law weighs in the apparent viscosity's interval, a clause naming their BIC weights."""
    weights = apparent.get("law_weights") or {}
    if len(weights) < 2:
        return ""
    lo, hi = apparent["selected_law_ci95"]
    listed = ", ".join(f"{name} {w:.2f}" for name, w in sorted(weights.items(), key=lambda kv: -kv[1]))
    return f", the laws weighted by their BIC evidence: {listed}; the selected law alone {lo:.4g}-{hi:.4g}"


def _margin(margin: dict | None) -> str:
    """The BIC margin of the best law over the runner-up, as a clause of the selection line."""
    if margin is None:
        return ""
    return (f"; BIC margin of {margin['best']} over {margin['runner_up']}: {margin['delta_bic']:.1f} "
            f"({margin['evidence']} evidence)")


def _slower_stir(resolvable: dict) -> str:
    """The report's advice for an inertia-dominated stir: the slower mean speed at which the viscous part would be
    half the reading (F_v ∝ U, F_i ∝ U²), and whether the sensor would still resolve the viscosity there."""
    speed = resolvable.get("viscous_speed")
    if speed is None:
        return "stir slower (a lower Reynolds number) to measure a thin fluid"
    change = resolvable["viscous_speed_change_per_doubling"]
    advice = (f"stir slower to measure a thin fluid: at a mean speed of {speed:.2g} m/s or less the viscous part "
              f"would be half the reading or more (F_v ∝ U, F_i ∝ U²), and doubling η would change the reading by "
              f"about {change:.2g} N rms")
    if resolvable["viscous_speed_resolves"]:
        return advice
    return advice + (f", below the noise and the sensor's resolution ({resolvable['floor']:.2g} N): a sensor "
                     "with a finer resolution or less noise is needed to measure this fluid by stirring")
