"""Constitutive models: the fluid's shear stress from its velocity gradient.

Every material shares the simulator's weakly compressible volumetric response τ_v(J) (evaluated on the particles,
``volumetric_stress``); materials differ in the shear stress (evaluated in grid cells, ``shear_stress``). What the
simulator asks of a material is the protocol ``Material``; ``as_material`` turns a fluid handed to the simulator
(a rheology law or a material) into one.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import torch
from torch import Tensor, nn

from ..rheology import RheologyLaw

SHEAR_RATE_FLOOR = 1e-6  # 1/s, keeps d(shear rate)/dC finite where the fluid is at rest


def deviatoric_rate_of_strain(C: Tensor) -> Tensor:
    """dev(D), D = (C + Cᵀ)/2, of velocity gradients C [1/s], (N, d, d)."""
    D = 0.5 * (C + C.transpose(-1, -2))
    eye = torch.eye(C.shape[-1], dtype=C.dtype, device=C.device)
    return D - D.diagonal(dim1=-2, dim2=-1).sum(-1)[:, None, None] / C.shape[-1] * eye


def shear_rate(dev_D: Tensor) -> Tensor:
    """Scalar shear rate γ̇ = sqrt(2 dev(D):dev(D)) [1/s]; γ̇ equals du/dy in simple shear u = (γ̇ y, 0)."""
    return torch.sqrt(2.0 * (dev_D * dev_D).sum(dim=(-1, -2)) + SHEAR_RATE_FLOOR**2)


def volumetric_stress(J: Tensor, bulk_modulus: float) -> Tensor:
    """Neo-Hookean volumetric stress τ_v = κ/2 (J − 1/J) [Pa] (the paper's Eq. 3): tension positive."""
    return 0.5 * bulk_modulus * (J - 1.0 / J)


@runtime_checkable
class Material(Protocol):
    """What the simulator asks of a material (an ``nn.Module``, whose parameters are the rollout's): the shear
    stress of grid cells and a bound of its viscosity for the time step. ``KelvinVoigt``, ``Corotated`` and
    ``hidden_physics.HiddenPhysics`` implement it; a material with a state of its own is a ``StatefulMaterial``,
    one whose stress depends on the step itself a ``StepDependentMaterial``."""

    def shear_stress(self, grad_v: Tensor, viscosity_cap: float, dt: float) -> Tensor:
        """Deviatoric stress [Pa], (K, d, d), of cells with velocity gradients ``grad_v`` [1/s], (K, d, d), over a
        step ``dt`` [s], with the apparent viscosity at most ``viscosity_cap`` [Pa·s]."""
        ...

    def max_viscosity(self, shear_rate_max: float) -> float:
        """Upper bound of the apparent viscosity [Pa·s] up to ``shear_rate_max`` [1/s], for the time-step limit."""
        ...


@runtime_checkable
class StatefulMaterial(Material, Protocol):
    """A material with a state of its own (``State.material``), which each step's shear stress advances."""

    def initial_material_state(self, scene) -> Tensor:
        """The state of the fluid at rest on ``scene``'s grid, as one flat tensor."""
        ...

    def shear_stress(self, grad_v: Tensor, viscosity_cap: float, dt: float, *,
                     state: Tensor) -> tuple[Tensor, Tensor]:
        """The stress [Pa], (K, d, d), as ``Material.shear_stress``, and the ``state`` after the step ``dt`` [s]."""
        ...


@runtime_checkable
class StepDependentMaterial(Material, Protocol):
    """A material that says whether its stress depends on the step ``dt`` itself (``step_dependent``: True for
    ``Corotated``, whose viscosity is μ Δt); the simulator then does not split the step into shear-stress
    substeps."""

    step_dependent: bool


def as_material(fluid: nn.Module) -> nn.Module:
    """The material of ``fluid``: ``fluid`` itself when it is a ``Material``, a rheology law
    (``diffstir.rheology.RheologyLaw``) in the paper's ``KelvinVoigt`` material.

    Raises:
        TypeError: ``fluid`` is neither an ``nn.Module`` material nor a rheology law.
    """
    if isinstance(fluid, nn.Module) and isinstance(fluid, Material):
        return fluid
    if isinstance(fluid, RheologyLaw):
        return KelvinVoigt(fluid)
    raise TypeError("fluid must be a rheology law or a material nn.Module (shear_stress(grad_v, viscosity_cap, dt) "
                    f"and max_viscosity(shear_rate_max)), got {type(fluid).__name__}; for example "
                    "diffstir.rheology.Newtonian(eta=0.1)")


class KelvinVoigt(nn.Module):
    """The paper's Kelvin-Voigt fluid: σ = τ_v(J) I + 2 η(γ̇) dev(D), D = (∇v + ∇vᵀ)/2.

    The viscous part is deviatoric (no bulk viscosity), so in simple shear σ_xy = η(γ̇) γ̇, and the apparent
    viscosity η comes from ``law`` (any ``diffstir.rheology`` law) at the particle's shear rate.
    """

    def __init__(self, law: nn.Module):
        super().__init__()
        if not isinstance(law, nn.Module) or not hasattr(law, "max_viscosity"):
            raise TypeError(
                f"KelvinVoigt needs a rheology law (an nn.Module from diffstir.rheology such as Carreau(...)), "
                f"got {type(law).__name__}"
            )
        self.law = law

    def shear_stress(self, grad_v: Tensor, viscosity_cap: float, dt: float) -> Tensor:
        """Viscous stress 2 η(γ̇) dev(D) [Pa], (K, d, d), for velocity gradients ``grad_v`` [1/s], (K, d, d).

        The apparent viscosity is clamped at ``viscosity_cap`` [Pa·s], the largest the explicit step resolves: a
        bi-viscous regularisation under which unyielded (plug) regions move as a very viscous fluid.
        """
        dev_D = deviatoric_rate_of_strain(grad_v)
        eta = self.law(shear_rate(dev_D)).clamp(max=viscosity_cap)
        return 2.0 * eta[:, None, None] * dev_D

    def viscosity_of(self, grad_v: Tensor, viscosity_cap: float) -> Tensor:
        """The apparent viscosity η(γ̇) [Pa·s], (K,), of cells with velocity gradients ``grad_v`` [1/s], (K, d, d),
        at most ``viscosity_cap``: what an implicit step holds over the step (``implicit_viscosity``)."""
        return self.law(shear_rate(deviatoric_rate_of_strain(grad_v))).clamp(max=viscosity_cap)

    def max_viscosity(self, shear_rate_max: float, dt: float | None = None) -> float:
        """Upper bound of the apparent viscosity up to ``shear_rate_max`` [Pa·s], for the time-step limit."""
        return float(self.law.max_viscosity(shear_rate_max))


class Corotated(nn.Module):
    """The fixed-corotated liquid used by FluidLab-style MPM, the paper's baseline.

    Shear stress 2μ (F − R) Fᵀ on the step's trial deformation gradient F = I + Δt ∇v, after which F is reset to
    its volumetric part (the usual MPM liquid treatment); the volumetric part is the simulator's τ_v(J).
    The shear term is then a viscous stress with an effective viscosity μ Δt that does not depend on the shear
    rate: the baseline cannot express shear thinning, thickening or a yield stress.

    Args:
        shear_modulus: μ [Pa]; an ``nn.Parameter`` stored in log space.
    """

    step_dependent = True  # its stress is the step's, μ Δt: the simulator does not split the step (``substeps``)

    def __init__(self, shear_modulus: float = 1e3):
        super().__init__()
        if not shear_modulus > 0:
            raise ValueError(f"Corotated.shear_modulus = {shear_modulus}; expected a positive value in Pa")
        self.log_shear_modulus = nn.Parameter(torch.tensor(float(shear_modulus)).log())

    @property
    def shear_modulus(self) -> Tensor:
        """μ [Pa]."""
        return self.log_shear_modulus.exp()

    def shear_stress(self, grad_v: Tensor, viscosity_cap: float, dt: float) -> Tensor:
        """Corotated shear stress 2μ (F − R) Fᵀ [Pa], (K, d, d), with F = I + Δt ∇v."""
        eye = torch.eye(grad_v.shape[-1], dtype=grad_v.dtype, device=grad_v.device)
        F_trial = eye + dt * grad_v
        R = polar_rotation(F_trial)
        return 2.0 * self.shear_modulus.to(grad_v.dtype) * (F_trial - R) @ F_trial.transpose(-1, -2)

    def max_viscosity(self, shear_rate_max: float, dt: float | None = None) -> float:
        """Effective viscosity μ Δt [Pa·s] (with Δt = ``dt``, or 1 ms when not yet known)."""
        return float(self.shear_modulus.detach()) * (dt if dt is not None else 1e-3)

    def apparent_viscosity(self, dt: float) -> float:
        """The baseline's viscosity estimate μ Δt [Pa·s] at the rollout's step ``dt`` [s]."""
        return float(self.shear_modulus.detach()) * dt


def polar_rotation(F: Tensor, iterations: int = 8) -> Tensor:
    """Rotation R of the polar decomposition F = R S, by Newton's iteration X ← (X + X⁻ᵀ)/2.

    Smooth everywhere F is invertible, unlike an SVD whose gradient is undefined at repeated singular values
    (every particle at rest). Converges quadratically for F near a rotation, which is the case for a liquid. A
    singular F (a step that crushes a particle: Δt ∇v with an eigenvalue −1, a rollout blowing up) has no
    rotation: its R is NaN, which the simulator reports as a non-finite state.
    """
    X = F
    for _ in range(iterations):
        inverse, info = torch.linalg.inv_ex(X)
        inverse = torch.where((info != 0)[..., None, None], torch.nan, inverse)
        X = 0.5 * (X + inverse.transpose(-1, -2))
    return X
