"""The incompressible pressure (``diffstir.mpm.projection``): its operator, its solvers and what it does to a step."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import diffstir.mpm.step as step_module
from diffstir.mpm import SimConfig, StirringSimulator
from diffstir.mpm.projection import PressureSolver, solve_pressure
from diffstir.rheology import Newtonian
from diffstir.rig import Rig
from diffstir.trajectory import circle

CONFIG = SimConfig(dim=2, dx=0.005, dtype="float64", pressure="projection", checkpoint_every=0)


@pytest.fixture(scope="module")
def captured():
    """The projection operators, right-hand sides and solutions of the steps of a short float64 stir, and the grid's
    node positions [m]."""
    calls = []
    original = step_module.solve_pressure

    def spy(operator, rhs):
        impulse = original(operator, rhs)
        calls.append((operator, rhs, impulse))
        return impulse

    step_module.solve_pressure = spy
    try:
        sim = StirringSimulator(Newtonian(eta=0.5, dtype=torch.float64), Rig(), CONFIG, density=1000.0)
        with torch.no_grad():
            sim(circle(radius=0.015, speed=0.1, duration=0.05, ramp_time=0.01))
    finally:
        step_module.solve_pressure = original
    return calls, sim.scene.nodes


def test_assembled_matrix_is_the_matrix_free_operator(captured):
    operator, rhs, _ = captured[0][-1]
    p = torch.randn(rhs.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    p = p * operator.pressure_cell
    kept = operator.pressure_cell.bool()
    assembled = operator.matrix() @ p[kept].numpy()
    free = operator(p)
    np.testing.assert_allclose(assembled, free[kept].numpy(), rtol=0, atol=1e-12 * np.abs(assembled).max())
    assert float(free[~kept].abs().max()) == 0.0  # cells without a pressure are left out


def test_operator_is_symmetric_positive_definite(captured):
    operator, _, _ = captured[0][-1]
    dense = operator.matrix().toarray()
    np.testing.assert_allclose(dense, dense.T, rtol=0, atol=1e-12 * np.abs(dense).max())
    assert np.linalg.eigvalsh(dense)[0] > 0


def test_ldl_and_conjugate_gradients_agree(captured):
    operator, rhs, impulse = captured[0][-1]
    by_ldl = PressureSolver(operator.matrix(), operator.pressure_cell, "ldl")(rhs)
    by_cg = PressureSolver(operator.matrix(), operator.pressure_cell, "cg")(rhs)
    torch.testing.assert_close(by_ldl, impulse, rtol=0, atol=1e-10 * float(impulse.abs().max()))
    torch.testing.assert_close(by_cg, by_ldl, rtol=0, atol=1e-7 * float(by_ldl.abs().max()))
    with pytest.raises(ValueError, match="method"):
        PressureSolver(operator.matrix(), operator.pressure_cell, "jacobi")


def test_projection_removes_a_smooth_divergence(captured):
    """A smooth source-like velocity field (a Gaussian blob, 2 cm wide, spreading from a point 15 mm from the rod's
    orbit) on the fluid's nodes, walls at rest, is made divergence-free up to what the stabilisation leaves of a
    field this smooth, of order β (k dx)²/(4d)²: under 2 %."""
    (*_, (operator, _, _)), nodes = captured
    offset = nodes - torch.tensor([-0.015, 0.0], dtype=nodes.dtype)
    v = torch.exp(-(offset**2).sum(1, keepdim=True) / 0.02**2) * offset / 0.02 * 0.01 * (operator.mobility > 0)
    before = -operator.constrained_divergence(v)
    after = operator.constrained_divergence(v + operator.impulse(solve_pressure(operator, before)))
    assert float(after.norm()) < 0.02 * float(before.norm())


def test_projection_is_two_dimensional_only():
    with pytest.raises(ValueError, match="2-D slice only"):
        SimConfig(dim=3, pressure="projection")
    with pytest.raises(ValueError, match="sim.pressure"):
        SimConfig(dim=2, pressure="incompressible")


def test_projection_fluid_needs_no_sound_speed():
    """The step follows the flow's Courant number and the viscous limit, not an acoustic one."""
    sim = StirringSimulator(Newtonian(eta=0.01), Rig(), CONFIG.replace(dtype="float32", dt_max=0.05),
                            density=1000.0)
    trajectory = circle(radius=0.015, speed=0.1, duration=1.0)
    u_max = trajectory.max_speed(Rig().rod.radius)
    assert sim.time_step(trajectory) == pytest.approx(CONFIG.cfl * CONFIG.dx / u_max, rel=0.01)
