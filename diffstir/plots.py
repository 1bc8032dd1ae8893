"""Figures and tables of simulation results (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_forces(result, law, out: Path) -> tuple[Path, Path]:
    """Write the force on the rod over time as ``force.csv`` and ``force.png`` in ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
    png = out / "force.png"
    fig.savefig(png, dpi=120)
    plt.close(fig)
    return csv, png
