"""The implicit shear stress (sim.viscous_solver = implicit): its operator, its closed forms beyond the explicit
step's cap, and its derivatives in both modes."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from problems import fitting_default, translating_rod_force

from diffstir.fitting.uncertainty import MODEL_FORCE_ERROR, Z95
from diffstir.mpm import Corotated, SimConfig, StirringSimulator, force_sensitivities
from diffstir.mpm.grid import Grid
from diffstir.mpm.implicit_viscosity import StiffnessPattern
from diffstir.mpm.materials import deviatoric_rate_of_strain
from diffstir.mpm.viscous import CellStencil, cell_velocity_gradient, nodal_forces
from diffstir.rheology import Carreau, Newtonian
from diffstir.rig import Rig
from diffstir.trajectory import circle, translate

F64 = dict(dtype=torch.float64)
TINY = SimConfig(dim=2, dx=0.005, sound_speed=2.0, dtype="float64", dt=1e-3, checkpoint_every=7,
                 viscous_solver="implicit")
IMPLICIT = fitting_default().replace(viscous_solver="implicit")
#: A closed form the fitting default must meet: within the force error σ_m every fit's interval assumes, at 95 %.
CLOSED_FORM_TOLERANCE = Z95 * MODEL_FORCE_ERROR


@pytest.mark.parametrize("dim", [2, 3])
def test_the_assembled_stiffness_is_the_viscous_node_force(dim):
    # f_i = −Σ_c V_c 2 η_c dev(D_c) ∇N_i(x_c) is linear in the node velocities: K v with K assembled from one cell's
    # stiffness scaled by V_c η_c, to rounding; K is symmetric
    grid = Grid(origin=torch.zeros(dim, **F64), dx=0.01, shape=(4,) * dim)
    cells = CellStencil.of(grid)
    generator = torch.Generator().manual_seed(0)
    v = torch.randn(grid.num_nodes, dim, generator=generator, **F64)
    eta = torch.rand(cells.corners.shape[0], generator=generator, **F64) + 0.1
    volume = torch.full_like(eta, grid.dx**dim)
    expected = nodal_forces(2.0 * eta[:, None, None] * deviatoric_rate_of_strain(cell_velocity_gradient(v, cells)),
                            volume, cells, grid.num_nodes)
    stiffness = StiffnessPattern.of(cells, grid.num_nodes).matrix((eta * volume).numpy())
    np.testing.assert_allclose(stiffness @ v.reshape(-1).numpy(), expected.reshape(-1).numpy(), rtol=0,
                               atol=1e-12 * float(expected.abs().max()))
    assert abs(stiffness - stiffness.T).max() <= 1e-12 * abs(stiffness).max()


@pytest.mark.parametrize("mu, speed", [(20.0, 0.02), (100.0, 0.02)])
def test_the_translating_rod_meets_its_closed_form_at_and_beyond_the_explicit_cap(mu, speed):
    """The rod translating through the cup's centre (Re = 0.02-0.1) on the fitting grid with the cap raised to
    the fluid: the implicit step is at the flow's 2 ms whatever η, where the explicit one shortens with η."""
    rig = Rig()
    config = IMPLICIT.replace(viscosity_cap=mu)
    trajectory = translate((speed, 0.0), duration=0.004 / speed, start=(-0.002, 0.0))
    sim = StirringSimulator(Newtonian(eta=mu), rig, config, density=1000.0)
    assert sim.time_step(trajectory) == pytest.approx(config.dt_max)
    assert sim.substeps(trajectory, sim.time_step(trajectory)) == 1
    with torch.no_grad():
        result = sim(trajectory)
    steady = -result.force[int(0.7 * len(result.force)):, 0].mean().item()
    assert steady == pytest.approx(translating_rod_force(mu, speed, rig.rod.radius, rig.cup.radius),
                                   rel=CLOSED_FORM_TOLERANCE)


#: The agreement check's simulators: the 2-D slice with the projection; the 3-D cup (its pressure from a sound
#: speed, the projection being the slice's) on 1 cm cells, on a shorter stir (its steps cost 30 times more).
AGREEMENT = {2: (TINY.replace(pressure="projection", dt=5e-4), 0.1, 50),
             3: (SimConfig(dim=3, dx=0.01, sound_speed=4.5, settle_time=0.02, dtype="float64", dt=1e-3,
                           checkpoint_every=7, pressure="compressible"), 0.04, 20)}


