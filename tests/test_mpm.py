"""The MLS-MPM stirring simulator: gradients, checkpointing, closed-form flows and error handling."""

from __future__ import annotations

import math

import pytest
import torch

from diffstir.fitting.uncertainty import MODEL_FORCE_ERROR, Z95
from diffstir.mpm import Corotated, SimConfig, StirringSimulator
from diffstir.mpm.materials import polar_rotation
from diffstir.rheology import Bingham, Carreau, Cross, HerschelBulkley, Newtonian, PowerLaw
from diffstir.rig import Rig
from diffstir.trajectory import circle, spin, stationary, translate
from problems import (couette_torque_newtonian, couette_torque_power_law, fitting_default, rod_in_pressure_gradient,
                      translating_rod_force)

F64 = dict(dtype=torch.float64)
TINY = SimConfig(dim=2, dx=0.005, sound_speed=2.0, dtype="float64", dt=1e-3, checkpoint_every=7)
SLICE = fitting_default()  # 2-D, 2.5 mm cells, incompressible
#: A closed form the fitting default must meet: within the force error σ_m every fit's interval assumes, at 95 %.
CLOSED_FORM_TOLERANCE = Z95 * MODEL_FORCE_ERROR

LAWS = [
    Newtonian(eta=0.5, **F64),
    PowerLaw(k=0.8, n=0.7, **F64),
    Carreau(eta0=1.0, eta_inf=0.05, lam=0.3, n=0.5, **F64),
    Cross(eta0=1.0, eta_inf=0.05, lam=0.2, n=0.8, **F64),
    HerschelBulkley(tau_y=0.05, k=0.5, n=0.8, shear_rate_reg=0.5, **F64),
    Bingham(tau_y=0.05, eta_p=0.4, shear_rate_reg=0.5, **F64),
]


def _loss(sim, trajectory):
    result = sim(trajectory)
    return (result.force**2).sum(-1).mean() + result.torque.square().mean()


@pytest.mark.parametrize("pressure", ["compressible", "projection"])
@pytest.mark.parametrize("law", LAWS, ids=lambda law: law.name)
def test_gradient_matches_central_differences(law, pressure):
    """d loss / d raw parameter by reverse mode through a checkpointed rollout equals central finite differences,
    also through the projection's pressure solve (differentiated implicitly, not through its iterations)."""
    sim = StirringSimulator(law, Rig(), TINY.replace(pressure=pressure), density=1000.0)
    trajectory = circle(radius=0.015, speed=0.05, duration=0.03, ramp_time=0.01)
    params = [p for p in law.parameters() if p.requires_grad]
    loss = _loss(sim, trajectory)
    grads = torch.autograd.grad(loss, params)
    eps = 1e-5
    for p, g in zip(params, grads):
        for i in range(p.numel()):
            with torch.no_grad():
                flat = p.view(-1)
                flat[i] += eps
                up = _loss(sim, trajectory)
                flat[i] -= 2 * eps
                down = _loss(sim, trajectory)
                flat[i] += eps
            fd = (up - down) / (2 * eps)
            # central differences carry O(eps²) truncation and ~1e-16/eps rounding: 1e-5 relative is ample
            assert float(g.view(-1)[i]) == pytest.approx(float(fd), rel=1e-5, abs=1e-14)


def test_corotated_gradient_matches_central_differences():
    material = Corotated(shear_modulus=400.0).double()
    sim = StirringSimulator(material, Rig(), TINY, density=1000.0)
    trajectory = circle(radius=0.015, speed=0.05, duration=0.02, ramp_time=0.01)
    loss = _loss(sim, trajectory)
    (g,) = torch.autograd.grad(loss, [material.log_shear_modulus])
    eps = 1e-5
    with torch.no_grad():
        material.log_shear_modulus += eps
        up = _loss(sim, trajectory)
        material.log_shear_modulus -= 2 * eps
        down = _loss(sim, trajectory)
        material.log_shear_modulus += eps
    assert float(g) == pytest.approx(float((up - down) / (2 * eps)), rel=1e-5)


def test_a_corotated_baseline_that_blows_up_raises_what_the_fit_rejects():
    """A shear modulus far past the explicit step's stability (μ Δt² / (ρ Δx²) ≫ 1) crushes particles (F = I + Δt ∇v
    singular): the rollout ends in FloatingPointError, the error the fit turns into a rejected trial step, not in
    the linear algebra's."""
    trajectory = circle(radius=0.015, speed=0.05, duration=0.05, ramp_time=0.01)
    for shear_modulus in (1e5, 1e8):  # Pa; stability needs μ < ρ Δx² / Δt² = 25 kPa here
        sim = StirringSimulator(Corotated(shear_modulus=shear_modulus).double(), Rig(), TINY, density=1000.0)
        with pytest.raises(FloatingPointError, match="became non-finite"), torch.no_grad():
            sim(trajectory)


