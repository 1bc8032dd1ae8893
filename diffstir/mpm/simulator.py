"""The stirring simulator as a torch module: a fluid in a rig, stirred along a trajectory, gives the force on the rod.

    sim = StirringSimulator(Carreau(eta0=1.0, eta_inf=0.01, lam=0.5, n=0.6), Rig(), SimConfig(dim=3), density=1050)
    result = sim(circle(radius=0.02, speed=0.1, duration=2.0))
    result.force.abs().mean().backward()          # gradients reach the law's nn.Parameters
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from ..errors import SimulationError
from ..rig import Rig
from ..trajectory import Trajectory
from .boundaries import RodPose
from .build import build_scene, settled_state
from .config import SimConfig
from .materials import StatefulMaterial, StepDependentMaterial, as_material
from .scene import Scene
from .state import State
from .step import step

SHEAR_RATE_SCALE = 4.0  # the largest shear rate resolvable on the grid is about this times (max speed / dx)
STEP_TOLERANCE = 1e-6  # relative: a duration within this of a whole number of steps takes that number (the
#                        rounding of times on a rig's clock, 1.5e-11 s at 1e5 s, does not add a step)


@dataclass
class SimResult:
    """The output of a rollout.

    Attributes:
        times: mid-step times [s], (T,), float64 whatever the config's dtype: a float32 time resolves only
            1 ms at 1e4 s, so that the steps of a rollout on a rig's clock would not increase.
        force: the fluid's force on the rod over each step [N], (T, d); in 2-D per unit length of rod [N/m].
        torque: the fluid's torque on the rod about its own axis [N·m], (T,); in 2-D per unit length [N].
        dt: the time step [s].
        state: the fluid's final state.
        snapshots: particle positions [m] about every ``snapshot_every`` steps, for drawing (detached): taken at the
            end of each checkpoint segment (``SimConfig.checkpoint_every`` steps) that reaches a multiple of it.
        snapshot_times: the time [s] of each snapshot.
        per_unit_length: True for a 2-D slice.
    """

    times: Tensor
    force: Tensor
    torque: Tensor
    dt: float
    state: State
    snapshots: list[Tensor]
    snapshot_times: list[float]
    per_unit_length: bool


class StirringSimulator(nn.Module):
    """A fluid in the rig, simulated with MLS-MPM; its parameters are those of the fluid's law.

    Args:
        fluid: a rheology law (``diffstir.rheology``; wrapped in the paper's Kelvin-Voigt material) or a material
            module (``materials.Material``: ``KelvinVoigt``, ``Corotated``, ``HiddenPhysics``; ``as_material``).
        rig: cup and rod (default: the paper's rig).
        config: resolution and numerics (default: ``SimConfig()``).
        density: the fluid's density [kg/m³].
        cache_dir: where settled states are cached (default ``$DIFFSTIR_CACHE_DIR`` or ``~/.cache/diffstir``).
    """

    def __init__(self, fluid: nn.Module, rig: Rig | None = None, config: SimConfig | None = None, *,
                 density: float = 1000.0, cache_dir: str | Path | None = None):
        super().__init__()
        self.material = as_material(fluid)
        self.rig = rig or Rig()
        self.config = config or SimConfig()
        if self.implicit and not hasattr(self.material, "viscosity_of"):
            raise ValueError(f"sim.viscous_solver = implicit needs a material with a viscosity (a rheology law); "
                             f"{type(self.material).__name__} has none: use sim.viscous_solver = explicit")
        self.density = float(density)
        self.cache_dir = cache_dir
        self.scene: Scene = build_scene(self.rig, self.config, self.density)
        # scalar kernels (simdlen 1): inductor's default vectorised CPU code was slower on this scene's small
        # tensors (measured, docs/benchmarks.md)
        self._step = (torch.compile(step, dynamic=False, options={"cpp.simdlen": 1}) if self.config.compile
                      else step)
        self.material.to(device=self.config.torch_device, dtype=self.config.torch_dtype)

    @property
    def viscosity_cap(self) -> float:
        """The largest apparent viscosity the simulation resolves [Pa·s] (see ``SimConfig``)."""
        return self.scene.viscosity_cap

    def sound_speed(self, trajectory: Trajectory) -> float:
        """The rollout's speed of sound c [m/s]: ``config.fixed_sound_speed`` where the config holds one, else
        ``config.sound_speed`` raised with ``config.compressibility`` δ to sqrt(p / (ρ δ)), p the larger of the
        dynamic pressure ρ U² and the viscous pressure of a rod of radius a dragged at U through a cup of radius b,
        2π η U / (a [ln(b/a) − (b² − a²)/(b² + a²)]) (its Stokes drag per unit length over its diameter), at the
        trajectory's top speed U and the viscosity at shear rate U/a."""
        cfg = self.config
        if cfg.fixed_sound_speed is not None:
            return cfg.fixed_sound_speed
        a, b = self.rig.rod.radius, self.rig.cup.radius
        u = trajectory.max_speed(a)
        law = getattr(self.material, "law", None)
        if law is not None:
            rate = torch.tensor([max(u / a, 1e-6)], dtype=self.config.torch_dtype, device=self.config.torch_device)
            with torch.no_grad():
                eta = float(law(rate).clamp(max=self.viscosity_cap)[0])
        else:
            eta = min(self.material.max_viscosity(max(u / a, 1e-6)), self.viscosity_cap)
        viscous = 2 * math.pi * eta * u / (a * (math.log(b / a) - (b**2 - a**2) / (b**2 + a**2)))
        pressure = max(self.density * u**2, viscous)
        return max(cfg.sound_speed, math.sqrt(pressure / (self.density * cfg.compressibility)))

    def time_step(self, trajectory: Trajectory) -> float:
        """The step [s]: min of the acoustic limit cfl·dx/(c + u_max) (c the rollout's ``sound_speed``; with a
        projection the flow's limit cfl·dx/u_max), ``dt_max`` and the ``viscous_time_step`` times ``max_substeps``
        (once where the shear stress is not subcycled, ``substeps``; not at all where it is implicit), shortened so
        that it divides the trajectory's duration."""
        cfg = self.config
        if cfg.dt is not None:
            dt = cfg.dt
        else:
            u_max = trajectory.max_speed(self.rig.rod.radius)
            signal = u_max if cfg.pressure == "projection" else self.sound_speed(trajectory) + u_max
            dt = min(cfg.cfl * cfg.dx / max(signal, 1e-12), cfg.dt_max)
            if not (self.subcycles or self.implicit):
                dt = min(dt, self.viscous_time_step(trajectory))
            elif self.subcycles and cfg.max_substeps is not None:
                dt = min(dt, cfg.max_substeps * self.viscous_time_step(trajectory))
        steps = max(1, math.ceil(trajectory.duration / dt * (1.0 - STEP_TOLERANCE)))
        return trajectory.duration / steps

    def viscous_time_step(self, trajectory: Trajectory) -> float:
        """The explicit viscous limit safety·ρ dx²/(2 d η_max) [s], η_max the material's largest viscosity up to
        the grid's shear rate ``SHEAR_RATE_SCALE``·u_max/dx, at most ``viscosity_cap``."""
        cfg = self.config
        u_max = trajectory.max_speed(self.rig.rod.radius)
        eta_max = min(self.material.max_viscosity(SHEAR_RATE_SCALE * u_max / cfg.dx + 1.0), self.viscosity_cap)
        return cfg.viscous_safety * self.density * cfg.dx**2 / (2 * cfg.dim * max(eta_max, 1e-12))

    @property
    def implicit(self) -> bool:
        """Whether the shear stress is solved implicitly (``SimConfig.viscous_solver``): no viscous limit."""
        return self.config.viscous_solver == "implicit"

    @property
    def subcycles(self) -> bool:
        """Whether the shear stress runs in substeps of its explicit limit (``SimConfig.viscous_substeps``); never
        for a material whose stress depends on the step itself (``Corotated``: μ Δt)."""
        step_dependent = isinstance(self.material, StepDependentMaterial) and self.material.step_dependent
        return self.config.viscous_substeps and not step_dependent and not self.implicit

    def substeps(self, trajectory: Trajectory, dt: float) -> int:
        """m, the shear stress's substeps in a step ``dt`` [s]: the fewest that keep dt/m within the
        ``viscous_time_step``; 1 without subcycling."""
        if not self.subcycles:
            return 1
        return max(1, math.ceil(dt / self.viscous_time_step(trajectory) * (1.0 - STEP_TOLERANCE)))

    def initial_state(self, trajectory: Trajectory) -> State:
        """The settled fluid around the rod at the trajectory's first pose, with the material's initial state
        (``material.initial_material_state(scene)``) for a material that has one."""
        pose = self._poses(trajectory, np.array([trajectory.t[0], trajectory.t[0] + 1e-3]))[0]
        state = settled_state(self.scene, self.rig, self.config, self.density, pose, self.cache_dir)
        if isinstance(self.material, StatefulMaterial):
            state.material = self.material.initial_material_state(self.scene)
        return state

    def forward(self, trajectory: Trajectory, *, initial: State | None = None,
                snapshot_every: int = 0) -> SimResult:
        """Stir along ``trajectory`` from the settled fluid (or ``initial``) and return the forces on the rod."""
        self._check_clearance(trajectory)
        dt = self.time_step(trajectory)
        substeps = self.substeps(trajectory, dt)
        steps = int(round(trajectory.duration / dt))
        times = trajectory.t[0] + dt * np.arange(steps + 1)
        poses = self._poses(trajectory, times)
        state = initial if initial is not None else self.initial_state(trajectory)
        if self.scene.incompressible and state.pressure is None:  # a fluid at rest: no pressure yet
            state = replace(state, pressure=torch.zeros(self.scene.cells.corners.shape[0], dtype=state.x.dtype,
                                                        device=state.x.device))
        bulk_modulus = 0.0 if self.scene.incompressible else self.density * self.sound_speed(trajectory) ** 2
        if bulk_modulus != self.scene.bulk_modulus:
            self.scene = replace(self.scene, bulk_modulus=bulk_modulus)
        forces, torques, snapshots, snapshot_times = [], [], [], []
        segment = self.config.checkpoint_every or steps
        names = state.names()  # the fields a step carries, the same in every segment
        for start in range(0, steps, segment):
            stop = min(start + segment, steps)

            def run(*tensors, start=start, stop=stop, names=names):
                s, f, q = State.from_tensors(tensors, names), [], []
                for k in range(start, stop):
                    s, force, torque = self._step(self.scene, self.material, s, poses[k], dt, substeps)
                    self._check_finite(s, k, dt)
                    f.append(force)
                    q.append(torque)
                return (*s.tensors(), torch.stack(f), torch.stack(q))

            if self.config.checkpoint_every and torch.is_grad_enabled():
                tensors = state.tensors()
                out = _Segment.apply(run, len(tensors), *tensors, *self._differentiable_inputs())
            else:
                out = run(*state.tensors())
            state = State.from_tensors(out[:-2], names)
            forces.append(out[-2])
            torques.append(out[-1])
            if snapshot_every and (stop // snapshot_every > start // snapshot_every or start == 0):
                snapshots.append(state.x.detach().clone())
                snapshot_times.append(float(times[stop]))
        mid = torch.as_tensor(times[:-1] + 0.5 * dt, dtype=torch.float64, device=state.x.device)
        return SimResult(times=mid, force=torch.cat(forces), torque=torch.cat(torques), dt=dt, state=state,
                         snapshots=snapshots, snapshot_times=snapshot_times, per_unit_length=self.config.dim == 2)

    def _differentiable_inputs(self) -> list[Tensor]:
        """What a rollout can be differentiated with respect to besides its initial state: the material's
        parameters and a differentiable rod slip length."""
        inputs = [p for p in self.parameters() if p.requires_grad]
        slip = self.scene.rod_slip_length
        if isinstance(slip, Tensor) and slip.requires_grad:
            inputs.append(slip)
        return inputs

    def _poses(self, trajectory: Trajectory, times: np.ndarray) -> list[RodPose]:
        """Mid-step rod poses and velocities for the steps between consecutive ``times``."""
        xy, z, angle = trajectory.poses(times)
        dt = np.diff(times)[:, None]
        tip = self.rig.rod_tip_height + z
        kw = dict(dtype=self.config.torch_dtype, device=self.config.torch_device)
        axis = torch.as_tensor(0.5 * (xy[1:] + xy[:-1]), **kw)
        mid_tip = torch.as_tensor(0.5 * (tip[1:] + tip[:-1]), **kw)
        mid_angle = torch.as_tensor(0.5 * (angle[1:] + angle[:-1]), **kw)
        velocity = np.diff(xy, axis=0) / dt
        if self.config.dim == 3:
            velocity = np.concatenate([velocity, np.diff(tip)[:, None] / dt], axis=1)
        velocity = torch.as_tensor(velocity, **kw)
        omega = torch.as_tensor(np.diff(angle) / dt[:, 0], **kw)
        return [RodPose(axis=axis[k], tip=mid_tip[k], angle=mid_angle[k], velocity=velocity[k],
                        angular_velocity=omega[k]) for k in range(len(times) - 1)]

    def _check_clearance(self, trajectory: Trajectory) -> None:
        reach = trajectory.max_offset() + self.rig.rod.radius
        if reach >= self.rig.cup.radius - 0.5 * self.config.dx:
            raise ValueError(
                f"trajectory: the rod (radius {self.rig.rod.radius} m) reaches {reach:.4g} m from the cup's axis, "
                f"touching the wall at {self.rig.cup.radius} m; keep the axis within "
                f"{self.rig.cup.radius - self.rig.rod.radius - 0.5 * self.config.dx:.4g} m of the centre"
            )
        if self.config.dim == 3 and self.rig.rod_tip_height + float(np.min(trajectory.z)) <= self.config.dx:
            raise ValueError("trajectory.z: the rod's tip reaches the cup's bottom")

    def _check_finite(self, state: State, k: int, dt: float) -> None:
        if torch.isfinite(state.x).all():
            return
        law = getattr(self.material, "law", self.material)
        params = law.parameters_si() if hasattr(law, "parameters_si") else {
            n: float(p.detach().reshape(-1)[0]) for n, p in law.named_parameters()}
        raise SimulationError(
            f"the simulation became non-finite at step {k} (t = {k * dt:.4g} s, dt = {dt:.3g} s) with "
            f"{type(law).__name__} parameters {params}; try a smaller sim.cfl or sim.viscous_safety"
        )


class _Segment(torch.autograd.Function):
    """A checkpointed rollout segment: its forward keeps no graph at all, its backward recomputes the segment
    with gradients and differentiates it.

    ``torch.utils.checkpoint`` (non-reentrant) drops a segment's saved tensors but keeps its autograd graph, a few
    hundred nodes per step: about 0.3-0.9 MB per step on the paper's scene, several GB over 8000 steps. Here only
    the segment's inputs are kept. Gradients flow to the state tensors and to ``params`` (the simulator's
    ``_differentiable_inputs``); a tensor that requires grad and reaches the step by another way would get none.
    """

    @staticmethod
    def forward(ctx, run, num_state: int, *inputs: Tensor):
        ctx.run, ctx.num_state = run, num_state
        ctx.save_for_backward(*inputs)
        with torch.no_grad():
            return run(*(t.detach() for t in inputs[:num_state]))

    @staticmethod
    def backward(ctx, *grad_outputs: Tensor):
        inputs = ctx.saved_tensors
        # every state tensor is recomputed as requiring grad, also the rollout's initial state, so that a compiled
        # step sees the same inputs in every segment
        state = [t.detach().requires_grad_(t.is_floating_point()) for t in inputs[:ctx.num_state]]
        wrt = [t for t in (*state, *inputs[ctx.num_state:]) if t.requires_grad]
        with torch.enable_grad():
            pairs = [(out, grad) for out, grad in zip(ctx.run(*state), grad_outputs) if out.requires_grad]
        grads = iter(torch.autograd.grad([out for out, _ in pairs], wrt, [grad for _, grad in pairs],
                                         allow_unused=True) if wrt and pairs else [None] * len(wrt))
        per_input = [next(grads) if t.requires_grad else None for t in (*state, *inputs[ctx.num_state:])]
        return (None, None, *(g if needed else None for g, needed in zip(per_input, ctx.needs_input_grad[2:])))


def simulate(fluid: nn.Module, trajectory: Trajectory, *, rig: Rig | None = None, config: SimConfig | None = None,
             density: float = 1000.0, snapshot_every: int = 0) -> SimResult:
    """Stir ``fluid`` (a rheology law or material) in ``rig`` along ``trajectory``; see ``StirringSimulator``."""
    return StirringSimulator(fluid, rig, config, density=density)(trajectory, snapshot_every=snapshot_every)