@pytest.mark.parametrize("dim", [2, 3])
def test_implicit_and_explicit_steps_agree_where_both_are_stable(dim):
    """A stir of a thinning fluid whose explicit limit is above the step: the two updates differ by the
    backward-Euler step's first-order error, O(Δt η / (ρ dx²)), under a few per cent of the force here."""
    eta0, density = 2.0, 1000.0  # Pa·s, kg/m³
    law = Carreau(eta0=eta0, eta_inf=0.05, lam=0.3, n=0.5, **F64)
    config, duration, last = AGREEMENT[dim]
    trajectory = circle(radius=0.015, speed=0.05, duration=duration, ramp_time=duration / 4)
    forces = {}
    for solver in ("explicit", "implicit"):
        sim = StirringSimulator(law, Rig(), config.replace(viscous_solver=solver), density=density)
        assert sim.substeps(trajectory, sim.time_step(trajectory)) == 1
        with torch.no_grad():
            forces[solver] = sim(trajectory).force[-last:].norm(dim=1).mean().item()
    # Δt η_0 / (ρ dx²): the relative step of the slowest viscous mode, 0.04 in 2-D and 0.02 in 3-D
    bound = config.dt * eta0 / (density * config.dx**2)
    assert forces["implicit"] == pytest.approx(forces["explicit"], rel=bound)


@pytest.mark.parametrize("pressure", ["compressible", "projection"])
def test_gradient_through_the_implicit_step_matches_central_differences(pressure):
    """Reverse mode through the solve's implicit derivative (and the projection's carried pressure) equals central
    differences in every law parameter."""
    law = Carreau(eta0=18.0, eta_inf=0.5, lam=0.3, n=0.5, **F64)
    sim = StirringSimulator(law, Rig(), TINY.replace(pressure=pressure), density=1000.0)
    trajectory = circle(radius=0.015, speed=0.05, duration=0.03, ramp_time=0.01)

    def loss():
        result = sim(trajectory)
        return (result.force**2).sum(-1).mean() + result.torque.square().mean()

    params = [p for p in law.parameters() if p.requires_grad]
    grads = torch.autograd.grad(loss(), params)
    eps = 1e-5
    for p, g in zip(params, grads):
        with torch.no_grad():
            p += eps
            up = loss()
            p -= 2 * eps
            down = loss()
            p += eps
        assert float(g.sum()) == pytest.approx(float((up - down) / (2 * eps)), rel=1e-5, abs=1e-14)


def test_forward_mode_sensitivities_through_the_implicit_step():
    law = Carreau(eta0=1.0, eta_inf=0.05, lam=0.3, n=0.5, **F64)
    sim = StirringSimulator(law, Rig(), TINY.replace(pressure="projection"), density=1000.0)
    trajectory = circle(radius=0.015, speed=0.05, duration=0.03, ramp_time=0.01)
    sens = force_sensitivities(sim, trajectory)
    with torch.no_grad():
        torch.testing.assert_close(sens.force, sim(trajectory).force, rtol=0, atol=0)
    values = law.parameters_si()
    for j, (name, value) in enumerate(values.items()):
        step = 1e-4 * value  # the projection's solve conditions the differences (tests/test_sensitivity.py)
        law.set_parameters_si(**{name: value + step})
        with torch.no_grad():
            up = sim(trajectory).force
        law.set_parameters_si(**{name: value - step})
        with torch.no_grad():
            down = sim(trajectory).force
        law.set_parameters_si(**{name: value})
        central = (up - down) / (2 * step)
        torch.testing.assert_close(sens.force_jacobian[..., j], central, rtol=0,
                                   atol=1e-6 * float(central.abs().max()))


def test_a_material_without_a_viscosity_is_refused_naming_the_setting():
    with pytest.raises(ValueError, match="sim.viscous_solver"):
        StirringSimulator(Corotated(1e5), Rig(), TINY)
    with pytest.raises(ValueError, match="viscous_solver"):
        SimConfig(viscous_solver="backward")
