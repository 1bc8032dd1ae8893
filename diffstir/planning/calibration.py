"""The fitting simulator's reading at each candidate speed, for Newtonian fluids: what a plan's information is
computed from.

A plan reads a law through Metzner and Otto's apparent viscosity (``fitting.initial``): a steady window at speed U
reads like the Newtonian fluid of viscosity η(γ̇_eff), γ̇_eff = k_s U / a (a: the rod's radius). So a calibration
holds, for each candidate speed U, the mean |reading| M_U(η) [N] of a one-speed stir for Newtonian probes η_j over
the prior's range (a ``ViscosityLadder``: the rod from rest, its ramp, then ``steady_time`` at U, averaged after
``settle_time``), and k_s, measured once at the middle speed and viscosity (``fitting.effective_shear_rate``), as
the behaviour experiment uses one k_s for all its windows (``behaviour.pipeline``). The reading is the force along
the rod's path (tangential mode), whose mean over a window does not depend on where on the circle it starts.

It costs speeds × probes + 4 simulations of the fitting simulator, side by side, and is cached on disk by everything
it depends on (``$DIFFSTIR_CACHE_DIR/plan`` or ``~/.cache/diffstir/plan``), so a second plan for the same rig, speeds
and simulator costs none; the package ships the paper rig's at the plan's defaults (``SHIPPED``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import __version__
from ..fitting import (SHEAR_RATE_PROBES, FitModel, ReadingJob, StirProblem, ViscosityLadder, Windows,
                       metzner_otto_constant)
from ..lab.programme import stirring_programme
from ..mpm import SimConfig, cache_root
from ..parallel import Workers
from ..recording import CupGeometry, Recording, RodGeometry, SensorSpec
from ..rig import Rig


#: Calibrations shipped with the package (the paper's rig at the plan's defaults), read when the cache has none.
SHIPPED = Path(__file__).resolve().parents[1] / "data" / "plan"


@dataclass(frozen=True)
class Calibration:
    """Newtonian readings M_U(η) [N] at each of ``speeds`` [m/s] (``ladders``, in order) on a circle of ``radius``
    [m], and the stir's Metzner-Otto constant ``shear_rate_factor`` k_s [1] for a rod of radius ``rod_radius`` [m]."""

    radius: float
    rod_radius: float
    speeds: tuple[float, ...]
    ladders: tuple[ViscosityLadder, ...]
    shear_rate_factor: float

    def shear_rate(self, speed: float) -> float:
        """γ̇_eff = k_s U / a [1/s] at speed ``speed`` [m/s]."""
        return self.shear_rate_factor * abs(speed) / self.rod_radius

    def ladder(self, speed: float) -> ViscosityLadder:
        """The ladder of the calibrated speed ``speed`` [m/s]."""
        for calibrated, ladder in zip(self.speeds, self.ladders):
            if math.isclose(calibrated, abs(speed), rel_tol=1e-9):
                return ladder
        raise KeyError(f"speed {speed!r} m/s was not calibrated; calibrated: {list(self.speeds)}")

    def to_dict(self) -> dict:
        ladders = [{"viscosities": list(ld.viscosities), "mean_abs": list(ld.mean_abs)} for ld in self.ladders]
        return {"radius": self.radius, "rod_radius": self.rod_radius, "speeds": list(self.speeds),
                "shear_rate_factor": self.shear_rate_factor, "ladders": ladders,
                "units": {"radius": "m", "rod_radius": "m", "speeds": "m/s", "viscosities": "Pa s", "mean_abs": "N"}}

    @classmethod
    def from_dict(cls, data: dict) -> "Calibration":
        ladders = tuple(ViscosityLadder(tuple(ld["viscosities"]), tuple(ld["mean_abs"])) for ld in data["ladders"])
        return cls(float(data["radius"]), float(data["rod_radius"]), tuple(data["speeds"]), ladders,
                   float(data["shear_rate_factor"]))


def probe_viscosities(viscosity: tuple[float, float]) -> tuple[float, ...]:
    """Newtonian probes [Pa·s] over a prior's apparent-viscosity range: its ends and one per decade between, at
    least three. Beyond the ends the ladder extends its top segment (a Stokes drag, linear in η) and holds its
    bottom reading (``ViscosityLadder.reading``)."""
    low, high = math.log10(viscosity[0]), math.log10(viscosity[1])
    return tuple(float(v) for v in np.logspace(low, high, max(3, int(math.ceil(high - low - 1e-9)) + 1)))


