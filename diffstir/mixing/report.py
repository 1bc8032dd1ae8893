"""The mixing analysis's report.md and plot (``Mixing.report``, ``Mixing.plots``): ``time_course.png``, the
viscosity's time course with its 95 % band, the fitted approach, the time to homogeneity and the Lederer-Roegiers
range."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..plots import pyplot, save_figure
from ..report_files import format_bound
from ..rheology.blending import blend_range


def markdown(summary: dict) -> str:
    """report.md of a mixing analysis's ``summary`` (``Mixing.summary``)."""
    m = summary["mixing"]
    rule = m["lederer_roegiers"]
    (eta1, eta2), (low, high) = rule["viscosities"], rule["range"]
    homogeneous = m["homogeneity_time_ci95"]
    alpha = rule["implied_alpha"]
    lines = [f"# Mixing: blend {m['blend_viscosity']:.4g} Pa·s, homogeneous after {m['homogeneity_time']:.3g} s", "",
             f"- blend viscosity (the course's plateau): {m['blend_viscosity']:.4g} Pa·s (95 % CI "
             f"{format_bound(m['blend_viscosity_ci95'][0])}-{format_bound(m['blend_viscosity_ci95'][1])})",
             f"- time to homogeneity: {m['homogeneity_time']:.3g} s"
             + (f" (95 % CI {homogeneous[0]:.3g}-{homogeneous[1]:.3g} s)" if homogeneous else
                " (no interval: the course's time constant is not resolved)"),
             f"- Lederer-Roegiers range of {eta1:.4g} and {eta2:.4g} Pa·s at volume fraction {rule['fraction']:.3g} "
             f"of the first: {low:.4g}-{high:.4g} Pa·s (α from 1 to 0); the blend lies "
             + ("inside" if rule["blend_in_range"] else "**outside**") + " it"
             + ("" if alpha is None else f"; implied α = {alpha:.3g}"),
             f"- density {summary['density']['value']:.1f} kg/m³ ({summary['density']['source']}); "
             f"{summary['seconds']:.0f} s", "",
             "| window | time [s] | speed [m/s] | η [Pa·s] (95 % CI) |", "|---|---|---|---|"]
    for p in m["time_course"]:
        lines.append(f"| {p['window']} | {p['time']:.3g} | {p['speed']:.4g} | {p['viscosity']:.4g} "
                     f"({format_bound(p['viscosity_ci95'][0])}-{format_bound(p['viscosity_ci95'][1])}) |")
    return "\n".join(lines) + "\n"


def plot_all(result, out: Path) -> dict[str, Path]:
    """time_course.png of the ``Mixing`` ``result`` in ``out``: η(t) with its 95 % band, the fitted approach, the
    time to homogeneity and the Lederer-Roegiers range."""
    plt = pyplot()
    t = result.times
    eta = np.array([p.viscosity for p in result.points])
    lo, hi = np.array([p.ci95 for p in result.points]).T
    low, high = blend_range(*result.viscosities, result.fraction)
    fig, ax = plt.subplots(figsize=(6, 4), constrained_layout=True)
    ax.axhspan(low, high, color="tab:green", alpha=0.12, label="Lederer-Roegiers, α ∈ [0, 1]")
    ax.fill_between(t, lo, hi, color="tab:blue", alpha=0.2, label="95 % band")
    ax.plot(t, eta, "o", color="tab:blue", label="apparent viscosity per window")
    dense = np.linspace(t[0], t[-1], 200)
    ax.plot(dense, result.approach.curve(dense), "k-", lw=1, label="exponential approach")
    ax.axvline(result.approach.homogeneity_time, color="k", ls=":", lw=0.8, label="homogeneous")
    if result.approach.homogeneity_interval:
        ax.axvspan(*result.approach.homogeneity_interval, color="k", alpha=0.08, label="its 95 % interval")
    ax.set_yscale("log")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("apparent viscosity [Pa·s]")
    ax.legend(fontsize=7)
    return {"time_course": save_figure(fig, out / "time_course.png")}
