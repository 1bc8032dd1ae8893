"""Settings of the MLS-MPM stirring simulation."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import torch


@dataclass(frozen=True)
class SimConfig:
    """Resolution, time stepping and numerics of a stirring simulation.

    Attributes:
        dim: 2 for a horizontal slice of the cup (plane flow, forces per unit length of rod, no gravity),
            3 for the full rig (free surface, gravity, the rod's tip).
        dx: grid cell size [m].
        particles_per_cell: particles per cell along each axis (the cell holds this to the power ``dim``).
        sound_speed: speed of sound of the weakly compressible fluid [m/s]; the bulk modulus is
            ``density * sound_speed**2``. Keep it at least ten times the fastest flow (Mach < 0.1); in 3-D also high
            enough that the hydrostatic compression ``density * g * fill_height / bulk_modulus`` stays small.
        cfl: acoustic Courant number, ``dt <= cfl * dx / (sound_speed + max rod speed)``.
        viscous_safety: fraction of the explicit viscous limit ``density * dx**2 / (2 * dim * eta_max)`` used.
        viscosity_cap: the largest apparent viscosity simulated [Pa·s]; a law's viscosity above it is clamped (the
            bi-viscous regularisation of yield-stress plugs), so that its time step stays finite.
        dt_max: the largest time step [s].
        dt: a fixed time step [s]; None chooses it from the limits above at the start of each rollout.
        headroom: grid space above the fluid's surface at rest [m], for the surface's rise while stirring.
        settle_time: time the fluid is left to settle under gravity before a 3-D rollout [s].
        checkpoint_every: steps per gradient-checkpoint segment; 0 keeps every step's graph (more memory).
        dtype: ``"float32"`` or ``"float64"``.
        device: torch device string, e.g. ``"cpu"`` or ``"cuda"``.
        compile: run each step through ``torch.compile`` (inductor, static shapes, scalar C++ kernels). Costs
            tens of seconds of compilation per scene, law type and time step, then steps run about 1.2x faster
            than eager on the paper's 3-D scene and 2.3-2.9x on the 2-D default, forward and forward + backward,
            on the 2-core CPU (docs/benchmarks.md); worth it for long rollouts and repeated fits of one scene, not
            for a one-off short simulation.
    """

    dim: Literal[2, 3] = 3
    dx: float = 0.005
    particles_per_cell: int = 2
    sound_speed: float = 10.0
    cfl: float = 0.4
    viscous_safety: float = 0.9
    viscosity_cap: float = 20.0
    dt_max: float = 1e-3
    dt: float | None = None
    headroom: float = 0.02
    settle_time: float = 0.3
    checkpoint_every: int = 25
    dtype: Literal["float32", "float64"] = "float32"
    device: str = "cpu"
    compile: bool = False

    def __post_init__(self) -> None:
        if self.dim not in (2, 3):
            raise ValueError(f"sim.dim = {self.dim!r}; expected 2 or 3")
        for name in ("dx", "sound_speed", "cfl", "viscous_safety", "dt_max", "viscosity_cap"):
            value = getattr(self, name)
            if not value > 0:
                raise ValueError(f"sim.{name} = {value!r}; expected a positive number")
        if self.dx > 0.05:
            raise ValueError(f"sim.dx = {self.dx} m looks like millimetres or centimetres; lengths are in metres")
        if self.particles_per_cell < 1:
            raise ValueError(f"sim.particles_per_cell = {self.particles_per_cell}; expected >= 1")
        if self.dt is not None and not self.dt > 0:
            raise ValueError(f"sim.dt = {self.dt!r}; expected a positive time step in s, or None")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"sim.dtype = {self.dtype!r}; expected 'float32' or 'float64'")
        if self.checkpoint_every < 0:
            raise ValueError(f"sim.checkpoint_every = {self.checkpoint_every}; expected >= 0")

    @property
    def torch_dtype(self) -> torch.dtype:
        return torch.float32 if self.dtype == "float32" else torch.float64

    @property
    def torch_device(self) -> torch.device:
        device = torch.device(self.device)
        if device.type == "cuda" and not torch.cuda.is_available():
            raise ValueError("sim.device = 'cuda' but no CUDA device is available; use sim.device=cpu")
        return device

    def replace(self, **changes) -> "SimConfig":
        """A copy with ``changes`` applied."""
        return replace(self, **changes)
