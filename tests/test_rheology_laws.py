"""Rheology laws: closed-form values, limits, parametrisation, gradients, dtype/device, time-step bound."""

import math

import numpy as np
import pytest
import torch
from torch.func import functional_call

from diffstir.rheology import (
    LAWS,
    Bingham,
    Carreau,
    Cross,
    HerschelBulkley,
    Newtonian,
    PowerLaw,
    RheologyLaw,
    Tabulated,
    make_law,
)
from diffstir.rheology.parameters import BoundedParameter, from_raw, to_raw

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
DTYPES = [torch.float32, torch.float64]
F64 = torch.float64

# One law of each family with interior, non-default values; HB and Carreau also shear-thickening variants.
CASES = {
    "newtonian": dict(eta=0.37),
    "power_law": dict(k=2.5, n=0.4, shear_rate_reg=0.02),
    "carreau": dict(eta0=12.0, eta_inf=0.05, lam=0.8, n=0.35),
    "cross": dict(eta0=12.0, eta_inf=0.05, lam=0.8, n=0.7),
    "herschel_bulkley": dict(tau_y=4.0, k=1.5, n=0.6, shear_rate_reg=0.01),
    "bingham": dict(tau_y=4.0, eta_p=0.2, shear_rate_reg=0.01),
}
THICKENING = {
    "power_law": dict(k=0.5, n=1.6),
    "carreau": dict(eta0=0.5, eta_inf=20.0, lam=2.0, n=0.4),  # eta_inf > eta0, as in the paper's Table II
    "carreau_n_above_1": dict(eta0=0.5, eta_inf=0.01, lam=2.0, n=1.7),
    "cross": dict(eta0=0.5, eta_inf=20.0, lam=2.0, n=1.2),
    "herschel_bulkley": dict(tau_y=0.3, k=0.5, n=1.8),
}


def build(name: str, dtype=F64, device="cpu", **overrides) -> RheologyLaw:
    values = {**CASES.get(name, {}), **overrides}
    return make_law(name, dtype=dtype, device=device, **values)


def rates(*values: float, dtype=F64) -> torch.Tensor:
    return torch.tensor(values, dtype=dtype)


def evaluate(fn, g: np.ndarray) -> np.ndarray:
    """``fn`` (a law or its ``stress``) at float64 shear rates ``g`` [1/s], as a numpy array."""
    with torch.no_grad():
        return fn(torch.from_numpy(np.asarray(g, dtype=np.float64))).numpy()


# --- closed-form values --------------------------------------------------------------------------------------------

G = (0.0, 1e-3, 0.3, 2.0, 75.0)


def _hand(name: str, g: float) -> float:
    """eta [Pa·s] of CASES[name] at g [1/s], written out independently of the library."""
    p = CASES[name]
    if name == "newtonian":
        return p["eta"]
    if name == "power_law":
        return p["k"] * (g**2 + p["shear_rate_reg"] ** 2) ** ((p["n"] - 1) / 2)
    if name == "carreau":
        return p["eta_inf"] + (p["eta0"] - p["eta_inf"]) * (1 + (p["lam"] * g) ** 2) ** ((p["n"] - 1) / 2)
    if name == "cross":
        return p["eta_inf"] + (p["eta0"] - p["eta_inf"]) / (1 + (p["lam"] * g) ** p["n"])
    gc = p["shear_rate_reg"]
    yield_part = p["tau_y"] / gc if g == 0.0 else p["tau_y"] * (1 - math.exp(-g / gc)) / g
    if name == "herschel_bulkley":
        return yield_part + p["k"] * (g**2 + gc**2) ** ((p["n"] - 1) / 2)
    return yield_part + p["eta_p"]


@pytest.mark.parametrize("name", CASES)
def test_closed_form_values(name):
    law = build(name)
    expected = torch.tensor([_hand(name, g) for g in G], dtype=F64)
    torch.testing.assert_close(law(rates(*G)), expected, rtol=1e-13, atol=0.0)
    torch.testing.assert_close(law.stress(rates(*G)), expected * rates(*G), rtol=1e-13, atol=0.0)
    assert law.zero_shear_viscosity().item() == pytest.approx(_hand(name, 0.0), rel=1e-13)


