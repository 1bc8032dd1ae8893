"""Compare the simulator with closed-form solutions and an independent reference; print markdown (docs/validation.md).

    python scripts/validate_simulator.py [--checks couette power_law translate buoyancy2d convergence rest3d stir
                                                   stir_convergence stir_sound_speed stir_history
                                                   stir_drift stir_timestep inertial_error
                                                   numerical_viscosity]
        [--rest-time 8] [--reference-dir DIR] [--numerics LABEL ...] [--set KEY=VALUE ...]

Every 2-D check runs the fit's fine stage (conf/sim/slice2d.yaml: 2.5 mm cells, an incompressible pressure,
"projection", sim.pressure=projection, diffstir/mpm/projection.py, a FLIP share of 0.95, the cells' fill relaxed
over 50 ms) and, for comparison, the same slice with a weakly compressible pressure ("compressible": the sound
speed raised per rollout to 3 % compression from 1 m/s, J relaxed towards the grid's packing), the numerics it
replaced on 2026-11-24 ("former": APIC transfers, each particle's J from its own divergence, a fixed 1 m/s), and
the compressible slice with boundary particles carrying the fluid's pressure into the solids ("wall pressure",
sim.wall_pressure=true, diffstir/mpm/walls.py); the stir check also the compressible slice at 1 % and 0.3 %
compression; "implicit" is the projection with the shear stress solved implicitly (sim.viscous_solver=implicit,
diffstir/mpm/implicit_viscosity.py). --numerics runs only the numerics whose labels start with the given words;
--set KEY=VALUE sets SimConfig fields on each of them (e.g. dt_max=0.004 for a longer step).
- couette: rod spinning at the cup's centre, 2-D, mu = 1 Pa s, Omega = 2 rad/s (Re = 0.75); steady torque per unit
  length against 4 pi mu Omega a^2 b^2 / (b^2 - a^2).
- power_law: the same with a power-law fluid, K = 1 Pa s^n, n = 0.6, Omega = 1 rad/s (Re = 0.6 at the rod), against
  2 pi K a^2 [2 Omega / (n (1 - (a/b)^(2/n)))]^n.
- translate: rod translating through the cup's centre at Re = rho U 2a / mu = 0.1 (mu = 0.5, 1 and 3 Pa s), 2 mm
  either side of it; steady force per unit length against 4 pi mu U / [ln(b/a) - (b^2 - a^2)/(b^2 + a^2)].
- thick: the translating rod at U = 20 mm/s in 1, 20 and 100 Pa s fluids, the viscosity cap raised to the fluid's,
  projection and implicit only (not run by default): the explicit shear stress's step shortens with the viscosity,
  the implicit one's does not; each row says the step, its substeps and the wall time.
- buoyancy2d: the rod held still 15 mm off centre under a body force of 1 m/s² along x (standing in for gravity,
  which a horizontal slice lacks); steady force per unit length against -rho g pi a^2 (a sound speed of 2 m/s).
- convergence: the Newtonian and power-law Couette checks and the 0.5 and 1 Pa s translating rod, projection and
  compressible, on 5, 2.5, 2, 1.67 and 1.25 mm cells (not run by default).
- rest3d: the paper's 3-D scene at rest (8 s, the paper's recording length): the fluid's volume by its particles'
  J (sum J V0), the height of its centre of mass (at rest neither may change), and the vertical force against
  rho g V_immersed.
- stir: the paper's stir (the rod on a 15 mm circle at 0.1 m/s, 0.5 s ramp, 1.5 s) in 2-D at eta = 0.05, 0.2, 1 and
  3 Pa s against the incompressible finite-element reference of scripts/stir_reference.py (computed once into
  --reference-dir, 1-5 minutes per viscosity; needs scikit-fem). Printed per run: the drag (the force against the
  rod's motion) and the radial force averaged from 0.9 s, their deviation from the reference, the rms deviation of
  the whole force vector from 0.3 s (the simulator's force smoothed over 20 ms) and the rms of what the smoothing
  removed, both over the reference's rms force, and the sound speed and number of steps (not run by default).
- stir_convergence: the stir at 1 Pa s with the compressible numerics on 2.5, 1.67 and 1.25 mm cells, at 3 % and 1 %
  compression and with the projection: how much of the stir's deviation is the grid's (not run by default).
- numerical_viscosity: the viscosity [m^2/s] at which the transfers alone damp an 8-cell shear wave in an inviscid
  fluid (tests/problems.py), with the projection at time steps of 2, 1, 0.5, 0.25 and 0.1 ms and the compressible
  pressure at 1, 0.25, 0.1 and 0.06 ms, with and without the FLIP share (not run by default).
- stir_sound_speed: the stir at 1 Pa s with the compressible numerics at fixed sound speeds of 2, 4, 8 and 16 m/s
  (not run by default).
- stir_drift: the stir at 0.2 Pa s held for 4 s (against a 4 s reference), the compressible and the projection with
  the fill relaxed over 50 ms, 0.5 s and not at all: the drag per second and how evenly the particles fill the
  cup at the end (not run by default).
- stir_timestep: the stir with the projection at several time steps, each with the transfers' numerical viscosity
  ν_num at its step (as numerical_viscosity measures it): at 0.1 Pa s (Re = 25) at 4, 2, 1, 0.5 and 0.25 ms, on
  1.67 mm cells, and simulated at η − ρ ν_num at 1 and 0.5 ms; at 0.05, 1 and 3 Pa s at 4, 2 and 1 ms. The drag,
  the radial force and the fluid's angular momentum against the reference's (not run by default; 0.05 Pa s's
  reference takes a few minutes).
- inertial_error: how far the fine stage's force is off in the part that does not scale with the viscosity, the
  stir's inertial part, at 0.05, 0.1 and 0.2 Pa s (Re = 50, 25, 12.5), the step the config gives. The reference's
  force F(t) = V(t) + I(t) with its viscous part V = dF / d ln η (from the reference at 1.1 η) and its inertial part
  I = F − V; the simulated force's deviation D = F_sim − F: drag and radial force from 0.9 s (D / I per component),
  and the rms of |D| over the rms of |I| from 0.3 s, both components together (all of D counted against I, the
  viscous part's own error included). The rms of the last over the three viscosities is the inertial force error
  σ_i of diffstir.fitting.uncertainty.INERTIAL_FORCE_ERROR (not run by default; the references take minutes).
- stir_history: the stir at 1 Pa s (compressible, at 1 % compression, without FLIP, and with J relaxed over 10 ms) in
  time windows: the drag and radial force against the reference's, and the particles next to the rod (within half
  a cell and from half a cell to one cell of its surface, per area, over the resting fluid's), and the fluid's
  angular momentum about the cup's axis at the end (not run by default).

Runs with one intra-op thread: the simulator's tensors are small, and on a shared 2-core machine two threads made
every step many times slower (docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import platform
import sys
import time
from functools import partial
from pathlib import Path

import torch
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from problems import (couette_torque_newtonian, couette_torque_power_law, fitting_default,  # noqa: E402
                      numerical_viscosity, rod_in_pressure_gradient, translating_rod_force)

import numpy as np  # noqa: E402

from diffstir.mpm import SimConfig, StirringSimulator  # noqa: E402
from diffstir.mpm.boundaries import RodPose  # noqa: E402
from diffstir.mpm.packing import deposit  # noqa: E402
from diffstir.mpm.step import node_fill  # noqa: E402
from diffstir.rheology import Newtonian, PowerLaw  # noqa: E402
from diffstir.rig import Rig  # noqa: E402
from diffstir.trajectory import circle, spin, stationary, translate  # noqa: E402

RIG = Rig()
A, B = RIG.rod.radius, RIG.cup.radius
STIR_SPEED = 0.1  # m/s, the paper's stir on a 15 mm circle
COMPRESSIBLE = fitting_default().replace(pressure="compressible")
FORMER = COMPRESSIBLE.replace(flip=0.0, volume_relaxation=0.0, settle_time=0.0, compressibility=None, sound_speed=1.0)
PROJECTION = fitting_default()
WALL_PRESSURE = COMPRESSIBLE.replace(wall_pressure=True)
IMPLICIT = PROJECTION.replace(viscous_solver="implicit")
CONFIGS = {"compressible": COMPRESSIBLE, "former": FORMER, "projection": PROJECTION, "wall pressure": WALL_PRESSURE,
           "implicit": IMPLICIT}
STIR_CONFIGS = {"compressible": COMPRESSIBLE, "compressible at 1 %": COMPRESSIBLE.replace(compressibility=0.01),
                "compressible at 0.3 %": COMPRESSIBLE.replace(compressibility=0.003), "former": FORMER,
                "projection": PROJECTION, "wall pressure": WALL_PRESSURE}
STIR_SOUND_SPEEDS = {f"compressible, c = {c:g} m/s": COMPRESSIBLE.replace(compressibility=None, sound_speed=c)
                     for c in (2.0, 4.0, 8.0, 16.0)}  # m/s
STIR_VISCOSITIES = (0.05, 0.2, 1.0, 3.0)  # Pa s
DRIFT_CONFIGS = {"compressible": COMPRESSIBLE, **{f"projection{'' if tau == 0.05 else f', relaxation {tau:g} s'}":
                                        PROJECTION.replace(volume_relaxation=tau) for tau in (0.05, 0.5, 0.0)}}
HISTORY_CONFIGS = {"compressible": COMPRESSIBLE, "compressible at 1 %": COMPRESSIBLE.replace(compressibility=0.01),
                   "compressible, APIC (flip 0)": COMPRESSIBLE.replace(flip=0.0),
                   "compressible, relaxation 10 ms": COMPRESSIBLE.replace(volume_relaxation=0.01)}
STIR_CONVERGENCE = {f"{label}, dx = {dx * 1e3:.3g} mm": COMPRESSIBLE.replace(dx=dx, **changes)
                    for dx in (0.0025, 0.005 / 3, 0.00125)
                    for label, changes in (("compressible", {}), ("compressible at 1 %", {"compressibility": 0.01}),
                                           ("projection", {"pressure": "projection"}))}


def steady(values: torch.Tensor) -> float:
    """Mean over the last 30 % of a series."""
    return values[int(0.7 * len(values)):].mean().item()


def couette(config: SimConfig, label: str) -> tuple[str, float, float]:
    sim = StirringSimulator(Newtonian(eta=1.0), RIG, config, density=1000.0)
    with torch.no_grad():
        result = sim(spin(2.0, duration=0.6, ramp_time=0.1))
    return (f"Couette torque, 2-D, {label} [N]", -steady(result.torque), couette_torque_newtonian(1.0, 2.0, A, B))


def power_law_couette(config: SimConfig, label: str) -> tuple[str, float, float]:
    k, n, omega = 1.0, 0.6, 1.0
    sim = StirringSimulator(PowerLaw(k=k, n=n), RIG, config, density=1000.0)
    with torch.no_grad():
        result = sim(spin(omega, duration=0.6, ramp_time=0.1))
    return (f"power-law (n = {n}) Couette torque, 2-D, {label} [N]", -steady(result.torque),
            couette_torque_power_law(k, n, omega, A, B))


def buoyancy_2d(config: SimConfig, label: str, g: float = 1.0) -> tuple[str, float, float]:
    """The pressure part of the rod's reaction in 2-D (``problems.rod_in_pressure_gradient``)."""
    return (f"rod at rest under a body force of {g:g} m/s², 2-D, {label} [N/m]",
            float(rod_in_pressure_gradient(config, g)[0]), -1000.0 * g * math.pi * A**2)