def test_the_polar_rotation_is_that_of_f_and_nan_where_f_is_singular():
    angle = 0.3
    rotation = torch.tensor([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]], **F64)
    stretch = torch.tensor([[1.2, 0.1], [0.1, 0.9]], **F64)  # symmetric positive definite
    F = torch.stack([rotation @ stretch, torch.ones(2, 2, **F64)])
    R = polar_rotation(F)
    torch.testing.assert_close(R[0], rotation, rtol=0, atol=1e-12)
    assert torch.isnan(R[1]).all()


def test_checkpointing_does_not_change_forces_or_gradients():
    trajectory = circle(radius=0.015, speed=0.05, duration=0.02, ramp_time=0.01)
    results = []
    for every in (0, 5):
        law = Carreau(eta0=1.0, eta_inf=0.05, lam=0.3, n=0.5, **F64)
        sim = StirringSimulator(law, Rig(), TINY.replace(checkpoint_every=every), density=1000.0)
        loss = _loss(sim, trajectory)
        results.append((float(loss), torch.autograd.grad(loss, list(law.parameters()))))
    assert results[0][0] == pytest.approx(results[1][0], rel=1e-12)
    for a, b in zip(results[0][1], results[1][1]):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-16)


def test_snapshots_are_taken_where_their_times_say():
    """A snapshot is the particles after a whole checkpoint segment: its time is that segment's end, and the last
    one is the final state."""
    trajectory = circle(radius=0.015, speed=0.05, duration=0.03, ramp_time=0.01)
    sim = StirringSimulator(Newtonian(eta=1.0, **F64), Rig(), TINY, density=1000.0)  # segments of 7 steps
    with torch.no_grad():
        result = sim(trajectory, snapshot_every=10)
    steps = [round(t / result.dt) for t in result.snapshot_times]
    assert steps == [7, 14, 21, 30]  # the segment ends that reach 10, 20 and 30 steps, after the first segment
    assert len(result.snapshots) == len(steps)
    torch.testing.assert_close(result.snapshots[-1], result.state.x)


@pytest.mark.slow
def test_compiled_step_matches_eager():
    """``SimConfig.compile`` changes how a step is computed, not what: the loss and its gradient through a
    checkpointed rollout equal the eager ones to float64 rounding (compiled kernels reorder sums; rounding of 1e-16
    amplified over 10 steps stays far below the 1e-9 allowed)."""
    trajectory = circle(radius=0.015, speed=0.05, duration=0.01, ramp_time=0.01)
    runs = []
    for compiled in (False, True):
        law = Carreau(eta0=1.0, eta_inf=0.05, lam=0.3, n=0.5, **F64)
        sim = StirringSimulator(law, Rig(), TINY.replace(compile=compiled, checkpoint_every=5), density=1000.0)
        loss = _loss(sim, trajectory)
        runs.append((loss.detach(), torch.autograd.grad(loss, list(law.parameters()))))
    torch.testing.assert_close(runs[1][0], runs[0][0], rtol=1e-9, atol=0.0)
    for eager, compiled in zip(runs[0][1], runs[1][1]):
        torch.testing.assert_close(compiled, eager, rtol=1e-9, atol=1e-15)


def test_float32_gradient_agrees_with_float64():
    trajectory = circle(radius=0.015, speed=0.05, duration=0.03, ramp_time=0.01)
    grads = []
    for dtype in ("float64", "float32"):
        law = Newtonian(eta=0.5, dtype=getattr(torch, dtype))
        sim = StirringSimulator(law, Rig(), TINY.replace(dtype=dtype), density=1000.0)
        grads.append(float(torch.autograd.grad(_loss(sim, trajectory), list(law.parameters()))[0]))
    # float32 rounding (1e-7) amplified over 30 steps of a well-conditioned map stays far below 1e-3
    assert grads[1] == pytest.approx(grads[0], rel=1e-3)