def test_papanastasiou_factor_matches_series_and_exact_form_across_the_switch():
    # (1 - exp(-x))/x is evaluated by a Taylor series below x = 1e-2 and exactly above; both sides of the switch
    # must agree with an independent high-precision evaluation (math.expm1) to float64 round-off.
    law = Bingham(tau_y=1.0, eta_p=1e-3, shear_rate_reg=1.0, dtype=F64)
    p = law.parameters_si()
    x = np.array([1e-12, 1e-6, 9.99e-3, 1e-2, 1.001e-2, 0.5, 40.0, 800.0])
    expected = p["tau_y"] * -np.expm1(-x) / x + p["eta_p"]
    torch.testing.assert_close(law(torch.from_numpy(x)), torch.from_numpy(expected), rtol=1e-14, atol=0.0)


# --- limits --------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["carreau", "cross"])
def test_plateau_laws_tend_to_eta0_and_eta_inf(name):
    p = CASES[name]
    law = build(name)
    span = abs(p["eta0"] - p["eta_inf"])
    low = np.array([1e-9, 1e-7, 1e-5]) / p["lam"]
    high = np.array([1e5, 1e7, 1e9]) / p["lam"]
    eta_low = evaluate(law, low)
    eta_high = evaluate(law, high)
    if name == "carreau":
        # 1 - (1 + x^2)^(-a) <= a x^2 and (1 + x^2)^(-a) <= x^(-2a), with a = (1 - n)/2 and x = lam g.
        a = (1 - p["n"]) / 2
        bound_low = span * a * (p["lam"] * low) ** 2
        bound_high = span * (p["lam"] * high) ** (-2 * a)
    else:
        # 1 - 1/(1 + u) <= u and 1/(1 + u) <= 1/u, with u = (lam g)^n.
        bound_low = span * (p["lam"] * low) ** p["n"]
        bound_high = span * (p["lam"] * high) ** (-p["n"])
    eps = 4 * np.finfo(float).eps * p["eta0"]
    assert np.all(np.abs(eta_low - p["eta0"]) <= bound_low + eps)
    assert np.all(np.abs(eta_high - p["eta_inf"]) <= bound_high + eps)


def test_power_law_is_k_g_to_n_minus_1_far_above_the_regularisation_rate():
    law = build("power_law")
    p = {**law.parameters_si(), "shear_rate_reg": law.shear_rate_reg}
    g = p["shear_rate_reg"] * np.array([1e2, 1e3, 1e5])
    eta = evaluate(law, g)
    ideal = p["k"] * g ** (p["n"] - 1)
    # |(1 + e)^a - 1| <= |a| e for |a| <= 1 (Bernoulli), with e = (g_c/g)^2 and a = (n - 1)/2; plus round-off.
    bound = abs(p["n"] - 1) / 2 * (p["shear_rate_reg"] / g) ** 2 + 1e-14
    assert np.all(np.abs(eta / ideal - 1) <= bound)
    assert law.zero_shear_viscosity().item() == pytest.approx(p["k"] * p["shear_rate_reg"] ** (p["n"] - 1), rel=1e-14)


@pytest.mark.parametrize("name", ["herschel_bulkley", "bingham"])
def test_yield_stress_laws_finite_at_rest_and_stress_tends_to_tau_y(name):
    p = CASES[name]
    gc = p["shear_rate_reg"]
    law = build(name)
    eta0 = law.zero_shear_viscosity()
    assert torch.isfinite(eta0)
    viscous_at_rest = p["k"] * gc ** (p["n"] - 1) if name == "herschel_bulkley" else p["eta_p"]
    assert eta0.item() == pytest.approx(p["tau_y"] / gc + viscous_at_rest, rel=1e-14)

    # On the regularised scale g >> g_c the stress is tau_y + viscous part, to relative order exp(-g/g_c) and
    # (g_c/g)^2, and tends to tau_y as g -> 0+.
    g = gc * np.array([1e4, 1e3, 1e2])
    stress = evaluate(law.stress, g)
    viscous = p["k"] * g ** p["n"] if name == "herschel_bulkley" else p["eta_p"] * g
    ideal = p["tau_y"] + viscous
    bound = p["tau_y"] * np.exp(-g / gc) + viscous * (1 - p.get("n", 1.0)) / 2 * (gc / g) ** 2 + 1e-13 * ideal
    assert np.all(np.abs(stress - ideal) <= bound)
    assert np.all(np.diff(np.abs(stress - p["tau_y"])) < 0)  # closer to tau_y as g decreases
    assert abs(stress[-1] - p["tau_y"]) <= viscous[-1] * (1 + 1e-3)