def translating(config: SimConfig, label: str, mu: float = 1.0) -> tuple[str, float, float]:
    """The rod translating through the cup's centre at Re = ρ U 2a / μ = 0.1, 2 mm either side of it."""
    speed = 0.1 * mu / (1000.0 * 2 * A)
    sim = StirringSimulator(Newtonian(eta=mu), RIG, config, density=1000.0)
    with torch.no_grad():
        result = sim(translate((speed, 0.0), duration=0.004 / speed, start=(-0.002, 0.0)))
    return (f"translating rod drag, 2-D, {label}, mu = {mu:g} Pa s, U = {speed * 1e3:.3g} mm/s [N/m]",
            -steady(result.force[:, 0]), translating_rod_force(mu, speed, A, B))


def thick(config: SimConfig, label: str, mu: float, speed: float = 0.02) -> tuple[str, float, float]:
    """The rod translating through the cup's centre at ``speed`` [m/s] in a fluid of ``mu`` [Pa s], the viscosity cap
    raised to it where it is above; the label gives the step, its substeps and the wall time."""
    sim = StirringSimulator(Newtonian(eta=mu), RIG, config.replace(viscosity_cap=max(config.viscosity_cap, mu)),
                            density=1000.0)
    trajectory = translate((speed, 0.0), duration=0.004 / speed, start=(-0.002, 0.0))
    dt = sim.time_step(trajectory)
    clock = time.perf_counter()
    with torch.no_grad():
        result = sim(trajectory)
    return (f"translating rod drag, 2-D, {label}, mu = {mu:g} Pa s, U = {speed * 1e3:.3g} mm/s, "
            f"{dt * 1e3:.3g} ms step in {sim.substeps(trajectory, dt)}, {time.perf_counter() - clock:.1f} s [N/m]",
            -steady(result.force[:, 0]), translating_rod_force(mu, speed, A, B))


