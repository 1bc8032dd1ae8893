"""The diagnosis's diagnosis.md and plots (``Diagnosis.report``, ``Diagnosis.plots``): ``residual.png``, where the
mismatch is; ``before_after.png``, measured versus simulated before and after modelling the effect;
``candidates.png``, each candidate's score."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..plots import pyplot, save_figure
from ..report_files import format_param

PHASE_COLOURS = {"start-up": "tab:green", "speed change": "tab:orange", "reversal": "tab:purple", "stop": "0.75"}


def markdown(summary: dict) -> str:
    """A human-readable diagnosis of ``summary`` (see :meth:`Diagnosis.summary`)."""
    loc, base, refit = summary["location"], summary["base"], summary["refit"]
    lines = [f"# Diagnosis of {summary['recording']}", "", f"**Verdict: {summary['verdict']}.** {summary['sentence']}",
             "", "## Where the mismatch is", "",
             f"Base: {base['law']} {', '.join(f'{k} = {v:.4g}' for k, v in base['params'].items())} "
             f"({base['source']}); residual rms {loc['rms_over_noise']:.2f} × the noise ({loc['noise']:.3g} N); "
             f"transient time 2a/U = {loc['transient_time']:.2f} s.", "",
             "| phase | seconds | rms residual / noise | mean residual [N] |", "|---|---|---|---|"]
    for phase, row in loc["phases"].items():
        lines.append(f"| {phase} | {row['seconds']:.2f} | {row['rms_over_noise']:.2f} | {row['mean']:.3g} |")
    regime = ", ".join(f"{k} {v:+.2f}" for k, v in loc["regime"].items())
    freq = loc["frequency"]
    lines += ["", f"Worst phase: {loc['worst_phase']}. Correlation of the residual with {regime}.",
              f"Stirring frequency {freq['stirring_frequency']:.3g} Hz; residual variance at its harmonics "
              f"1/2/3: {freq['harmonic_1']:.0%}/{freq['harmonic_2']:.0%}/{freq['harmonic_3']:.0%}; measured reading "
              f"lags the simulated one by {1e3 * freq['lag']:.0f} ms.",
              "Suspicious windows (running rms above 2σ): " + (", ".join(
                  f"{w['start']:.2f}-{w['end']:.2f} s ({w['phase']}, {w['rms']:.3g} N)" for w in loc["windows"])
                  or "none") + ".", "", "## Candidates", "",
              "| effect | score ΔBIC | probability | loss before [N] | loss after [N] | parameters (95 % CI) "
              "| simulations |",
              "|---|---|---|---|---|---|---|"]
    for row in summary["ranking"]:
        if row.get("score") is None:
            lines.append(f"| {row['effect']} | - | - | - | - | not fitted: {row['note']} | 0 |")
            continue
        params = "; ".join(format_param(k, v, row["units"][k], row["ci95"][k]) for k, v in row["params"].items())
        if row.get("warning"):
            params += f" (**{row['warning']}**)"
        lines.append(f"| {row['effect']} | {row['score']:.1f} | {row['probability']:.2f} | {row['loss_before']:.4g} "
                     f"| {row['loss_after']:.4g} | {params} | {row['simulations']} |")
    after = refit["fluid_after"]
    lines += ["", "## The fit with the effect modelled", "",
              f"Refit with **{refit['effect']}**: loss {refit['loss_before']:.4g} N → {refit['loss_after']:.4g} N.",
              f"Fluid before: {refit['fluid_before']['name']} "
              + ", ".join(f"{k} = {v:.4g}" for k, v in refit["fluid_before"]["params"].items())
              + f"; after: {after.get('name', '-')} "
              + ", ".join(f"{k} = {v:.4g} {after['units'][k]}" for k, v in after.get("params", {}).items()) + ".",
              "", f"Compared {summary['window']['start']:.3g}-{summary['window']['end']:.3g} s; simulation "
              f"{summary['simulation']['dim']}-D, dx = {summary['simulation']['dx']} m; {summary['simulations']} "
              f"simulations, {summary['seconds']:.0f} s.", ""]
    return "\n".join(lines)


def plot_all(diag, out: Path) -> dict[str, Path]:
    """residual.png, before_after.png and candidates.png of the ``Diagnosis`` ``diag`` in ``out``."""
    plt = pyplot()
    t, measured = diag.problem.times, diag.problem.measured
    loc, none, refit = diag.location, diag.fits["none"], diag.refit
    paths = {}

    fig, axes = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True, constrained_layout=True)
    label = loc["_label"]
    for ax in axes:
        for phase, colour in PHASE_COLOURS.items():
            mask = (label == phase).astype(int)
            edges = np.flatnonzero(np.diff(np.concatenate([[0], mask, [0]])))
            for k, (a, b) in enumerate(zip(edges[::2], edges[1::2])):
                ax.axvspan(t[a], t[b - 1], color=colour, alpha=0.15, lw=0, label=phase if k == 0 and ax is axes[0]
                           else None)
    axes[0].plot(t, measured, color="0.4", lw=0.7, label="measured")
    axes[0].plot(t, diag.base.predicted, lw=1.0, label=f"fitted {diag.base.law.name}")
    axes[0].set_ylabel("reading [N]")
    axes[0].legend(fontsize=7, ncol=3, loc="upper right")
    residual = loc["_residual"]
    axes[1].plot(t, residual, color="k", lw=0.7)
    axes[1].axhspan(-2 * loc["noise"], 2 * loc["noise"], color="tab:blue", alpha=0.15, label="±2σ noise")
    for w in loc["windows"]:
        axes[1].axvspan(w["start"], w["end"], color="tab:red", alpha=0.25, lw=0)
    axes[1].set_ylabel("residual [N]")
    axes[1].set_xlabel("time [s] (shaded red: suspicious windows)")
    axes[1].legend(fontsize=7, loc="upper right")
    paths["residual"] = save_figure(fig, out / "residual.png")

    fig, axes = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True, constrained_layout=True)
    axes[0].plot(t, measured, color="0.4", lw=0.7, label="measured")
    axes[0].plot(t, none.predicted, lw=1.0, label=f"before: base law (loss {none.loss:.3g} N)")
    axes[0].plot(t, refit.predicted, lw=1.0, label=f"after: {refit.name} (loss {refit.loss:.3g} N)")
    axes[0].set_ylabel("reading [N]")
    axes[0].legend(fontsize=7, loc="upper right")
    axes[1].plot(t, measured - none.predicted, lw=0.7, label="before")
    axes[1].plot(t, measured - refit.predicted, lw=0.7, label="after")
    axes[1].set_ylabel("residual [N]")
    axes[1].set_xlabel("time [s]")
    axes[1].legend(fontsize=7, loc="upper right")
    paths["before_after"] = save_figure(fig, out / "before_after.png")

    scored = [r for r in diag.ranking if r.get("score") is not None]
    fig, ax = plt.subplots(figsize=(6, 0.35 * len(scored) + 1.2), constrained_layout=True)
    ax.barh([r["effect"] for r in scored][::-1], [r["score"] for r in scored][::-1], color="tab:blue")
    ax.axvline(-diag.evidence["thresholds"]["evidence"], color="k", ls=":", lw=0.8)
    ax.set_xlabel("score: BIC − BIC(none) (dotted: an effect is named left of it)")
    paths["candidates"] = save_figure(fig, out / "candidates.png")
    return paths
