"""Forward-mode sensitivities of the force: against central differences and the plain rollout."""

from __future__ import annotations

import pytest
import torch

from diffstir.mpm import Corotated, SimConfig, StirringSimulator, force_sensitivities
from diffstir.rheology import Bingham, Carreau, Cross, HerschelBulkley, Newtonian, PowerLaw
from diffstir.rig import Rig
from diffstir.trajectory import circle

F64 = dict(dtype=torch.float64)
TINY = SimConfig(dim=2, dx=0.005, sound_speed=2.0, dtype="float64", dt=1e-3)
TRAJECTORY = circle(radius=0.015, speed=0.05, duration=0.03, ramp_time=0.01)
LAWS = [
    lambda: Newtonian(eta=0.5, **F64),
    lambda: PowerLaw(k=0.8, n=0.7, **F64),
    lambda: Carreau(eta0=1.0, eta_inf=0.05, lam=0.3, n=0.5, **F64),
    lambda: Cross(eta0=1.0, eta_inf=0.05, lam=0.2, n=0.8, **F64),
    lambda: HerschelBulkley(tau_y=0.05, k=0.5, n=0.8, shear_rate_reg=0.5, **F64),
    lambda: Bingham(tau_y=0.05, eta_p=0.4, shear_rate_reg=0.5, **F64),
]


def _force(sim) -> torch.Tensor:
    with torch.no_grad():
        return sim(TRAJECTORY).force


# every law with the compressible fluid; through the projection's pressure solve (whose derivative does not depend
# on the law) the law with the most parameters
CASES = [(make, "compressible") for make in LAWS] + [(LAWS[2], "projection")]


@pytest.mark.parametrize("make_law, pressure", CASES, ids=lambda case: case().name if callable(case) else case)
def test_sensitivities_match_central_differences_in_each_si_parameter(make_law, pressure):
    law = make_law()
    sim = StirringSimulator(law, Rig(), TINY.replace(pressure=pressure), density=1000.0)
    sens = force_sensitivities(sim, TRAJECTORY)
    torch.testing.assert_close(sens.force, _force(sim), rtol=0, atol=0)  # the dual rollout's primal is the rollout
    values = law.parameters_si()
    assert sens.names == [f"{name} [{law.units[name]}]" for name in values]
    # central differences carry O(h²) truncation and rounding of about κ 1e-16 |F| / h, κ the condition number of
    # what the step solves: 1 for the compressible fluid, about 1e4 for the projection's pressure (its operator's
    # eigenvalues span 1e4-1e8), so the projection takes a larger relative step h
    relative_step = 1e-6 if pressure == "compressible" else 1e-4
    for j, (name, value) in enumerate(values.items()):
        step = relative_step * value
        law.set_parameters_si(**{name: value + step})
        up = _force(sim)
        law.set_parameters_si(**{name: value - step})
        down = _force(sim)
        law.set_parameters_si(**{name: value})
        central = (up - down) / (2 * step)
        # both far below 1e-6 of the scale
        scale = central.abs().max()
        assert scale > 0
        torch.testing.assert_close(sens.force_jacobian[..., j], central, rtol=0, atol=1e-6 * float(scale))


def test_a_plain_parameter_keeps_its_name_and_raw_units():
    material = Corotated(shear_modulus=400.0).double()
    sim = StirringSimulator(material, Rig(), TINY, density=1000.0)
    sens = force_sensitivities(sim, TRAJECTORY, ["material.log_shear_modulus"])
    assert sens.names == ["material.log_shear_modulus"] and sens.force_jacobian.shape == (*sens.force.shape, 1)
    eps = 1e-6
    with torch.no_grad():
        material.log_shear_modulus += eps
        up = _force(sim)
        material.log_shear_modulus -= 2 * eps
        down = _force(sim)
        material.log_shear_modulus += eps
    central = (up - down) / (2 * eps)
    torch.testing.assert_close(sens.force_jacobian[..., 0], central, rtol=0, atol=1e-6 * float(central.abs().max()))


def test_an_unknown_parameter_is_refused_with_the_known_ones():
    sim = StirringSimulator(Newtonian(eta=0.5, **F64), Rig(), TINY, density=1000.0)
    with pytest.raises(ValueError, match=r"unknown parameters \['eta'\].*params\.eta\.raw"):
        force_sensitivities(sim, TRAJECTORY, ["eta"])
