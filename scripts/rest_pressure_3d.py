"""Why the rod at rest in 3-D does not feel its buoyancy (docs/validation-rest-3d.md, The 3-D fluid at rest).

The paper's rig in 3-D, the fluid settled and then held still for ``--hold`` seconds around the still rod. Printed:

* the mean vertical force on the rod against the buoyancy ρ g V of its immersed volume, to the fill height and
  below the free surface as it stands (the weakly compressible fluid's column sinks by a few per cent);
* the particles' pressure p = −κ/2 (J − 1/J) (κ = ρ c²) in layers one cell thick, far from the rod (the outer
  half of the gap between rod and wall, a cell clear of the wall) and under the rod's tip, against the
  hydrostatic ρ g (h_s − z), h_s the free surface's height far from the rod;
* the fluid's compression two ways: the particles' mean 1 − J, and the drop of the free surface below the fill
  height (a column compressed uniformly by ε sinks by ε h);
* the fluid's volume by its particles' J, Σ J V0, and its centre of mass's height, in the settled state and after
  the hold: at rest neither should change; and the seeded volume against the cup's fill volume;
* the rod's reaction on the final state split by node layer above the tip (``diffstir.mpm.step``): the particles'
  momentum with the fluid's pressure impulse (p2g), the gravity of the fluid mass on the rod's nodes, and the
  momentum the ghost-velocity boundary condition gives that mass; with ``--wall-pressure`` also the rod's boundary
  particles' push on the fluid's nodes, which its reaction counts with the opposite sign;
* who holds the fluid's weight: the cup's bottom and wall (the momentum their boundary condition takes from the
  fluid mass on their nodes), with ``--wall-pressure`` the cup's boundary particles, and the rod.

    python scripts/rest_pressure_3d.py [--dx 0.01] [--hold 0.02] [--settle 0.2] [--wall-pressure] [--device cuda]
"""

from __future__ import annotations

import argparse
import math
import platform
import time
from collections import defaultdict
from datetime import datetime, timezone

import numpy as np
import torch

from diffstir.mpm import SimConfig, StirringSimulator
from diffstir.mpm.boundaries import is_solid
from diffstir.mpm.step import MASS_FLOOR, grid_update, p2g
from diffstir.mpm.wall_pressure import wall_impulses
from diffstir.rheology import Newtonian
from diffstir.rig import Rig
from diffstir.trajectory import stationary

