"""Figures and tables of simulation results (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def pyplot():
    """matplotlib.pyplot on the headless Agg backend (imported on first use: plotting is optional work)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: Path) -> Path:
    """Save ``fig`` to ``path`` at the project's resolution and release it."""
    fig.savefig(path, dpi=120)
    pyplot().close(fig)
    return path


def viscosity_band(ax, rates: np.ndarray, eta: np.ndarray, lower: np.ndarray, upper: np.ndarray, label: str,
                   alpha: float = 0.15) -> None:
    """A flow curve η(γ̇) [Pa·s] over ``rates`` [1/s] on log axes, with its 95 % band [``lower``, ``upper``]
    [Pa·s] where finite (``fitting.log_viscosity_interval``)."""
    line, = ax.loglog(rates, eta, label=label)
    finite = np.isfinite(upper)
    ax.fill_between(rates[finite], lower[finite], upper[finite], color=line.get_color(), alpha=alpha)


def plot_forces(result, law, out: Path) -> tuple[Path, Path]:
    """Write the force on the rod over time as ``force.csv`` and ``force.png`` in ``out``."""
    plt = pyplot()
    t = result.times.detach().cpu().numpy()
    force = result.force.detach().cpu().numpy()
    unit = "N/m" if result.per_unit_length else "N"
    names = ["force_x", "force_y", "force_z"][: force.shape[1]]
    csv = out / "force.csv"
    header = "# force of the fluid on the rod, " + ("per unit length of rod, " if result.per_unit_length else "")
    header += f"law {law!r}\nt," + ",".join(names)
    np.savetxt(csv, np.column_stack([t, force]), delimiter=",", header=header, comments="", fmt="%.9g")
    fig, ax = plt.subplots(figsize=(7, 3.5), constrained_layout=True)
    for k, name in enumerate(names):
        ax.plot(t, force[:, k], lw=0.8, label=name)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"force on the rod [{unit}]")
    ax.set_title(repr(law), fontsize=8)
    ax.legend()
    return csv, save_figure(fig, out / "force.png")