def rest3d(duration: float) -> list[tuple[str, float, float]]:
    rows = []
    for label, config in (("paper's numerics", SimConfig(dim=3, dx=0.01, sound_speed=4.5, cfl=0.45, flip=0.0,
                                                         volume_relaxation=0.0)),
                          ("default numerics", SimConfig(dim=3, dx=0.01, sound_speed=4.5, cfl=0.45))):
        sim = StirringSimulator(Newtonian(eta=0.1), RIG, config, density=1000.0)
        trajectory = stationary(duration)
        start = sim.initial_state(trajectory)
        with torch.no_grad():
            result = sim(trajectory, initial=start)
        volume = lambda s: (s.J.sum() * sim.scene.particle_volume).item()  # noqa: E731
        height = lambda s: s.x[:, 2].mean().item()  # noqa: E731
        buoyancy = 1000.0 * 9.81 * math.pi * A**2 * RIG.rod.immersion_depth
        rows += [(f"3-D rest (1 cm cells, {label}), fluid volume by J, sum J V0, after {duration:g} s / at start",
                  volume(result.state) / volume(start), 1.0),
                 (f"3-D rest (1 cm cells, {label}), centre of mass height after {duration:g} s / at start",
                  height(result.state) / height(start), 1.0),
                 (f"3-D rest (1 cm cells, {label}), vertical force on the rod [N] vs rho g V",
                  steady(result.force[:, 2]), buoyancy)]
    return rows