def test_cross_with_vanishing_exponent_is_newtonian_above_zero_shear():
    law = Cross(eta0=2.0, eta_inf=0.4, lam=1.0, n=0.01, dtype=F64)
    g = np.logspace(-2, 2, 9)
    # eta - (eta0 + eta_inf)/2 = (eta0 - eta_inf) (1/(1 + u) - 1/2) with u = (lam g)^n, and |1/(1 + u) - 1/2|
    # <= |u - 1|/4 for u > 0; here |u - 1| <= exp(n |log(lam g)|) - 1 <= exp(0.01 log 100) - 1.
    bound = (2.0 - 0.4) * (math.exp(0.01 * math.log(100.0)) - 1) / 4
    assert np.all(np.abs(evaluate(law, g) - 1.2) <= bound)
    assert bound < 0.02


def test_carreau_never_turns_negative_when_it_falls_from_eta_inf():
    # eta_inf > eta0 with n > 1: eta_inf + (eta0 - eta_inf) sqrt(1 + (lam g)^2) falls without bound; eta is floored
    # at 0 there and follows the formula until then (the fit's blow-up at eta0 0.37, eta_inf 3.76, lam 1.16, n 2)
    law = Carreau(eta0=0.37, eta_inf=3.76, lam=1.16, n=2.0, dtype=F64)
    g = np.logspace(-2, 3, 51)
    formula = 3.76 + (0.37 - 3.76) * np.sqrt(1.0 + (1.16 * g) ** 2)
    assert np.all(evaluate(law, g) >= 0.0)
    assert np.allclose(evaluate(law, g)[formula > 0], formula[formula > 0], rtol=1e-6)


# --- parametrisation -----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("name", LAWS)
def test_set_and_get_parameters_round_trip(name, dtype):
    law = build(name, dtype=dtype)
    rng = np.random.default_rng(7)
    for _ in range(5):
        values = {}
        for key, (lo, hi) in law.bounds().items():
            u = rng.uniform(0.02, 0.98)
            scale = law.params[key].scale
            values[key] = lo * (hi / lo) ** u if scale == "log" else lo + (hi - lo) * u
        law.set_parameters_si(**values)
        got = law.parameters_si()
        for key, value in values.items():
            lo, hi = law.bounds()[key]
            # The value is rebuilt from log lo + (log hi - log lo) sigmoid(raw) (or the linear analogue): a few
            # rounding errors of the dtype on numbers of size |log lo| + |log hi| (or |lo| + |hi|).
            if law.params[key].scale == "log":
                size = abs(math.log(lo)) + abs(math.log(hi))
            else:
                size = (abs(lo) + abs(hi)) / value
            rtol = 8 * torch.finfo(dtype).eps * size
            assert got[key] == pytest.approx(value, rel=rtol), key


@pytest.mark.parametrize("name", LAWS)
def test_out_of_bounds_value_raises_naming_parameter_value_bounds_and_unit(name):
    law = build(name)
    key, spec = next(iter(law.specs.items()))
    lo, hi = law.bounds()[key]
    before = law.parameters_si()
    with pytest.raises(ValueError) as error:
        law.set_parameters_si(**{key: 10 * hi})
    message = str(error.value)
    assert key in message and f"{10 * hi:g}" in message and f"{lo:g}" in message and f"{hi:g}" in message
    assert spec.unit in message
    assert law.parameters_si() == before
    with pytest.raises(ValueError, match=key):
        make_law(name, **{key: lo / 10})
    with pytest.raises(ValueError, match="valid"):
        law.set_parameters_si(not_a_parameter=1.0)


def test_set_parameters_is_atomic():
    law = Carreau()
    before = law.parameters_si()
    with pytest.raises(ValueError, match="n = 5"):
        law.set_parameters_si(eta0=3.0, n=5.0)
    assert law.parameters_si() == before