def calibrate(rig: Rig, config: SimConfig, density: float, radius: float, speeds: tuple[float, ...],
              viscosities: tuple[float, ...], *, ramp_time: float, steady_time: float, settle_time: float,
              sample_rate: float, workers: int = 1, cache_dir: str | Path | None = None,
              report: Callable[[tuple], None] | None = None) -> Calibration:
    """The calibration (module docstring) of ``speeds`` [m/s] on a circle of ``radius`` [m] in ``rig`` for a fluid
    of ``density`` [kg/m³], with Newtonian probes ``viscosities`` [Pa·s], from the cache when it holds it.
    ``report`` receives ("calibration", simulations, cache file) before simulating and each simulation's
    ("evaluation", ...) event."""
    settings = dataclasses.asdict(config)
    if config.viscous_solver == "explicit":  # keyed only when implicit, so that the shipped calibration stays valid
        del settings["viscous_solver"]
    key = {"rig": dataclasses.asdict(rig), "config": settings, "density": density, "radius": radius,
           "speeds": list(speeds), "viscosities": list(viscosities), "ramp_time": ramp_time,
           "steady_time": steady_time, "settle_time": settle_time, "sample_rate": sample_rate, "version": __version__}
    digest = hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()[:16]
    path = cache_root(cache_dir) / "plan" / f"calibration-{digest}.json"
    for known in (path, SHIPPED / path.name):
        if known.exists():
            return Calibration.from_dict(json.loads(known.read_text()))
    problems = [_one_speed_problem(rig, config, density, radius, u, ramp_time=ramp_time, steady_time=steady_time,
                                   settle_time=settle_time, sample_rate=sample_rate) for u in speeds]
    jobs = [ReadingJob("plan", f"{u:g}@{eta:g}", problem, FitModel.named("newtonian", eta=eta))
            for u, problem in zip(speeds, problems) for eta in viscosities]
    middle = problems[len(problems) // 2]
    reference = math.sqrt(viscosities[0] * viscosities[-1])
    report = report or (lambda event: None)
    report(("calibration", len(jobs) + SHEAR_RATE_PROBES, str(path)))
    with Workers(workers, report) as pool:
        readings = pool.map(jobs)

        def side_by_side(models: list[FitModel]) -> list[float]:
            probes = [ReadingJob("plan", f"shear-rate{k}", middle, model) for k, model in enumerate(models)]
            return [middle.mean_reading(r) for r in pool.map(probes)]

        factor = metzner_otto_constant(middle, reference, evaluate=side_by_side)
    means = [job.problem.mean_reading(r) for job, r in zip(jobs, readings)]
    n = len(viscosities)
    ladders = tuple(ViscosityLadder(tuple(viscosities), tuple(means[k * n:(k + 1) * n])) for k in range(len(speeds)))
    calibration = Calibration(radius, rig.rod.radius, tuple(float(u) for u in speeds), ladders, factor)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(f".{os.getpid()}.tmp")
    partial.write_text(json.dumps(calibration.to_dict(), indent=1))
    partial.replace(path)
    return calibration


def _one_speed_problem(rig: Rig, config: SimConfig, density: float, radius: float, speed: float, *,
                       ramp_time: float, steady_time: float, settle_time: float, sample_rate: float) -> StirProblem:
    """A blank recording of the rod from rest to ``speed`` [m/s] on a circle of ``radius`` [m], compared over its
    steady part after ``settle_time`` [s]."""
    trajectory = stirring_programme([{"speed": speed, "duration": ramp_time + steady_time}], radius=radius,
                                    ramp_time=ramp_time, sample_rate=sample_rate)
    recording = Recording(cup=CupGeometry(radius=rig.cup.radius, fill_height=rig.cup.fill_height),
                          rod=RodGeometry(radius=rig.rod.radius, immersion_depth=rig.rod.immersion_depth),
                          sensor=SensorSpec(mode="tangential", sample_rate=sample_rate), density=None,
                          t=trajectory.t, x=trajectory.xy[:, 0], y=trajectory.xy[:, 1],
                          force=np.zeros(len(trajectory.t)), name=f"plan-{speed:g}mps")
    end = float(trajectory.t[-1])
    return StirProblem(recording, config, density, Windows(ramp_time + settle_time, end, end))