def stir_reference(viscosity: float, directory: Path, duration: float = 1.5) -> dict:
    """The finite-element reference of the paper's stir at ``viscosity`` [Pa s] for ``duration`` [s], computed once
    into ``directory``."""
    path = directory / (f"stir_{viscosity:g}.npz" if duration == 1.5 else f"stir_{viscosity:g}_{duration:g}s.npz")
    if not path.exists() or "angular_momentum" not in np.load(path):  # made before it was recorded
        from stir_reference import stir  # scripts/stir_reference.py; needs scikit-fem

        directory.mkdir(parents=True, exist_ok=True)
        np.savez(path, **stir(viscosity, duration=duration, step=0.0005 if viscosity < 0.1 else 0.002))
    return dict(np.load(path))


def stir_run(config: SimConfig, viscosity: float, reference: dict, simulated_viscosity: float | None = None) -> dict:
    """The paper's stir at ``viscosity`` [Pa s] (simulated with ``simulated_viscosity`` where given) against the
    ``reference``: drag and radial force [N/m] from 0.9 s and the reference's, the rms deviation and noise over the
    reference's rms force [1], the steps, the sound speed, the fluid's angular momentum about the cup's axis at
    the end over the reference's [1], and the smoothed radial and along-motion force [N/m] at the steps' times
    [s]."""
    trajectory = circle(radius=0.015, speed=STIR_SPEED, duration=1.5)
    sim = StirringSimulator(Newtonian(eta=simulated_viscosity or viscosity), RIG, config, density=1000.0)
    with torch.no_grad():
        result = sim(trajectory)
    t = result.times.double().numpy()
    radial, along = _orbit_components(trajectory, t, result.force.double().numpy())
    width = max(1, int(round(0.02 / result.dt)))
    kernel = np.ones(width) / width
    radial_s, along_s = (np.convolve(x, kernel, "same") for x in (radial, along))
    t_ref = reference["times"]
    window = (t_ref > 0.3) & (t_ref < 1.45)
    late = t_ref > 0.9
    scale = np.sqrt(np.mean(reference["radial"][window] ** 2 + reference["tangential"][window] ** 2))
    deviation = np.sqrt(np.mean((np.interp(t_ref[window], t, radial_s) - reference["radial"][window]) ** 2
                                + (np.interp(t_ref[window], t, along_s) - reference["tangential"][window]) ** 2))
    noise = np.sqrt(np.mean((along - along_s)[width:-width] ** 2 + (radial - radial_s)[width:-width] ** 2))
    return {"drag": -np.interp(t_ref[late], t, along_s).mean(), "drag_ref": -reference["tangential"][late].mean(),
            "radial": np.interp(t_ref[late], t, radial_s).mean(), "radial_ref": reference["radial"][late].mean(),
            "deviation": deviation / scale, "noise": noise / scale, "steps": len(t),
            "sound": f"{sim.sound_speed(trajectory):.2f}" if config.pressure == "compressible" else "none",
            "spin": angular_momentum(sim, result.state) / reference["angular_momentum"][-1],
            "times": t, "radial_history": radial_s, "along_history": along_s}


