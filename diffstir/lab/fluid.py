"""Fluids of the virtual lab: a rheology law with its parameters, or a tabulated flow curve, and a density.

A fluid is described by a plain mapping (a Hydra config in ``conf/lab/fluid/``):

    name: castor oil                 # label written to the recording's ``fluid`` field
    density: 961.0                   # kg/m^3
    temperature: 25.0                # degC at the start of the recording
    law: {name: newtonian, params: {eta: 0.65}}                      # any law of diffstir.rheology.LAWS, SI
    law: {name: tabulated, flow_curve: caggioni_carbopol_glycerin_temp/T_20}   # a bundled real flow curve
    law: {name: tabulated, shear_rate: [...], viscosity: [...]}      # or stress: [...]; 1/s, Pa·s, Pa
    source: where the values come from
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from diffstir.errors import is_number
from diffstir.rheology import LAWS, RheologyLaw, Tabulated, bundled_flow_curves, make_law


@dataclass(frozen=True)
class Fluid:
    """A virtual fluid: ``law`` spec (mapping, see the module docstring), ``density`` [kg/m³], start
    ``temperature`` [°C], label ``name`` and ``source`` (citation of the values)."""

    name: str
    density: float
    law: Mapping
    temperature: float | None = None
    source: str = ""
    notes: str = ""

    def __post_init__(self) -> None:
        if not (is_number(self.density) and 400.0 <= self.density <= 3000.0):
            raise ValueError(f"fluid.density = {self.density!r}; expected a liquid density in kg/m^3 "
                             f"(400 to 3000; water is 1000)")
        if self.temperature is not None and not (is_number(self.temperature) and -30.0 <= self.temperature <= 120.0):
            raise ValueError(f"fluid.temperature = {self.temperature!r}; expected degrees Celsius (-30 to 120)")
        object.__setattr__(self, "law", dict(self.law))
        if "name" not in self.law:
            raise ValueError(f"fluid.law = {self.law!r} has no 'name'; expected one of "
                             f"{sorted(LAWS) + ['tabulated']}")

    @classmethod
    def from_mapping(cls, cfg: Mapping) -> "Fluid":
        """A Fluid from a config mapping with the fields of this class (unknown keys are refused)."""
        cfg = dict(cfg)
        known = {"name", "density", "law", "temperature", "source", "notes"}
        unknown = sorted(set(cfg) - known)
        if unknown:
            raise ValueError(f"fluid: unknown field(s) {unknown}; expected {sorted(known)}")
        return cls(**cfg)

    def make_law(self) -> RheologyLaw:
        """The viscosity law η(γ̇) [Pa·s] this fluid follows."""
        return make_fluid_law(self.law)


def make_fluid_law(spec: Mapping) -> RheologyLaw:
    """A law from ``{name, params}`` (SI values) or a tabulated flow curve (``flow_curve`` key of
    ``bundled_flow_curves()``, or ``shear_rate`` [1/s] with ``viscosity`` [Pa·s] or ``stress`` [Pa])."""
    spec = dict(spec)
    name = spec.pop("name")
    if name != "tabulated":
        params = dict(spec.pop("params", {}) or {})
        if spec:
            raise ValueError(f"fluid.law: unknown field(s) {sorted(spec)} for law {name!r}; expected name, params")
        return make_law(name, **params)
    if "flow_curve" in spec:
        key = spec.pop("flow_curve")
        curves = bundled_flow_curves()
        if key not in curves:
            raise ValueError(f"fluid.law.flow_curve = {key!r} is not a bundled flow curve; valid: {sorted(curves)}")
        if spec:
            raise ValueError(f"fluid.law: flow_curve excludes the field(s) {sorted(spec)}")
        return Tabulated(curves[key].shear_rate, stress=curves[key].stress)
    unknown = sorted(set(spec) - {"shear_rate", "viscosity", "stress"})
    if unknown or "shear_rate" not in spec:
        raise ValueError(f"fluid.law (tabulated): fields {sorted(spec)}; expected flow_curve, or shear_rate (1/s) "
                         f"with viscosity (Pa s) or stress (Pa)")
    return Tabulated(spec["shear_rate"], stress=spec.get("stress"), viscosity=spec.get("viscosity"))
