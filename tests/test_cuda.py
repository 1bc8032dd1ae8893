"""The simulator on a CUDA device gives the CPU's forces, gradients and sensitivities (skipped without a GPU).

CI has no GPU; these run where one is present (``python -m pytest tests/test_cuda.py``, docs/benchmarks.md records
the last run). Every comparison is in float64, where the two devices differ only by the order of their floating-point
sums (CUDA's scatter-add is atomic, the CPU's sequential): about 1e-16 relative per sum, amplified over the short
rollouts below to far under the 1e-9 asserted; through the projection's pressure solve, whose operator's condition
number is about 1e4 (``tests/test_sensitivity.py``), 1e4 times more (1e-5; an H100 differed from the CPU by up
to 1.1e-9 there, docs/benchmarks.md).
"""

from __future__ import annotations

import pytest
import torch

from diffstir.mpm import Corotated, SimConfig, StirringSimulator, force_sensitivities
from diffstir.rheology import Carreau, HerschelBulkley, Newtonian
from diffstir.rig import Rig
from diffstir.trajectory import circle, stationary

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")

F64 = dict(dtype=torch.float64)
TINY = SimConfig(dim=2, dx=0.005, sound_speed=2.0, dtype="float64", dt=1e-3, checkpoint_every=7)
#: The condition number of the projection's pressure operator (its eigenvalues span 1e4-1e8): its solve amplifies
#: the devices' rounding differences this much more than the compressible step's.
PROJECTION_CONDITION = 1e4
STIR = circle(radius=0.015, speed=0.05, duration=0.03, ramp_time=0.01)


def _run(make_fluid, config: SimConfig, device: str, trajectory=STIR, cache_dir=None):
    """Forces, torques and the gradient of a loss with respect to every parameter, on ``device``."""
    fluid = make_fluid()
    sim = StirringSimulator(fluid, Rig(), config.replace(device=device), density=1000.0, cache_dir=cache_dir)
    result = sim(trajectory)
    assert result.force.device.type == torch.device(device).type
    loss = (result.force**2).sum(-1).mean() + result.torque.square().mean()
    params = [p for p in sim.parameters() if p.requires_grad]
    grads = torch.autograd.grad(loss, params)
    return result.force.detach().cpu(), result.torque.detach().cpu(), [g.cpu() for g in grads]


def _assert_same(cpu, cuda, conditioning: float = 1.0):
    """Forces, torques and gradients agree to 1e-9 relative, times the ``conditioning`` of a solve in the step."""
    for a, b in zip(cpu[:2], cuda[:2]):
        torch.testing.assert_close(b, a, rtol=1e-9 * conditioning, atol=1e-12 * conditioning)
    for a, b in zip(cpu[2], cuda[2]):
        torch.testing.assert_close(b, a, rtol=1e-9 * conditioning, atol=1e-15 * conditioning)


@pytest.mark.parametrize("numerics", [dict(), dict(pressure="projection"), dict(wall_pressure=True)],
                         ids=["compressible", "projection", "wall_pressure"])
@pytest.mark.parametrize("make_fluid", [
    lambda: Carreau(eta0=1.0, eta_inf=0.05, lam=0.3, n=0.5, **F64),
    lambda: HerschelBulkley(tau_y=0.05, k=0.5, n=0.8, shear_rate_reg=0.5, **F64),
    lambda: Corotated(shear_modulus=400.0).double(),
], ids=["carreau", "herschel_bulkley", "corotated"])
def test_a_2d_stir_on_cuda_equals_the_cpu(make_fluid, numerics):
    config = TINY.replace(**numerics)
    _assert_same(_run(make_fluid, config.replace(kernels="torch"), "cpu"),
                 _run(make_fluid, config.replace(kernels="auto"), "cuda"),
                 conditioning=PROJECTION_CONDITION if config.pressure == "projection" else 1.0)


def test_a_3d_stir_on_cuda_equals_the_cpu(tmp_path):
    """The paper's 1 cm grid in 3-D, settled on each device, then stirred: the settled fluids, the forces and the
    gradients agree (the settling runs 0.05 s, so its rounding stays far below the tolerance too)."""
    config = SimConfig(dim=3, dx=0.01, sound_speed=4.5, settle_time=0.05, dtype="float64", checkpoint_every=10,
                       kernels="torch")
    trajectory = circle(radius=0.015, speed=0.05, duration=0.02, ramp_time=0.01)
    runs = [_run(lambda: Newtonian(eta=0.2, **F64), config, device, trajectory, tmp_path / device)
            for device in ("cpu", "cuda")]
    _assert_same(*runs)


def test_the_settled_cache_written_on_one_device_loads_on_the_other(tmp_path):
    config = SimConfig(dim=3, dx=0.01, sound_speed=4.5, settle_time=0.02, dtype="float64")
    trajectory = stationary(0.01)
    on_cpu = StirringSimulator(Newtonian(eta=0.2, **F64), Rig(), config, cache_dir=tmp_path).initial_state(trajectory)
    on_cuda = StirringSimulator(Newtonian(eta=0.2, **F64), Rig(), config.replace(device="cuda"),
                                cache_dir=tmp_path).initial_state(trajectory)
    assert on_cuda.x.device.type == "cuda"
    torch.testing.assert_close(on_cuda.x.cpu(), on_cpu.x, rtol=0, atol=0)


def test_forward_mode_sensitivities_on_cuda_equal_the_cpu():
    jacobians = []
    for device in ("cpu", "cuda"):
        law = Carreau(eta0=1.0, eta_inf=0.05, lam=0.3, n=0.5, **F64)
        sim = StirringSimulator(law, Rig(), TINY.replace(device=device, kernels="torch"), density=1000.0)
        jacobians.append(force_sensitivities(sim, STIR).force_jacobian.cpu())
    torch.testing.assert_close(jacobians[1], jacobians[0], rtol=1e-9, atol=1e-12 * float(jacobians[0].abs().max()))


def test_a_float32_stir_on_cuda_agrees_with_float64():
    """The default precision on the GPU: the mean drag of a short stir within 1e-4 of float64's (float32 carries
    about 1e-7 per operation; the rollout's few hundred steps amplify it well under that)."""
    forces = {}
    for dtype in ("float32", "float64"):
        law = Newtonian(eta=0.5, dtype=getattr(torch, dtype))
        config = TINY.replace(device="cuda", dtype=dtype)
        with torch.no_grad():
            forces[dtype] = StirringSimulator(law, Rig(), config).forward(STIR).force.double().norm(dim=1).mean()
    assert float(forces["float32"]) == pytest.approx(float(forces["float64"]), rel=1e-4)