def angular_momentum(sim: StirringSimulator, state) -> float:
    """The 2-D fluid's angular momentum about the cup's axis, Σ m (x v_y − y v_x) [kg m²/s per m of rod]."""
    x, v = state.x.double(), state.v.double()
    return float(sim.scene.particle_mass * (x[:, 0] * v[:, 1] - x[:, 1] * v[:, 0]).sum())


def stir_row(config: SimConfig, label: str, viscosity: float, reference: dict) -> str:
    r = stir_run(config, viscosity, reference)
    return (f"| {viscosity:g} | {label} | {r['sound']} | {r['steps']} | {r['drag']:.4f} | {r['drag_ref']:.4f} | "
            f"{100 * (r['drag'] / r['drag_ref'] - 1):+.1f} % | {r['radial']:+.4f} | {r['radial_ref']:+.4f} | "
            f"{100 * r['deviation']:.1f} % | {100 * r['noise']:.1f} % |")


def stir_timestep(directory: Path, density: float = 1000.0) -> None:
    """The stir with the projection at several time steps: at 0.1 Pa s (Re = 25) from 4 to 0.25 ms, on 1.67 mm
    cells, and simulated at η − ρ ν_num (the viscosity the transfers' damping brings back to η) at 1 and 0.5 ms;
    at 0.05, 1 and 3 Pa s at 1, 2 and 4 ms. Each run with the transfers' numerical viscosity ν_num [m²/s] at its
    step (``numerical_viscosity``) and the fluid's density ``density`` [kg/m³]."""
    runs = ([(0.1, "projection", 0.0025, dt, False) for dt in (4e-3, 2e-3, 1e-3, 5e-4, 2.5e-4)]  # Pa s, m, s
            + [(0.1, "projection", 0.0025, dt, True) for dt in (1e-3, 5e-4)]
            + [(0.1, "projection, dx = 1.67 mm", 0.0025 / 1.5, 1e-3, False)]
            + [(eta, "projection", 0.0025, dt, False)
               for eta in (0.05, 1.0, 3.0) for dt in (4e-3, 2e-3, 1e-3)])
    print("\n| η [Pa·s] | numerics | Δt [ms] | ν_num [m²/s] | ρ ν_num / η | simulated η [Pa·s] | drag [N/m] | "
          "reference | deviation | radial [N/m] | reference | angular momentum / reference |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|")
    nu = {}
    for viscosity, label, dx, dt, compensated in runs:
        reference = stir_reference(viscosity, directory)
        config = PROJECTION.replace(dx=dx, dt=dt)
        if (dx, dt) not in nu:
            nu[dx, dt] = numerical_viscosity(config, None)
        simulated = viscosity - density * nu[dx, dt] if compensated else viscosity
        r, share = stir_run(config, viscosity, reference, simulated), density * nu[dx, dt] / viscosity
        print(f"| {viscosity:g} | {label} | {dt * 1e3:g} | {nu[dx, dt]:.2e} | {share:.3f} | {simulated:.4g} | "
              f"{r['drag']:.4f} | {r['drag_ref']:.4f} | {100 * (r['drag'] / r['drag_ref'] - 1):+.1f} % | "
              f"{r['radial']:+.4f} | {r['radial_ref']:+.4f} | {r['spin']:.3f} |", flush=True)


