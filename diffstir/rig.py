"""The stirring rig: a cylindrical cup, a vertical rod, and the paper's dimensions.

Frames and units: the cup frame has its origin on the cup's axis at the inner bottom, z up; all lengths in m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from .errors import is_number


@dataclass(frozen=True)
class Cup:
    """A cylindrical cup.

    Attributes:
        radius: inner radius [m].
        fill_height: depth of the fluid at rest, rod immersed [m].
        height: inner height of the cup [m]; only sets the grid's headroom.
        wall: ``"no_slip"`` or ``"slip"`` condition on the wall and the bottom.
    """

    radius: float = 0.0425
    fill_height: float = 0.130
    height: float = 0.165
    wall: str = "no_slip"

    def __post_init__(self) -> None:
        _positive("cup.radius", self.radius, "m")
        _positive("cup.fill_height", self.fill_height, "m")
        if self.fill_height > self.height:
            raise ValueError(f"cup.fill_height = {self.fill_height} m exceeds cup.height = {self.height} m")
        if self.wall not in ("no_slip", "slip"):
            raise ValueError(f"cup.wall = {self.wall!r}; expected 'no_slip' or 'slip'")
        if self.radius > 1.0:
            raise ValueError(f"cup.radius = {self.radius} m looks like millimetres; lengths are in metres")

    @property
    def fill_volume(self) -> float:
        """Fluid volume at rest [m³], ignoring the rod's displacement."""
        return math.pi * self.radius**2 * self.fill_height

    @classmethod
    def from_fill_volume(cls, radius: float, fill_volume: float, **kwargs) -> "Cup":
        """A cup filled with ``fill_volume`` [m³] of fluid."""
        return cls(radius=radius, fill_height=fill_volume / (math.pi * radius**2), **kwargs)


@dataclass(frozen=True)
class Rod:
    """A vertical stirring rod: a cylinder, or any closed mesh (a spoon, a paddle) given by ``mesh``.

    Attributes:
        radius: cylinder radius [m] (for a mesh: the radius of its bounding cylinder, used for clearance checks).
        immersion_depth: depth of the rod's tip below the free surface at rest [m].
        length: total length [m]; only the immersed part matters to the fluid.
        wall: ``"no_slip"`` or ``"slip"`` condition on the rod's surface.
        mesh: path of a closed mesh in the rod frame (metres, tip at z = 0, axis along z), or None for a cylinder.
        slip_length: Navier slip length b [m] of a ``"no_slip"`` wall: the fluid slides along the rod at
            u_slip = b ∂u_t/∂n; 0 (the default) is no-slip.
    """

    radius: float = 0.0125
    immersion_depth: float = 0.080
    length: float = 0.200
    wall: str = "no_slip"
    mesh: str | None = None
    slip_length: float = 0.0

    def __post_init__(self) -> None:
        _positive("rod.radius", self.radius, "m")
        _positive("rod.immersion_depth", self.immersion_depth, "m")
        if self.wall not in ("no_slip", "slip"):
            raise ValueError(f"rod.wall = {self.wall!r}; expected 'no_slip' or 'slip'")
        if not (is_number(self.slip_length) and 0 <= self.slip_length <= 0.1):
            raise ValueError(f"rod.slip_length = {self.slip_length!r}; expected a Navier slip length in m, "
                             f"0 <= b <= 0.1 (0 is no-slip)")
        if self.slip_length > 0 and self.wall == "slip":
            raise ValueError("rod.slip_length > 0 needs rod.wall = 'no_slip'; a 'slip' wall already slips freely")
        if self.radius > 0.5:
            raise ValueError(f"rod.radius = {self.radius} m looks like millimetres; lengths are in metres")


@dataclass(frozen=True)
class Rig:
    """Cup, rod and gravity. Defaults are the paper's rig: an 8.5 cm PET cup, 16.5 cm tall, filled with
    738 ml, and a 2.5 cm wooden rod immersed 8 cm."""

    cup: Cup = field(default_factory=lambda: Cup.from_fill_volume(0.0425, 738e-6, height=0.165))
    rod: Rod = field(default_factory=Rod)
    gravity: float = 9.81  # m/s²

    def __post_init__(self) -> None:
        if self.rod.radius >= self.cup.radius:
            raise ValueError(
                f"rod.radius = {self.rod.radius} m is not smaller than cup.radius = {self.cup.radius} m"
            )
        if self.rod.immersion_depth >= self.cup.fill_height:
            raise ValueError(
                f"rod.immersion_depth = {self.rod.immersion_depth} m reaches the cup's bottom "
                f"(fill_height = {self.cup.fill_height} m)"
            )

    @property
    def rod_tip_height(self) -> float:
        """Height of the rod's tip above the cup's bottom at rest [m]."""
        return self.cup.fill_height - self.rod.immersion_depth

    @property
    def max_rod_offset(self) -> float:
        """Largest distance of the rod's axis from the cup's axis that keeps the rod off the wall [m]."""
        return self.cup.radius - self.rod.radius


def _positive(name: str, value: float, unit: str) -> None:
    if not (is_number(value) and value > 0):
        raise ValueError(f"{name} = {value!r}; expected a positive number in {unit}")
