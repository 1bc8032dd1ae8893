"""Boundary particles that carry the fluid's pressure into the solids (diffstir.mpm.walls, sim.wall_pressure)."""

import numpy as np
import pytest
import torch

from diffstir.mpm import SimConfig, StirringSimulator
from diffstir.mpm.boundaries import is_solid, rod_sdf
from diffstir.mpm.materials import volumetric_stress
from diffstir.mpm.step import MASS_FLOOR, p2g
from diffstir.mpm.wall_pressure import wall_impulses
from diffstir.rheology import Newtonian
from diffstir.rig import Rig
from diffstir.trajectory import stationary

DT = 1e-4  # s
J = 0.97  # a uniform 3 % compression


@pytest.fixture(scope="module")
def compressed_slice():
    """A 2-D slice seeded on its lattice (no settling), every particle at J = 0.97, at rest; the simulator, the
    particles' state, the rod's pose and the nodes' pressure impulse from the particles [N·s/m], (nodes, 2)."""
    config = SimConfig(dim=2, dx=0.005, settle_time=0.0, wall_pressure=True, dtype="float64")
    sim = StirringSimulator(Newtonian(eta=1.0), Rig(), config, density=1000.0)
    trajectory = stationary(0.01, position=(0.015, 0.0))
    state = sim.initial_state(trajectory)
    state.J = torch.full_like(state.J, J)
    pose = sim._poses(trajectory, np.array([0.0, DT]))[0]
    buffer, stencil = p2g(sim.scene, state, DT)
    return sim, state, pose, buffer, stencil


def test_boundary_particles_impulses_sum_to_zero_over_the_nodes(compressed_slice):
    sim, state, pose, buffer, stencil = compressed_slice
    rod, cup = wall_impulses(sim.scene, state, stencil, buffer[:, 2], pose, DT)
    scale = DT * -volumetric_stress(torch.tensor(J), sim.scene.bulk_modulus).item() * sim.scene.grid.dx  # [N·s/m]
    assert cup.abs().max() > 0.1 * scale and rod.abs().max() > 0.1 * scale  # they push
    torch.testing.assert_close(cup.sum(0), torch.zeros(2, dtype=cup.dtype), atol=1e-12 * scale * len(cup), rtol=0)
    torch.testing.assert_close(rod.sum(0), torch.zeros(2, dtype=rod.dtype), atol=1e-12 * scale * len(rod), rtol=0)


def test_the_cups_boundary_particles_complete_the_stencil_of_a_uniform_pressure(compressed_slice):
    # a uniform pressure pushes no node of the fluid; near a wall the particles' stencils are cut and the nodes next
    # to it are pushed off it, unless particles in the wall on the fluid's lattice carry the same pressure
    sim, state, pose, buffer, stencil = compressed_slice
    scene = sim.scene
    rod, cup = wall_impulses(scene, state, stencil, buffer[:, 2], pose, DT)
    fluid = (buffer[:, 2] > MASS_FLOOR) & ~is_solid(scene.cup_phi, scene.grid.dx)
    fluid &= rod_sdf(scene.rod, scene.nodes, pose)[0] > 3 * scene.grid.dx  # the rod's lattice is not the fluid's
    particles = buffer[fluid, :2]
    scale = DT * -volumetric_stress(torch.tensor(J), scene.bulk_modulus).item() * scene.grid.dx
    assert particles.norm(dim=1).max() > 0.1 * scale  # cut stencils push the nodes by the wall
    assert (particles + cup[fluid]).norm(dim=1).max() < 1e-9 * scale


def test_wall_pressure_needs_a_compressible_fluid():
    with pytest.raises(ValueError, match="sim.wall_pressure"):
        SimConfig(dim=2, pressure="projection", wall_pressure=True)