def inertial_error(directory: Path, config: SimConfig, viscosities: tuple[float, ...] = (0.05, 0.1, 0.2),
                   step: float = 1.1) -> None:
    """The simulated stir's deviation from the reference against the reference's inertial part I = F − dF/d ln η
    (the derivative from the reference at ``step`` × η), per viscosity [Pa s] (the module docstring)."""
    print("\n| η [Pa·s] | Re | component | reference [N/m] | viscous part dF/d ln η | inertial part | simulated | "
          "deviation / inertial part |\n|---|---|---|---|---|---|---|---|")
    ratios = []
    for viscosity in viscosities:
        reference, raised = stir_reference(viscosity, directory), stir_reference(step * viscosity, directory)
        r, reynolds = stir_run(config, viscosity, reference), 1000.0 * STIR_SPEED * 2 * A / viscosity  # ρ U 2a / η
        t_ref, t = reference["times"], r["times"]
        if not np.allclose(raised["times"], t_ref):
            raise RuntimeError(f"the references at {viscosity:g} and {step * viscosity:g} Pa s have other times")
        forces = {name: np.stack([reference[name], raised[name]]) for name in ("radial", "tangential")}
        viscous = {name: (f[1] - f[0]) / math.log(step) for name, f in forces.items()}
        inertial = {name: forces[name][0] - viscous[name] for name in forces}
        simulated = {"radial": np.interp(t_ref, t, r["radial_history"]),
                     "tangential": np.interp(t_ref, t, r["along_history"])}
        late, window = t_ref > 0.9, (t_ref > 0.3) & (t_ref < 1.45)
        for label, name, sign in (("drag", "tangential", -1.0), ("radial", "radial", 1.0)):
            i_late = sign * inertial[name][late].mean()
            deviation = sign * (simulated[name] - forces[name][0])[late].mean()
            print(f"| {viscosity:g} | {reynolds:.1f} | {label} | "
                  f"{sign * forces[name][0][late].mean():+.4f} | {sign * viscous[name][late].mean():+.4f} | "
                  f"{i_late:+.4f} | {sign * simulated[name][late].mean():+.4f} | {deviation / i_late:+.3f} |")
        deviation = np.hypot(*(simulated[n] - forces[n][0] for n in forces))[window]
        ratio = math.sqrt(np.mean(deviation**2) / np.mean(np.hypot(*inertial.values())[window] ** 2))
        ratios.append(ratio)
        print(f"| {viscosity:g} | | rms over 0.3-1.45 s, both | | | | | {ratio:.3f} |", flush=True)
    listed = ", ".join(f"{v:g}" for v in viscosities)
    print(f"\nσ_i, the rms over {listed} Pa s: {math.sqrt(np.mean(np.square(ratios))):.3f}")


def stir_history(directory: Path, viscosity: float = 1.0) -> None:
    reference = stir_reference(viscosity, directory)
    trajectory = circle(radius=0.015, speed=STIR_SPEED, duration=1.5)
    windows = ((0.1, 0.3), (0.3, 0.5), (0.5, 0.7), (0.7, 0.9), (0.9, 1.2), (1.2, 1.5))  # s
    print("\n| numerics | window [s] | drag [N/m] | reference | ratio | radial [N/m] | reference | "
          "particles within dx/2 of the rod | dx/2 to dx |\n|---|---|---|---|---|---|---|---|---|")
    spin_up = []
    for label, config in HISTORY_CONFIGS.items():
        sim = StirringSimulator(Newtonian(eta=viscosity), RIG, config, density=1000.0)
        every = max(1, int(round(0.01 / sim.time_step(trajectory))))  # a snapshot every 10 ms
        with torch.no_grad():
            result = sim(trajectory, snapshot_every=every)
        t = result.times.double().numpy()
        radial, along = _orbit_components(trajectory, t, result.force.double().numpy())
        shot_times = np.array(result.snapshot_times)
        centres, _, _ = trajectory.poses(shot_times)
        per_area = (config.particles_per_cell / config.dx) ** 2
        shells = []
        for x, centre in zip(result.snapshots, centres):
            r = np.hypot(*(x.double().numpy() - centre).T)
            shells.append([((r >= A + lo * config.dx) & (r < A + hi * config.dx)).sum()
                           / (math.pi * ((A + hi * config.dx) ** 2 - (A + lo * config.dx) ** 2) * per_area)
                           for lo, hi in ((0.0, 0.5), (0.5, 1.0))])
        shells = np.array(shells)
        spin_up.append((label, angular_momentum(sim, result.state)))
        for lo, hi in windows:
            m, mr, ms = ((x > lo) & (x <= hi) for x in (t, reference["times"], shot_times))
            drag, drag_ref = -along[m].mean(), -reference["tangential"][mr].mean()
            print(f"| {label} | {lo:g}-{hi:g} | {drag:.4f} | {drag_ref:.4f} | {drag / drag_ref:.3f} | "
                  f"{radial[m].mean():+.4f} | {reference['radial'][mr].mean():+.4f} | {shells[ms, 0].mean():.2f} | "
                  f"{shells[ms, 1].mean():.2f} |", flush=True)
    final = reference["angular_momentum"][-1]
    for label, value in spin_up:
        print(f"{label}: the fluid's angular momentum about the cup's axis at {trajectory.duration:g} s "
              f"{value:.4e} kg m²/s per m, reference {final:.4e} ({value / final:.3f})")