DENSITY, SOUND_SPEED = 1000.0, 4.5  # kg/m³, m/s (the paper's grid's defaults, tests/test_mpm.py)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dx", type=float, default=0.01, help="cell size [m]")
    parser.add_argument("--hold", type=float, default=0.02, help="time held at rest after settling [s]")
    parser.add_argument("--settle", type=float, default=0.2, help="settling time [s]")
    parser.add_argument("--wall-pressure", action="store_true", help="boundary particles in the solids carry the "
                        "fluid's pressure (SimConfig.wall_pressure)")
    parser.add_argument("--device", default="cpu", help="torch device (SimConfig.device), e.g. cuda")
    args = parser.parse_args()
    torch.set_num_threads(1)
    device = torch.cuda.get_device_name() if args.device.startswith("cuda") else f"{platform.machine()}, 1 thread"
    print(f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, {device}, torch {torch.__version__}, "
          f"dx = {args.dx} m, settle {args.settle} s, hold {args.hold} s, wall pressure {args.wall_pressure}")
    rig = Rig()
    rod, g = rig.rod, rig.gravity
    cfg = SimConfig(dim=3, dx=args.dx, sound_speed=SOUND_SPEED, settle_time=args.settle,
                    wall_pressure=args.wall_pressure, device=args.device)
    sim = StirringSimulator(Newtonian(eta=0.2), rig, cfg, density=DENSITY)
    trajectory = stationary(args.hold)
    start = time.perf_counter()
    settled = sim.initial_state(trajectory)
    settling = time.perf_counter() - start
    with torch.no_grad():
        result = sim(trajectory)
    print(f"{settled.num_particles} particles, settled in {settling:.0f} s (or loaded from the cache), held "
          f"{len(result.times)} steps of {result.dt * 1e3:.3f} ms in {time.perf_counter() - start - settling:.0f} s")
    buoyancy = DENSITY * g * math.pi * rod.radius ** 2 * rod.immersion_depth
    print(f"vertical force on the rod {result.force[:, 2].mean().item():+.4f} N, buoyancy ρ g V {buoyancy:.4f} N")

    x, J = result.state.x, result.state.J
    r = x[:, :2].norm(dim=1)
    far = (r > 0.5 * (rod.radius + rig.cup.radius)) & (r < rig.cup.radius - args.dx)  # the outer half of the gap
    surface = float(x[far, 2].max())
    tip = rig.cup.fill_height - rod.immersion_depth
    kappa = DENSITY * SOUND_SPEED ** 2
    sunken = DENSITY * g * math.pi * rod.radius ** 2 * (surface - tip)
    print(f"the same against ρ g V below the free surface far from the rod (h_s = {surface:.5f} m), {sunken:.4f} N: "
          f"{result.force[:, 2].mean().item() / sunken:.4f}")

    def pressure(mask) -> str:
        j = J[mask]
        return f"{float((-0.5 * kappa * (j - 1.0 / j)).mean()):7.0f} ({int(mask.sum())})" if mask.any() else "-"

    print("\n| height z [m] | hydrostatic ρ g (h_s − z) [Pa] | particle p far from the rod [Pa] (n) | "
          "under the tip [Pa] (n) |\n|---|---|---|---|")
    for z in [surface - k * args.dx for k in range(1, int(surface / args.dx))]:
        layer = (x[:, 2] > z - 0.5 * args.dx) & (x[:, 2] < z + 0.5 * args.dx)
        under = layer & (r < rod.radius) & (x[:, 2] < tip)
        print(f"| {z:.3f} | {DENSITY * g * (surface - z):.0f} | {pressure(layer & far)} | {pressure(under)} |")
    print(f"\ncompression: particles' mean 1 − J {float((1 - J).mean()):.4f}; free surface "
          f"{surface:.4f} m against the fill height {rig.cup.fill_height:.4f} m: "
          f"{(rig.cup.fill_height - surface) / rig.cup.fill_height:.4f} of the column")

    v0 = sim.scene.particle_volume
    cup_volume = math.pi * rig.cup.radius ** 2 * rig.cup.fill_height
    rod_volume = math.pi * rod.radius ** 2 * rod.immersion_depth
    print(f"seeded: {settled.x.shape[0]} particles, N V0 {settled.x.shape[0] * v0 * 1e6:.1f} ml; the cup to its fill "
          f"height holds {cup_volume * 1e6:.1f} ml, less the rod's immersed {rod_volume * 1e6:.1f} ml")
    for name, fluid in (("settled", settled), (f"after {args.hold:g} s at rest", result.state)):
        print(f"{name}: Σ J V0 {float(fluid.J.sum()) * v0 * 1e6:.1f} ml, centre of mass at "
              f"z = {float(fluid.x[:, 2].mean()) * 1e3:.2f} mm")

    dt = result.dt
    state = result.state
    pose = sim._poses(trajectory, np.array([trajectory.t[-1] - dt, trajectory.t[-1]]))[0]
    scene, d = sim.scene, sim.scene.dim
    buffer, stencil = p2g(scene, state, dt)
    wall_push = None if scene.walls is None else wall_impulses(scene, state, stencil, buffer[:, d], pose, dt)
    update = grid_update(scene, sim.material, buffer, pose, dt, wall_push=wall_push)
    v_new, force = update.velocity, update.force
    window = scene.rod_window.nodes(scene.grid, pose.axis)
    nodes = scene.nodes[window]
    local = nodes - torch.cat([pose.axis, pose.tip.reshape(1)])
    inside = (local[:, :2].norm(dim=1) <= rod.radius) & (local[:, 2] >= 0)
    mass = buffer[window, d]
    parts = defaultdict(lambda: torch.zeros(3, dtype=torch.float64))
    for i in torch.nonzero(inside & (mass > 0)).flatten().tolist():
        layer = int(round(float(local[i, 2]) / args.dx))
        parts[layer] += torch.tensor([float(buffer[window[i], 2]) / dt, float(mass[i]) * float(scene.gravity[2]),
                                      -float(mass[i] * v_new[window[i], 2].detach()) / dt], dtype=torch.float64)
    print(f"\nthe rod's vertical reaction on the final state {force[2].item():+.4f} N, by node layer above the tip:\n"
          "| layer [cells] | momentum + the fluid's pressure impulse / Δt [N] | gravity of the node mass [N] | "
          "− ghost momentum / Δt [N] |\n|---|---|---|---|")
    total = torch.zeros(3, dtype=torch.float64)
    for layer in sorted(parts):
        total += parts[layer]
        print(f"| {layer} | {parts[layer][0]:+.4f} | {parts[layer][1]:+.4f} | {parts[layer][2]:+.4f} |")
    print(f"| all | {total[0]:+.4f} | {total[1]:+.4f} | {total[2]:+.4f} |")
    # who carries the fluid's weight: each solid's nodes hold the momentum their boundary condition takes from the
    # fluid mass on them (the rod's reaction; shear stress left out, the fluid is at rest), and each solid's
    # boundary particles push the fluid's nodes
    node_mass = buffer[:, d]
    has_mass = node_mass > MASS_FLOOR
    cup = is_solid(scene.cup_phi, scene.grid.dx)
    fluid = has_mass & ~cup & ~torch.zeros_like(cup).index_fill(0, window[inside], True)
    v_free = torch.where(has_mass[:, None], buffer[:, :d] / node_mass.clamp_min(MASS_FLOOR)[:, None]
                         + dt * scene.gravity, 0.0)
    held = node_mass * (v_free[:, 2] - v_new[:, 2].detach()) / dt
    bottom = cup & (scene.nodes[:, 2] < 0.5 * scene.grid.dx)
    cup_particles = 0.0
    if wall_push is not None:
        rod_push, cup_push = wall_push
        print(f"the rod's boundary particles push the fluid's nodes with {float(rod_push[fluid, 2].sum()) / dt:+.4f} N "
              "(the rod's reaction counts it with the opposite sign)")
        cup_particles = -float(cup_push[fluid, 2].sum()) / dt
    weight = float(state.x.shape[0] * scene.particle_mass * rig.gravity)
    print(f"the fluid's weight {weight:.4f} N is held by: the cup's bottom {float(held[bottom].sum()):+.4f} N, its "
          f"wall {float(held[cup & ~bottom].sum()):+.4f} N, its boundary particles {cup_particles:+.4f} N, the rod "
          f"{force[2].item():+.4f} N (they sum to {float(held[cup].sum()) + cup_particles + force[2].item():+.4f} N; "
          f"at rest −{weight:.4f} N, the cup holding the weight and the buoyancy, −{weight + buoyancy:.4f} N)")


if __name__ == "__main__":
    main()