def test_a_value_read_back_on_a_bound_is_the_bound():
    # a fit that ends on a bound reads its value back through float32 parameters, a few ulps outside
    law = Carreau(bounds={"eta0": (1.0, 10.0)})
    law.set_parameters_si(eta0=float(np.float32(10.0) * (1 + 2 * np.finfo(np.float32).eps)))
    assert law.parameters_si()["eta0"] == pytest.approx(10.0, rel=1e-6)
    with pytest.raises(ValueError, match="outside its bounds"):
        law.set_parameters_si(eta0=10.01)  # a real excursion is still refused


def test_bounds_override():
    law = Carreau(eta0=5.0, bounds={"eta0": (1.0, 10.0)})
    assert law.bounds()["eta0"] == (1.0, 10.0)
    assert law.bounds()["lam"] == (1e-4, 1e3)
    with pytest.raises(ValueError, match=r"eta0 = 20 Pa·s is outside its bounds \[1, 10\] Pa·s"):
        law.set_parameters_si(eta0=20.0)
    with pytest.raises(ValueError, match="unknown parameter"):
        Carreau(bounds={"tau_y": (1.0, 2.0)})
    with pytest.raises(ValueError, match="lo > 0"):
        Carreau(bounds={"eta0": (0.0, 2.0)})
    with pytest.raises(ValueError, match="lo < hi"):
        Carreau(bounds={"eta0": (3.0, 2.0)})


def test_bounded_parameter_maps_every_raw_inside_its_bounds():
    raw = torch.tensor([-1e3, -40.0, -1.0, 0.0, 2.0, 40.0, 1e3], dtype=F64)
    for scale, lo, hi in (("log", 1e-4, 1e3), ("linear", 0.05, 2.0)):
        value = from_raw(raw, lo, hi, scale)
        assert torch.all((value >= lo) & (value <= hi))
        for v in (lo, hi, math.sqrt(lo * hi)):
            assert math.isfinite(to_raw(v, lo, hi, scale))
    p = BoundedParameter("lam", 1e3, (1e-4, 1e3), "log", "s")
    assert p().item() == pytest.approx(1e3, rel=1e-6)


@pytest.mark.parametrize("name", LAWS)
def test_gradients_match_finite_differences(name):
    law = build(name)
    g = rates(0.0, 3e-3, 0.01, 0.2, 3.0, 50.0)
    names = [key for key, _ in law.named_parameters()]
    raws = tuple(p.detach().clone().requires_grad_(True) for _, p in law.named_parameters())

    def eta(*raw):
        return functional_call(law, dict(zip(names, raw)), (g,))

    assert torch.autograd.gradcheck(eta, raws, eps=1e-6, atol=1e-7, rtol=1e-6)
    g_pos = g[1:].clone().requires_grad_(True)
    assert torch.autograd.gradcheck(law, (g_pos,), eps=1e-7, atol=1e-7, rtol=1e-6)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("name", LAWS)
def test_gradients_finite_and_nonzero_at_interior_points(name, dtype):
    law = build(name, dtype=dtype)
    law(torch.tensor([0.0, 0.5, 1.0, 20.0], dtype=dtype)).sum().backward()
    for key, param in law.named_parameters():
        assert torch.isfinite(param.grad) and param.grad != 0, key


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("name", LAWS)
def test_output_keeps_shape_dtype_and_device(name, dtype, device):
    law = build(name, dtype=dtype, device=device)
    g = torch.rand(3, 4, 5, dtype=dtype, device=device) * 10
    for out in (law(g), law.stress(g)):
        assert out.shape == g.shape and out.dtype == dtype and out.device == g.device
    assert law.zero_shear_viscosity().dtype == dtype
    # A float32 law evaluated at float64 shear rates computes in float64.
    assert build(name, dtype=torch.float32, device=device)(g.double()).dtype == F64


def test_integer_shear_rate_is_rejected():
    with pytest.raises(TypeError, match="floating-point"):
        Newtonian()(torch.tensor([1, 2]))


# --- time-step bound -----------------------------------------------------------------------------------------------

ALL_CASES = [(name, CASES[name]) for name in CASES] + [
    (name.removesuffix("_n_above_1"), values) for name, values in THICKENING.items()
]