@pytest.mark.parametrize("pressure", ["compressible", "projection"])
def test_newtonian_couette_torque_2d(pressure):
    """Rod spinning at the cup's centre, Stokes regime (Re = ρΩa(b−a)/μ = 0.75): the steady torque per unit
    length matches 4πμΩa²b²/(b²−a²) within ``CLOSED_FORM_TOLERANCE`` on the fitting default (2.5 mm cells: the rod
    is 10 across), with either pressure."""
    mu, omega = 1.0, 2.0
    rig = Rig()
    sim = StirringSimulator(Newtonian(eta=mu), rig, SLICE.replace(pressure=pressure), density=1000.0)
    with torch.no_grad():
        result = sim(spin(omega, duration=0.6, ramp_time=0.1))
    steady = -result.torque[int(0.7 * len(result.torque)):].mean().item()
    assert steady == pytest.approx(couette_torque_newtonian(mu, omega, rig.rod.radius, rig.cup.radius),
                                   rel=CLOSED_FORM_TOLERANCE)


@pytest.mark.parametrize("dx", [0.0025, 0.002])
def test_power_law_couette_torque_2d(dx):
    """Shear-thinning power-law fluid (K = 1 Pa·s^n, n = 0.6), rod spinning at Ω = 1 rad/s at the cup's centre:
    the steady torque per unit length matches 2πKa²[2Ω/(n(1 − (a/b)^(2/n)))]^n within ``CLOSED_FORM_TOLERANCE``.
    Stokes regime: the
    apparent viscosity at the rod, K γ̇_a^(n−1) = 0.61 Pa·s at γ̇_a = 3.4 /s, gives Re = ρΩa(b−a)/η = 0.6; the
    slowest shear rate, 0.06 /s at the cup's wall, stays above the law's regularisation rate 0.01 /s."""
    k, n, omega = 1.0, 0.6, 1.0
    rig = Rig()
    sim = StirringSimulator(PowerLaw(k=k, n=n), rig, SLICE.replace(dx=dx), density=1000.0)
    with torch.no_grad():
        result = sim(spin(omega, duration=0.6, ramp_time=0.1))
    steady = -result.torque[int(0.7 * len(result.torque)):].mean().item()
    assert steady == pytest.approx(couette_torque_power_law(k, n, omega, rig.rod.radius, rig.cup.radius),
                                   rel=CLOSED_FORM_TOLERANCE)


def test_float32_and_float64_simulate_the_same_cup():
    """The cup's radius is a whole number of 2.5 mm cells, so four nodes lie on its wall (φ = 0 up to round-off):
    both precisions must count them as wall nodes, and then their forces differ by round-off only (1e-7 relative,
    grown over 100 steps of a dissipative flow, far below the 1e-4 allowed)."""
    trajectory = circle(radius=0.015, speed=0.1, duration=0.05, ramp_time=0.02)
    runs = []
    for dtype in ("float64", "float32"):
        sim = StirringSimulator(Newtonian(eta=3.0, dtype=getattr(torch, dtype)), Rig(),
                                SLICE.replace(dtype=dtype), density=1000.0)
        with torch.no_grad():
            runs.append((sim.scene.cup_band.target, sim(trajectory).force.double()))
    torch.testing.assert_close(runs[1][0], runs[0][0], rtol=0, atol=0)
    scale = runs[0][1].norm(dim=1).max()
    assert (runs[1][1] - runs[0][1]).norm(dim=1).max() < 1e-4 * scale


@pytest.mark.parametrize("pressure", ["compressible", "projection"])
def test_rod_feels_the_pressure_gradient_2d(pressure):
    """The pressure part of the rod's reaction: the rod held still off centre in the slice under a body force g
    along x (standing in for gravity, which a horizontal slice lacks) is pushed back by the hydrostatic pressure
    gradient, −ρ g π a² per unit length, within ``CLOSED_FORM_TOLERANCE`` as the other closed forms (0.991 and,
    with the projection, 1.003 measured; the 3-D rod's buoyancy, below, still fails). 1 Pa·s damps the settling's
    sloshing within the first 0.2 s of 0.6 s."""
    g = 1.0
    steady = rod_in_pressure_gradient(SLICE.replace(pressure=pressure), g)
    assert float(steady[0]) == pytest.approx(-1000.0 * g * math.pi * Rig().rod.radius**2,
                                              rel=CLOSED_FORM_TOLERANCE)
    assert abs(float(steady[1])) < 0.01 * abs(float(steady[0]))  # no force across the gradient, by symmetry


