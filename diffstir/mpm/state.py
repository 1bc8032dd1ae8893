"""Particle state of the fluid."""

from __future__ import annotations

from dataclasses import dataclass, fields

from torch import Tensor


@dataclass
class State:
    """The fluid's particles at one instant. N particles, d dimensions.

    Attributes:
        x: positions [m], (N, d), cup frame.
        v: velocities [m/s], (N, d).
        C: affine velocity field (APIC/MLS), the particle's velocity gradient [1/s], (N, d, d).
        J: volume ratio (current / rest volume) [1], (N,).
        material: the material's own state, or None for a memoryless material: any tensor that the material
            evolves each step (``grid_update`` passes it to ``material.shear_stress(..., state=...)``), e.g. a
            structure parameter or a stress field on the grid cells (see ``diffstir.mpm.hidden_physics``).
        pressure: with an incompressible pressure, the last step's pressure in each grid cell [Pa], (cells,), which
            pushes the next step's shear-stress substeps (``step.grid_update``); zero for a fluid at rest, None with
            a sound speed.
    """

    x: Tensor
    v: Tensor
    C: Tensor
    J: Tensor
    material: Tensor | None = None
    pressure: Tensor | None = None

    def names(self) -> tuple[str, ...]:
        """The fields that hold a tensor, in field order."""
        return tuple(f.name for f in fields(self) if getattr(self, f.name) is not None)

    def tensors(self) -> tuple[Tensor, ...]:
        """The tensors of ``names`` (for checkpointing)."""
        return tuple(getattr(self, name) for name in self.names())

    @classmethod
    def from_tensors(cls, tensors: tuple[Tensor, ...], names: tuple[str, ...]) -> "State":
        """The state whose fields ``names`` hold ``tensors``."""
        return cls(**dict(zip(names, tensors, strict=True)))

    @property
    def num_particles(self) -> int:
        return self.x.shape[0]

    @property
    def dim(self) -> int:
        return self.x.shape[1]