@pytest.mark.parametrize("name,values", ALL_CASES)
def test_max_viscosity_bounds_eta_on_dense_grid(name, values):
    law = make_law(name, dtype=F64, **values)
    for g_max in (0.0, 0.05, 10.0, 1e3):
        grid = torch.cat([torch.zeros(1, dtype=F64), torch.logspace(-8, 0, 4000, dtype=F64) * g_max])
        bound = law.max_viscosity(g_max)
        assert isinstance(bound, float)
        assert bound >= law(grid).max().item() * (1 - 1e-12)
        assert bound <= 1.5 * law(grid).max().item()  # an upper bound, but not a loose one
    with pytest.raises(ValueError, match="shear_rate_max"):
        law.max_viscosity(-1.0)


def test_yield_stress_max_viscosity_is_tau_y_over_g_c():
    law = HerschelBulkley(tau_y=10.0, k=0.1, n=0.5, shear_rate_reg=1e-3, dtype=F64)
    expected = 10.0 / 1e-3 + 0.1 * 1e-3 ** (0.5 - 1)
    assert law.max_viscosity(100.0) == pytest.approx(expected, rel=1e-12)


# --- tabulated -----------------------------------------------------------------------------------------------------


def test_tabulated_interpolates_log_log_and_holds_the_ends():
    g = [0.1, 1.0, 10.0]
    eta = [100.0, 10.0, 4.0]
    law = Tabulated(g, viscosity=eta)
    same = Tabulated(g[::-1], stress=[e * r for e, r in zip(eta, g)][::-1])
    x = torch.tensor([0.0, 0.01, 0.1, math.sqrt(0.1), 1.0, math.sqrt(10.0), 10.0, 1e4], dtype=F64)
    expected = torch.tensor([100.0, 100.0, 100.0, math.sqrt(1000.0), 10.0, math.sqrt(40.0), 4.0, 4.0], dtype=F64)
    torch.testing.assert_close(law(x), expected, rtol=1e-13, atol=0.0)
    torch.testing.assert_close(same(x), expected, rtol=1e-13, atol=0.0)
    assert law(x.float()).dtype == torch.float32
    assert list(law.parameters()) == [] and law.parameters_si() == {}
    assert law.max_viscosity(5.0) == pytest.approx(100.0)
    assert Tabulated(g, viscosity=[1.0, 5.0, 2.0]).max_viscosity(3.0) == pytest.approx(5.0)
    assert Tabulated(g, viscosity=[1.0, 5.0, 2.0]).max_viscosity(0.5) < 5.0
    with pytest.raises(ValueError, match="repeated"):
        Tabulated([1.0, 1.0, 2.0], viscosity=[1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="exactly one"):
        Tabulated(g)
    with pytest.raises(ValueError, match=r"shear_rate must be finite and > 0 in 1/s"):
        Tabulated([0.0, 1.0], viscosity=[1.0, 2.0])


# --- registry and repr ---------------------------------------------------------------------------------------------


def test_registry_names_and_classes():
    assert LAWS == {
        "newtonian": Newtonian,
        "power_law": PowerLaw,
        "carreau": Carreau,
        "cross": Cross,
        "herschel_bulkley": HerschelBulkley,
        "bingham": Bingham,
    }
    for name, cls in LAWS.items():
        assert cls.name == name and set(cls.units) == set(cls.specs)
    assert Carreau.units == {"eta0": "Pa·s", "eta_inf": "Pa·s", "lam": "s", "n": "1"}


def test_unknown_law_name_lists_valid_names():
    with pytest.raises(ValueError) as error:
        make_law("casson")
    for name in LAWS:
        assert name in str(error.value)


def test_repr_shows_si_values_and_units():
    assert repr(Carreau(eta0=1.2, eta_inf=0.01, lam=0.5, n=0.6)) == (
        "Carreau(eta0=1.2 Pa·s, eta_inf=0.01 Pa·s, lam=0.5 s, n=0.6)"
    )
    assert repr(HerschelBulkley(tau_y=3.0, k=2.0, n=0.5, dtype=F64)) == (
        "HerschelBulkley(tau_y=3 Pa, k=2 Pa·s^n, n=0.5, shear_rate_reg=0.01 1/s)"
    )
    assert "1/s" in repr(Tabulated([1.0, 2.0], viscosity=[3.0, 4.0]))


def test_regularisation_rate_must_be_positive():
    with pytest.raises(ValueError, match="shear_rate_reg"):
        PowerLaw(shear_rate_reg=0.0)