def stir_drift(directory: Path, configs: dict[str, SimConfig], viscosity: float = 0.2, duration: float = 4.0) -> None:
    """The stir held for ``duration`` [s]: the drag per second against the reference's, and how evenly the particles
    fill the cup (the rms of the nodes' fill φ − 1 and its least value, more than two cells inside the cup)."""
    reference = stir_reference(viscosity, directory, duration)
    trajectory = circle(radius=0.015, speed=STIR_SPEED, duration=duration)
    windows = [(lo, lo + 1.0) for lo in np.arange(0.0, duration, 1.0)]
    print(f"\n| numerics | {' | '.join(f'drag {lo:g}-{hi:g} s [N/m]' for lo, hi in windows)} | fill φ at "
          f"{duration:g} s: rms of φ − 1 | least φ |\n|{'---|' * (len(windows) + 3)}")
    ref_t, ref_drag = reference["times"], -reference["tangential"]
    print(f"| reference | {' | '.join(f'{ref_drag[(ref_t > lo) & (ref_t <= hi)].mean():.4f}' for lo, hi in windows)}"
          " | | |")
    for label, config in configs.items():
        sim = StirringSimulator(Newtonian(eta=viscosity), RIG, config, density=1000.0)
        with torch.no_grad():
            result = sim(trajectory)
        t = result.times.double().numpy()
        _, along = _orbit_components(trajectory, t, result.force.double().numpy())
        drags = " | ".join(f"{-along[(t > lo) & (t <= hi)].mean():.4f}" for lo, hi in windows)
        end = trajectory.poses(np.array([duration]))[0][0]
        fill = node_fill(sim.scene, deposit(sim.scene.grid, result.state.x, sim.scene.particle_mass,
                                            sim.scene.offset_index, sim.scene.strides, sim.scene.particle_bounds),
                         RodPose(axis=torch.as_tensor(end, dtype=result.state.x.dtype), tip=torch.zeros(()),
                                 angle=torch.zeros(()), velocity=torch.zeros(2), angular_velocity=torch.zeros(())))
        inside = (sim.scene.cup_phi > 2 * config.dx) & (
            (sim.scene.nodes - torch.as_tensor(end, dtype=sim.scene.nodes.dtype)).norm(dim=1) > RIG.rod.radius)
        print(f"| {label} | {drags} | {float((fill[inside] - 1).pow(2).mean().sqrt()):.3f} | "
              f"{float(fill[inside].min()):.2f} |", flush=True)


