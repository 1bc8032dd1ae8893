"""Settings of the MLS-MPM stirring simulation."""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
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
            enough that the hydrostatic compression ``density * g * fill_height / bulk_modulus`` stays small. With
            ``compressibility`` set it is the least sound speed, raised per rollout.
        compressibility: the largest relative density change δ the stir's pressure may cause, or None to keep
            ``sound_speed``. Each rollout then uses c = max(sound_speed, sqrt(p / (ρ δ))), with p the larger of the
            dynamic pressure ρ U² and the viscous pressure of a rod dragged at the cup's centre (its Stokes drag
            per unit length over its diameter, 2π η U / (a [ln(b/a) − (b² − a²)/(b² + a²)])) at the trajectory's
            top speed U and the law's viscosity at the shear rate U/a. A viscous stir's pressure, not its Mach
            number, is what compresses the fluid: at 1 m/s a 1 Pa·s stir at 0.1 m/s compresses it by 13 % and reads
            27 % low against an incompressible reference (docs/validation.md).
        rollout_sound_speed: the sound speed of every rollout [m/s], held fixed in place of the ``compressibility``
            rule (a fit holds the one its starting law gets: ``fitting.StirProblem.frozen``), or None. The fluid
            settles at ``sound_speed`` either way, so that a rollout at a held sound speed starts from the state the
            rule's rollout starts from (on the 5 mm grid a stir at 0.6 m/s read 12 % apart from two states settled
            at 1 and 3.6 m/s, docs/identification.md step 5).
        cfl: acoustic Courant number, ``dt <= cfl * dx / (sound_speed + max rod speed)``.
        viscous_safety: fraction of the explicit viscous limit ``density * dx**2 / (2 * dim * eta_max)`` used.
        viscosity_cap: the largest apparent viscosity simulated [Pa·s]; a law's viscosity above it is clamped (the
            bi-viscous regularisation of yield-stress plugs), so that its time step stays finite.
        flip: share of FLIP in the particles' velocity update, v_p ← Σ w v_i + flip (v_p − Σ w v_i^old): the
            particle keeps the part of its velocity the grid did not see instead of losing it every step. 0 is
            APIC alone, whose transfers add a numerical viscosity of about 0.016 dx²/Δt (1e-4 m²/s on the fitting
            default: a 0.2 Pa·s fluid behaved like a 0.3 Pa·s one, and forces grew as Δt shrank;
            docs/validation.md).
        volume_relaxation: time [s] over which the particles' volume ratio J relaxes towards the packing the
            grid measures (``diffstir.mpm.packing``); 0 leaves each particle's J to its own velocity divergence,
            which drifts. Longer than the acoustic crossing of a particle's stencil, 3 dx / c, so that the packing's
            noise is not fed into the sound waves, and far shorter than the drift (seconds).
        pressure: ``"compressible"``: the pressure follows the particles' compression at the sound speed above;
            ``"projection"``: it is solved each step to keep the grid's velocity divergence-free
            (``diffstir.mpm.projection``), so no sound speed limits the step (the flow's Courant number,
            ``cfl * dx / max rod speed``, does) and none compresses the fluid. ``volume_relaxation`` is then the
            time over which the cells' fill relaxes back to one. 2-D only for now.
        wall_pressure: boundary particles in the cup's walls and bottom and in the rod carry the fluid's pressure
            into the particle-to-grid transfer (``diffstir.mpm.walls``), so that the fluid next to a solid face is
            not left at a fraction of its pressure. Off by default: it makes the 3-D fluid at rest hydrostatic and
            the rod's buoyancy converge at second order in dx, leaves the 2-D viscous checks unchanged, but reads
            the 2-D rod's force in a pressure gradient 4 % low and costs 1.3-2.2x a step (docs/validation.md).
        viscous_substeps: the shear stress runs in explicit substeps within each step, as many as keep each within
            the viscous limit ``viscous_safety * density * dx**2 / (2 * dim * eta_max)``
            (``diffstir.mpm.step.grid_update``), so that a high viscosity (a law at ``viscosity_cap``) shortens the
            shear stress's substeps but not the particles' transfers and the pressure's steps. False: the viscous
            limit shortens the whole step.
        max_substeps: the most shear-stress substeps in one step; where a thick fluid would need more, the step
            shortens to ``max_substeps`` viscous limits instead. A pressure solved once per step lags a shear stress
            that runs many substeps: the 2-D rod translating through a 20 Pa·s fluid reads 0.924, 0.903 and 0.844 of
            its closed-form drag at steps of 1, 2 and 4 ms (15, 29 and 57 substeps on 2.5 mm cells;
            docs/validation.md). None: no bound.
        viscous_solver: ``"explicit"``: the shear stress advances the velocity explicitly, in the step or its
            ``viscous_substeps``, whose count grows with the viscosity; ``"implicit"``: one backward-Euler solve per
            step with each cell's viscosity held at the step's start (``diffstir.mpm.implicit_viscosity``), stable
            at any viscosity, so that neither the step nor its cost depends on it: a fluid thicker than the default
            ``viscosity_cap`` is simulated by raising the cap. Materials with a viscosity (``KelvinVoigt``: every
            rheology law) only.
        dt_max: the largest time step [s].
        dt: a fixed time step [s]; None chooses it from the limits above at the start of each rollout.
        headroom: grid space above the fluid's surface at rest [m], for the surface's rise while stirring.
        settle_time: time the fluid is left to settle under gravity before a 3-D rollout [s].
        checkpoint_every: steps per gradient-checkpoint segment; 0 keeps every step's graph (more memory).
        dtype: ``"float32"`` or ``"float64"``.
        device: torch device string, e.g. ``"cpu"`` or ``"cuda"``.
        compile: run each step through ``torch.compile`` (inductor, static shapes, scalar C++ kernels). Costs
            tens of seconds of compilation per scene, law type and time step, then steps run about 1.9x faster
            than eager on the paper's 3-D scene and 2.4-3.0x on the 2-D default, forward and forward + backward,
            on the 2-core CPU (docs/benchmarks.md); worth it for long rollouts and repeated fits of one scene, not
            for a one-off short simulation.
        kernels: how the particle-grid transfers run (``diffstir.mpm.transfer``): ``"fused"``, C++ kernels for the
            CPU, compiled on first use (about 50 s and 1.7 GB of memory for the compiler, then cached; needs a C++
            compiler and ninja); ``"torch"``, torch tensor ops (any device); ``"auto"``, fused on the CPU where they
            build, torch ops otherwise (on CUDA, where no compiler is found). Same results to rounding; ``compile``
            calls the fused kernels from its graph.
    """

    dim: Literal[2, 3] = 3
    dx: float = 0.005
    particles_per_cell: int = 2
    sound_speed: float = 10.0
    compressibility: float | None = None
    rollout_sound_speed: float | None = None
    cfl: float = 0.4
    viscous_safety: float = 0.9
    viscosity_cap: float = 20.0
    flip: float = 0.95
    volume_relaxation: float = 0.05
    pressure: Literal["compressible", "projection"] = "compressible"
    wall_pressure: bool = False
    viscous_substeps: bool = True
    max_substeps: int | None = None
    viscous_solver: Literal["explicit", "implicit"] = "explicit"
    dt_max: float = 1e-3
    dt: float | None = None
    headroom: float = 0.02
    settle_time: float = 0.3
    checkpoint_every: int = 25
    dtype: Literal["float32", "float64"] = "float32"
    device: str = "cpu"
    compile: bool = False
    kernels: Literal["auto", "fused", "torch"] = "auto"

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
        if self.max_substeps is not None and not (isinstance(self.max_substeps, int) and self.max_substeps >= 1):
            raise ValueError(f"sim.max_substeps = {self.max_substeps!r}; expected a whole number >= 1, or null for no "
                             "bound")
        if self.viscous_solver not in ("explicit", "implicit"):
            raise ValueError(f"sim.viscous_solver = {self.viscous_solver!r}; expected 'explicit' or 'implicit'")
        if self.dt is not None and not self.dt > 0:
            raise ValueError(f"sim.dt = {self.dt!r}; expected a positive time step in s, or None")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"sim.dtype = {self.dtype!r}; expected 'float32' or 'float64'")
        if not 0.0 <= self.flip <= 1.0:
            raise ValueError(f"sim.flip = {self.flip!r}; expected a share between 0 (APIC) and 1 (FLIP)")
        if not self.volume_relaxation >= 0:
            raise ValueError(f"sim.volume_relaxation = {self.volume_relaxation!r}; expected a time >= 0 in s "
                             "(0: no relaxation)")
        if self.pressure not in ("compressible", "projection"):
            raise ValueError(f"sim.pressure = {self.pressure!r}; expected 'compressible' or 'projection'")
        if self.pressure == "projection" and self.dim == 3:
            raise ValueError("sim.pressure = 'projection' is built and validated for the 2-D slice only (a closed "
                             "domain, no free surface; docs/validation.md); use sim.pressure=compressible in 3-D")
        if self.wall_pressure and self.pressure == "projection":
            raise ValueError("sim.wall_pressure = true continues the particles' pressure into the solids; with "
                             "sim.pressure = 'projection' the particles carry none: set one of them back")
        if self.rollout_sound_speed is not None and not self.rollout_sound_speed > 0:
            raise ValueError(f"sim.rollout_sound_speed = {self.rollout_sound_speed!r}; expected a speed > 0 in m/s, "
                             "or null to follow sim.compressibility")
        if self.compressibility is not None and not 0 < self.compressibility < 0.5:
            raise ValueError(f"sim.compressibility = {self.compressibility!r}; expected a relative density change "
                             "between 0 and 0.5 (e.g. 0.01), or null to keep sim.sound_speed")
        if self.kernels not in ("auto", "fused", "torch"):
            raise ValueError(f"sim.kernels = {self.kernels!r}; expected 'auto', 'fused' or 'torch'")
        if self.kernels == "fused" and torch.device(self.device).type != "cpu":
            raise ValueError("sim.kernels = 'fused' runs on the CPU; use sim.kernels=auto or torch")
        if self.checkpoint_every < 0:
            raise ValueError(f"sim.checkpoint_every = {self.checkpoint_every}; expected >= 0")

    @property
    def torch_dtype(self) -> torch.dtype:
        return torch.float32 if self.dtype == "float32" else torch.float64

    @property
    def fixed_sound_speed(self) -> float | None:
        """The sound speed [m/s] of every rollout where it does not follow the stir (``rollout_sound_speed``, or
        ``sound_speed`` without ``compressibility``), else None."""
        if self.rollout_sound_speed is not None:
            return self.rollout_sound_speed
        return self.sound_speed if self.compressibility is None else None

    @property
    def torch_device(self) -> torch.device:
        device = torch.device(self.device)
        if device.type == "cuda" and not torch.cuda.is_available():
            raise ValueError("sim.device = 'cuda' but no CUDA device is available; use sim.device=cpu")
        return device

    def replace(self, **changes) -> "SimConfig":
        """A copy with ``changes`` applied."""
        return replace(self, **changes)

    def force_settings(self) -> dict:
        """Every setting a simulated force depends on: all but where and how it runs (``device``, ``kernels``,
        ``compile``, ``checkpoint_every``, which change it by rounding at most). A fit's checkpoint holds them, so
        that a changed step or cap is not resumed from fits made without it."""
        return {k: v for k, v in asdict(self).items() if k not in RUN_SETTINGS}

    def numerics(self) -> dict:
        """What a simulated force depends on besides the fluid and the stir, for records that must say which
        simulator made them (a rectifier's training pairs, an identification's preliminary estimate)."""
        return {k: getattr(self, k) for k in NUMERICS}


#: Settings that say where and how a simulation runs, not what it computes (``SimConfig.force_settings``).
RUN_SETTINGS = ("device", "kernels", "compile", "checkpoint_every")

#: The settings of ``SimConfig.numerics``. A record that lacks some of them was made by numerics that had then the
#: values of ``FORMER_NUMERICS``: APIC transfers, each particle's own J, a fixed sound speed, no boundary particles,
#: the shear stress's explicit limit setting the step (no substeps, no implicit solve), and the 2 ms largest step
#: that the coarse stage, the only estimator such records describe, has always had (conf/sim/coarse2d.yaml). A record
#: made with substeps before they were recorded reads as made without them, so a rectifier trained on it is not
#: applied.
NUMERICS = ("dim", "dx", "sound_speed", "compressibility", "flip", "volume_relaxation", "pressure",
            "wall_pressure", "viscous_substeps", "max_substeps", "viscous_solver", "dt_max")
FORMER_NUMERICS = {"compressibility": None, "flip": 0.0, "volume_relaxation": 0.0, "pressure": "compressible",
                   "wall_pressure": False, "viscous_substeps": False, "max_substeps": None,
                   "viscous_solver": "explicit", "dt_max": 0.002}

#: The fit's fine stage (``conf/sim/slice2d.yaml``; a test holds them equal): the 2-D slice on 2.5 mm cells, its
#: pressure solved for incompressibility, a 2 ms step of at most 15 viscous substeps.
FINE_STAGE = SimConfig(dim=2, dx=0.0025, sound_speed=1.0, compressibility=0.03, pressure="projection",
                       max_substeps=15, dt_max=0.002)
#: The fit's coarse stage (``conf/sim/coarse2d.yaml``): the 2-D slice on 5 mm cells, its pressure from a sound speed
#: raised per rollout so that the stir compresses the fluid by at most 3 %.
COARSE_STAGE = SimConfig(dim=2, dx=0.005, sound_speed=1.0, compressibility=0.03, dt_max=0.002)