@pytest.mark.parametrize("pressure, mu", [("compressible", 1.0), ("compressible", 3.0), ("projection", 1.0)])
def test_translating_rod_drag_2d(pressure, mu):
    """Rod translating at the cup's centre in the Stokes regime, Re = ρU2a/μ = 0.1 (U = 4 and 12 mm/s): the steady
    drag per unit length matches 4πμU / [ln(b/a) − (b² − a²)/(b² + a²)] within ``CLOSED_FORM_TOLERANCE`` on the
    fitting default. The rod
    moves 2 mm on either side of the centre (7 % of the gap's width), and the last 30 % of the run lies many viscous
    times (b − a)²/(π² ν) ≤ 0.1 s after the start. (At 0.5 Pa·s the compressible fluid reads 5.5 % low:
    docs/validation.md.)"""
    rig = Rig()
    speed = 0.1 * mu / (1000.0 * 2 * rig.rod.radius)
    duration = 0.004 / speed
    sim = StirringSimulator(Newtonian(eta=mu), rig, SLICE.replace(pressure=pressure), density=1000.0)
    with torch.no_grad():
        result = sim(translate((speed, 0.0), duration=duration, start=(-0.002, 0.0)))
    steady = -result.force[int(0.7 * len(result.force)):, 0].mean().item()
    assert steady == pytest.approx(translating_rod_force(mu, speed, rig.rod.radius, rig.cup.radius),
                                   rel=CLOSED_FORM_TOLERANCE)


@pytest.mark.parametrize("pressure", ["compressible", "projection"])
def test_time_step_obeys_its_courant_limit_and_substeps_the_viscous_one(pressure):
    """The step keeps the Courant number of the pressure's signal (the sound speed plus the flow's speed; with a
    projection the flow's speed alone); a viscosity whose explicit limit is shorter splits the shear stress into
    substeps within that limit instead of shortening the step (or shortens it, unsplit)."""
    rig = Rig()
    cfg = SLICE.replace(pressure=pressure)
    trajectory = circle(radius=0.015, speed=0.1, duration=1.0)
    u_max = trajectory.max_speed(rig.rod.radius)
    signal = u_max if pressure == "projection" else cfg.sound_speed + u_max
    viscous_limit = cfg.viscous_safety * 1000.0 * cfg.dx**2 / (2 * 2 * 10.0)
    thin = StirringSimulator(Newtonian(eta=0.01), rig, cfg)
    assert thin.time_step(trajectory) <= min(cfg.cfl * cfg.dx / signal, cfg.dt_max) + 1e-12
    assert thin.substeps(trajectory, thin.time_step(trajectory)) == 1
    thick = StirringSimulator(Newtonian(eta=10.0), rig, cfg)
    dt = thick.time_step(trajectory)
    assert dt > viscous_limit
    assert dt / thick.substeps(trajectory, dt) <= viscous_limit + 1e-12
    assert dt / (thick.substeps(trajectory, dt) - 1) > viscous_limit  # the fewest substeps
    unsplit = StirringSimulator(Newtonian(eta=10.0), rig, cfg.replace(viscous_substeps=False))
    assert unsplit.time_step(trajectory) <= viscous_limit + 1e-12
    assert unsplit.substeps(trajectory, unsplit.time_step(trajectory)) == 1
    # the corotated baseline's viscosity is μ Δt: its step is never split
    assert StirringSimulator(Corotated(1e5), rig, cfg).substeps(trajectory, 1e-3) == 1
    # the step divides the duration exactly
    assert (1.0 / dt) == pytest.approx(round(1.0 / dt), abs=1e-6)
    # a bound on the substeps shortens a thick fluid's step to that many viscous limits, not a thin one's
    fewer = thick.substeps(trajectory, dt) - 1
    bounded = cfg.replace(max_substeps=fewer)
    thick_bounded = StirringSimulator(Newtonian(eta=10.0), rig, bounded)
    dt_bounded = thick_bounded.time_step(trajectory)
    assert dt_bounded <= fewer * viscous_limit + 1e-12 and dt_bounded < dt
    assert thick_bounded.substeps(trajectory, dt_bounded) == fewer
    assert StirringSimulator(Newtonian(eta=0.01), rig, bounded).time_step(trajectory) == thin.time_step(trajectory)
    with pytest.raises(ValueError, match="max_substeps"):
        cfg.replace(max_substeps=0)


