"""The virtual lab's 3-D truth: the stir in the real cup by finite elements, not by the fitting simulator.

``FiniteElementTruth`` (``lab/sim=fe3d``) sets the discretisation; ``fe_stir_force`` runs
``diffstir.lab.stokes3d.stir_history`` (Navier-Stokes in the frame turning with the rod, Taylor-Hood tetrahedra,
SBDF2 in time) for a fluid stirred along a programme on a circle, and returns the horizontal force on the rod in the
lab [N]. It shares no code with the MPM simulator, so a fit to its recordings meets the simulator's own errors and
the 2-D slice's (docs/accuracy.md). Its limits: the free surface is a flat lid (no gravity waves, no meniscus), the
rod moves on a circle about the cup's axis without spinning or moving vertically, and the fluid is a
generalized-Newtonian law (hidden physics and blends need an MPM truth). Needs the ``validation`` extra
(scikit-fem, gmsh, pyamg).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from diffstir.errors import ConfigError, is_number
from diffstir.lab.fluid import Fluid
from diffstir.rig import Rig
from diffstir.trajectory import Trajectory

ON_CIRCLE = 1e-6
"""The largest relative spread of the rod's distance from the cup's axis over a programme the 3-D truth accepts."""


@dataclass(frozen=True)
class FiniteElementTruth:
    """The 3-D truth's discretisation: tetrahedra of ``cell`` [m] at the rod growing to ``growth`` × cell 2a away,
    and time steps of ``dt`` [s]."""

    cell: float = 0.005
    growth: float = 3.0
    dt: float = 0.002

    def __post_init__(self) -> None:
        checks = (("cell", self.cell, 5e-4, 0.02, "m"), ("growth", self.growth, 1.0, 10.0, "1 (far cells / near)"),
                  ("dt", self.dt, 1e-5, 0.02, "s"))
        for name, value, lo, hi, unit in checks:
            if not (is_number(value) and lo <= value <= hi):
                raise ConfigError(f"lab.sim.{name} = {value!r}; expected {lo} to {hi} {unit}")

    def times(self, trajectory: Trajectory) -> np.ndarray:
        """The truth's times [s]: steps of ``dt`` from the trajectory's first sample to its last."""
        steps = int(math.floor((trajectory.t[-1] - trajectory.t[0]) / self.dt + 1e-9))
        return trajectory.t[0] + self.dt * np.arange(steps + 1)

    def numerics(self) -> dict:
        """What the truth's force depends on besides the fluid, the rig and the stir, for records that must say
        which simulator made them (a rectifier's training pairs)."""
        return {"kind": "fe3d", "cell": self.cell, "growth": self.growth, "dt": self.dt}


def circle_motion(trajectory: Trajectory, times: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """The circle's radius e [m] and the rod's angle θ [rad], rate Ω [rad/s] and Ω' [rad/s²] at ``times`` [s]
    (a cubic spline through the trajectory's unwrapped angles). Raises ConfigError for a rod that leaves its circle,
    spins, moves vertically or does not start at rest."""
    radius = np.hypot(trajectory.xy[:, 0], trajectory.xy[:, 1])
    orbit = float(radius.mean())
    if orbit <= 0 or np.ptp(radius) > ON_CIRCLE * orbit:
        raise ConfigError(f"lab/programme: the rod's distance from the cup's axis spans {radius.min():.6g} to "
                          f"{radius.max():.6g} m; the 3-D truth (lab/sim=fe3d) needs a circle of fixed radius > 0 m")
    if np.ptp(trajectory.z) > 0 or np.ptp(trajectory.angle) > 0:
        raise ConfigError("lab/programme: the rod moves vertically or spins; the 3-D truth (lab/sim=fe3d) stirs on a "
                          "circle only")
    spline = CubicSpline(trajectory.t, np.unwrap(np.arctan2(trajectory.xy[:, 1], trajectory.xy[:, 0])))
    rate = spline(times, 1)
    if abs(rate[0]) * orbit > 1e-6:
        raise ConfigError(f"lab/programme: the rod starts at {abs(rate[0]) * orbit:.3g} m/s; the 3-D truth "
                          f"(lab/sim=fe3d) starts from rest (a programme ramps up from 0 m/s)")
    return orbit, spline(times), rate, spline(times, 2)


@dataclass
class FiniteElementStir:
    """The 3-D truth's force on the rod in the lab [N] (S, 2) at ``times`` [s] (S,), and its discretisation."""

    times: np.ndarray
    force: np.ndarray
    dt: float
    discretisation: dict


def fe_stir_force(fluid: Fluid, trajectory: Trajectory, rig: Rig, config: FiniteElementTruth) -> FiniteElementStir:
    """The horizontal force [N] of ``fluid`` on the rod stirred along ``trajectory`` in ``rig``, from rest, on
    steps of ``config.dt`` from the trajectory's first sample to its last."""
    try:
        from diffstir.lab import stokes3d
    except ImportError as error:
        raise ConfigError(f"lab/sim=fe3d needs the validation extra ({error.name} is missing): "
                          f"pip install -e '.[validation]'") from None
    times = config.times(trajectory)
    orbit, angle, rate, acceleration = circle_motion(trajectory, times)
    cup = stokes3d.CupRig.of(rig, orbit)
    if orbit + cup.rod_radius >= cup.cup_radius or cup.gap <= 0:
        raise ConfigError(f"rig: the rod (radius {cup.rod_radius} m on a circle of {orbit} m, tip {cup.gap} m above "
                          f"the bottom) must lie inside the cup (radius {cup.cup_radius} m, fill {cup.fill} m)")
    rig_mesh = stokes3d.build_mesh(cup, config.cell, growth=config.growth)
    law = fluid.make_law()
    if fluid.law.get("name") == "newtonian":  # a constant viscosity: one factorisation for the whole run
        law = float(law.parameters_si()["eta"])
    history = stokes3d.stir_history(rig_mesh, law, times, angle, rate, acceleration, density=fluid.density)
    discretisation = {"method": "finite elements, Taylor-Hood P2/P1 tetrahedra, SBDF2 (diffstir.lab.stokes3d)",
                      "tetrahedra": int(rig_mesh.mesh.t.shape[1]), "velocity_dofs": history.n_velocity,
                      "pressure_dofs": history.n_pressure, "factorisations": history.factorisations,
                      "seconds": history.seconds, "peak_memory_gib": history.memory_gib}
    return FiniteElementStir(times, history.force[:, :2], config.dt, discretisation)