def _orbit_components(trajectory, t: np.ndarray, force: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The force [N/m] along the orbit's radius (outwards) and along the rod's motion, at times ``t`` [s]."""
    xy, _, _ = trajectory.poses(t)
    phase = np.arctan2(xy[:, 1], xy[:, 0])
    return (force[:, 0] * np.cos(phase) + force[:, 1] * np.sin(phase),
            force[:, 1] * np.cos(phase) - force[:, 0] * np.sin(phase))


def stir(directory: Path, configs: dict[str, SimConfig], viscosities: tuple[float, ...]) -> None:
    print("\n| η [Pa·s] | numerics | c [m/s] | steps | drag [N/m] | reference | deviation | radial [N/m] | "
          "reference | rms deviation | rms noise |\n|---|---|---|---|---|---|---|---|---|---|---|")
    for viscosity in viscosities:
        reference = stir_reference(viscosity, directory)
        for label, config in configs.items():
            print(stir_row(config, label, viscosity, reference), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checks", nargs="+",
                        default=["couette", "power_law", "translate", "buoyancy2d", "rest3d"])
    parser.add_argument("--rest-time", type=float, default=8.0, help="duration of the rest3d check [s]")
    parser.add_argument("--numerics", nargs="+", help="run only the numerics whose labels start with these "
                        "(e.g. projection; default: all)")
    parser.add_argument("--reference-dir", type=Path, default=Path("outputs/stir-reference"),
                        help="where the stir check keeps its finite-element references")
    parser.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE",
                        help="SimConfig fields set on every numerics the checks pick (e.g. dt_max=0.004; not "
                        "rest3d's or stir_timestep's, which set their own)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    changes = {key: yaml.safe_load(value) for key, value in (item.split("=", 1) for item in args.set)}

    def pick(configs: dict[str, SimConfig]) -> dict[str, SimConfig]:
        chosen = {k: v for k, v in configs.items() if not args.numerics or any(k.startswith(n) for n in args.numerics)}
        return {k: v.replace(**changes) for k, v in chosen.items()}

    configs = pick(CONFIGS)
    print(f"{datetime.date.today()}, {platform.machine()}, {os.cpu_count()} CPUs, load average "
          f"{os.getloadavg()[0]:.1f} at start, torch {torch.__version__}, 1 thread, float32")
    checks = {
        "couette": lambda: [couette(config, label) for label, config in configs.items()],
        "power_law": lambda: [power_law_couette(config, label) for label, config in configs.items()],
        "translate": lambda: [translating(config, label, mu) for mu in (0.5, 1.0, 3.0, 20.0)
                              for label, config in configs.items()],
        "buoyancy2d": lambda: [buoyancy_2d(config, label) for label, config in configs.items()],
        "convergence": lambda: [check(config.replace(dx=dx), f"{label}, dx = {dx * 1e3:.3g} mm")
                                for label, config in configs.items() if label in ("projection", "compressible")
                                for dx in (0.005, 0.0025, 0.002, 0.0025 / 1.5, 0.00125)
                                for check in (couette, power_law_couette, partial(translating, mu=0.5),
                                              translating)],
        "thick": lambda: [thick(config, label, mu) for mu in (1.0, 20.0, 100.0) for label, config in configs.items()
                          if label in ("projection", "implicit")],
        "rest3d": lambda: rest3d(args.rest_time),
    }
    closed = [name for name in args.checks if name in checks]
    if closed:
        print("| check | simulated | closed form | ratio |")
        print("|---|---|---|---|")
    for name in closed:
        for label, value, reference in checks[name]():
            print(f"| {label} | {value:.5g} | {reference:.5g} | {value / reference:.3f} |", flush=True)
    if "stir" in args.checks:
        stir(args.reference_dir, pick(STIR_CONFIGS), STIR_VISCOSITIES)
    if "stir_convergence" in args.checks:
        stir(args.reference_dir, pick(STIR_CONVERGENCE), (1.0,))
    if "numerical_viscosity" in args.checks:
        print("\n| numerics | Δt [ms] | numerical viscosity, FLIP share 0.95 [m²/s] | APIC alone (flip 0) [m²/s] |\n"
              "|---|---|---|---|")
        for label, config, steps in (("projection", PROJECTION, (2e-3, 1e-3, 5e-4, 2.5e-4, 1e-4)),
                                     ("compressible", COMPRESSIBLE, (1e-3, 2.5e-4, 1e-4, 6e-5))):  # s
            for dt in steps:
                print(f"| {label} | {dt * 1e3:g} | {numerical_viscosity(config.replace(dt=dt), None):.2e} | "
                      f"{numerical_viscosity(config.replace(dt=dt, flip=0.0), None):.2e} |", flush=True)
    if "stir_sound_speed" in args.checks:
        stir(args.reference_dir, STIR_SOUND_SPEEDS, (1.0,))
    if "stir_history" in args.checks:
        stir_history(args.reference_dir)
    if "stir_drift" in args.checks:
        stir_drift(args.reference_dir, pick(DRIFT_CONFIGS))
    if "stir_timestep" in args.checks:
        stir_timestep(args.reference_dir)
    if "inertial_error" in args.checks:
        inertial_error(args.reference_dir, PROJECTION.replace(**changes))


if __name__ == "__main__":
    main()