@pytest.mark.parametrize("pressure", ["compressible", "projection"])
def test_gradient_through_viscous_substeps(pressure):
    """Through a rollout whose shear stress runs in substeps (a viscosity whose explicit limit is a quarter of the step), and
    the projection's carried pressure, reverse mode equals central differences."""
    law = Carreau(eta0=18.0, eta_inf=0.5, lam=0.3, n=0.5, **F64)
    sim = StirringSimulator(law, Rig(), TINY.replace(pressure=pressure), density=1000.0)
    trajectory = circle(radius=0.015, speed=0.05, duration=0.03, ramp_time=0.01)
    assert sim.substeps(trajectory, sim.time_step(trajectory)) == 4
    params = [p for p in law.parameters() if p.requires_grad]
    grads = torch.autograd.grad(_loss(sim, trajectory), params)
    eps = 1e-5
    for p, g in zip(params, grads):
        with torch.no_grad():
            p += eps
            up = _loss(sim, trajectory)
            p -= 2 * eps
            down = _loss(sim, trajectory)
            p += eps
        assert float(g.sum()) == pytest.approx(float((up - down) / (2 * eps)), rel=1e-5, abs=1e-14)


def test_rod_touching_the_wall_is_refused():
    sim = StirringSimulator(Newtonian(eta=0.1), Rig(), TINY)
    with pytest.raises(ValueError, match="touching the wall"):
        sim(circle(radius=0.035, speed=0.05, duration=0.1))


def test_unstable_settings_stop_with_a_clear_error():
    cfg = TINY.replace(dt=2e-2)  # twenty times the acoustic limit
    sim = StirringSimulator(Newtonian(eta=0.5, **F64), Rig(), cfg)
    with pytest.raises(FloatingPointError, match=r"at step \d+ .* Newtonian parameters \{'eta': 0\.[45]"):
        with torch.no_grad():
            sim(circle(radius=0.015, speed=0.05, duration=2.0))


def test_fluid_argument_must_be_a_module():
    with pytest.raises(TypeError, match="rheology law or a material"):
        StirringSimulator(lambda rate: rate, Rig(), TINY)


def test_three_dimensional_rollout_gives_gradients(cache_dir):
    """The paper's resolution (1 cm cells) in 3-D: the gradient of the horizontal force reaches the law."""
    law = Newtonian(eta=0.2)
    cfg = SimConfig(dim=3, dx=0.01, sound_speed=4.5, settle_time=0.2, checkpoint_every=10)
    sim = StirringSimulator(law, Rig(), cfg, density=1000.0, cache_dir=cache_dir)
    result = sim(circle(radius=0.015, speed=0.05, duration=0.02, ramp_time=0.01))
    assert result.force.shape[1] == 3 and torch.isfinite(result.force).all()
    result.force[:, :2].square().sum(-1).mean().backward()
    assert all(torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0 for p in law.parameters())


@pytest.mark.xfail(strict=True, reason="known open defect: on the paper's 1 cm cells the fluid's pressure does not "
                   "carry its column, the particles by the rod's tip are left at a fraction of it and the rod holds "
                   "the fluid mass on its own nodes (docs/validation-rest-3d.md, scripts/rest_pressure_3d.py)")
def test_rod_at_rest_feels_buoyancy_3d(cache_dir):
    cfg = SimConfig(dim=3, dx=0.01, sound_speed=4.5, settle_time=0.2)
    sim = StirringSimulator(Newtonian(eta=0.2), Rig(), cfg, density=1000.0, cache_dir=cache_dir)
    with torch.no_grad():
        result = sim(stationary(0.05))
    rod = Rig().rod
    buoyancy = 1000.0 * 9.81 * math.pi * rod.radius**2 * rod.immersion_depth
    assert result.force[:, 2].mean().item() == pytest.approx(buoyancy, rel=0.02)


def test_a_settling_that_blows_up_is_refused_and_not_cached(tmp_path):
    # eight times the acoustic Courant limit: the settling's explicit step is unstable within a few steps
    cfg = SimConfig(dim=2, dx=0.005, settle_time=0.05, cfl=8.0)
    sim = StirringSimulator(Newtonian(eta=1.0), Rig(), cfg, cache_dir=tmp_path)
    with pytest.raises(FloatingPointError, match="while settling.*sim.cfl"):
        sim.initial_state(stationary(0.01))
    assert not list(tmp_path.rglob("*.pt"))


def test_settled_state_is_cached(cache_dir):
    cfg = SimConfig(dim=3, dx=0.01, sound_speed=4.5, settle_time=0.05)
    trajectory = circle(radius=0.015, speed=0.05, duration=0.01)
    first = StirringSimulator(Newtonian(eta=0.2), Rig(), cfg, cache_dir=cache_dir).initial_state(trajectory)
    assert len(list((cache_dir / "settled").glob("*.pt"))) >= 1
    again = StirringSimulator(Newtonian(eta=5.0), Rig(), cfg, cache_dir=cache_dir).initial_state(trajectory)
    torch.testing.assert_close(first.x, again.x)
