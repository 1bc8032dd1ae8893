"""Training pairs for the rectifier: virtual-lab recordings with a known reference viscosity, estimated by the
pipeline's own preliminary estimator.

A pair is (mean stirring speed U [m/s], preliminary viscosity η_p [Pa·s], reference viscosity η_ref [Pa·s]):

* the recording comes from the virtual lab: a fluid's truth (an MPM simulation finer than the estimator's, or the
  stir in the 3-D cup by finite elements, ``lab/sim@truth=fe3d``), read through a randomly drawn, realistic sensor
  model, with its Archimedes density readings;
* η_p is the Newtonian ladder estimate (``diffstir.fitting.initial.ViscosityLadder``) on the estimator's
  resolution, exactly what ``identify`` computes before it fits any law;
* η_ref is the fluid's true apparent viscosity at the stir's effective shear rate γ̇_eff, measured as ``identify``
  measures it (``effective_shear_rate``) at Newtonian-equivalent viscosities ``RATE_PROBES`` and interpolated to
  the fluid's (``group_shear_rate``).

Work is split into shards, one per (programme, density) group: the ladder and γ̇_eff are simulated once per group
(they depend only on the rod's path, the sampling and the density) and shared by its fluids; each fluid costs one
truth simulation, read by several sensor models. A shard appends each fluid's pairs to its JSON-lines file as soon
as they exist, so an interrupted shard resumes where it stopped; a fluid that fails is retried and, if it keeps
failing, written to the shard's failure file, which ``collect`` reports (a shard is never silently short).
"""

from __future__ import annotations

import hashlib
import json
import math
import time
import traceback
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
import torch

from diffstir.density import density_estimate
from diffstir.errors import ConfigError, check_choices, is_number, is_whole
from diffstir.fitting import (PROBE_INDEX_STEP, StirProblem, ViscosityLadder, Windows, effective_shear_rate,
                              mean_stirring_speed)
from diffstir.lab import (
    FiniteElementTruth, Fluid, HiddenPhysicsSpec, SensorModel, TruthSimulation, make_fluid_law, read_truth,
    simulate_truth, stirring_programme,
)
from diffstir.mpm import SimConfig
from diffstir.report_files import write_text_atomically
from diffstir.rheology import LAWS, within_bounds
from diffstir.rig import Rig

PAIRS_FORMAT = "diffstir-rectifier-pairs/1"

#: Newtonian-equivalent viscosities [Pa·s] at which a group's effective shear rate is measured; in between,
#: ln γ̇_eff is interpolated linearly in ln η (inertia makes γ̇_eff depend on the fluid, unlike Metzner-Otto's
#: creeping-flow constant), and held constant outside.
RATE_PROBES = (0.1, 1.0, 10.0)

#: How γ̇_eff was measured (``diffstir.fitting.initial.effective_shear_rate``). Shards measured otherwise are
#: brought up to date when they resume: the group's rates are measured again and every pair's reference is
#: recomputed from its stored law, without rerunning a truth simulation.
SHEAR_RATE_METHOD = f"mean |reading|, power-law probes n = 1 +- {PROBE_INDEX_STEP}"


@dataclass(frozen=True)
class PairDesign:
    """What the pair set spans. Shards are the (programme, density) groups, programme-major.

    Attributes:
        programmes: circles the rod stirs on, each {radius [m], speed [m/s]}.
        densities: fluid densities [kg/m³].
        duration: recording length [s] (at least one stirring period of every programme).
        ramp_time: speed ramp at the start [s].
        fluids_per_shard: truth simulations per group.
        sensors_per_fluid: sensor models (recordings) per truth simulation.
        viscosity: range [Pa·s] of the reference viscosity, drawn log-uniform.
        laws: probability of each law family.
        sensor: ranges of the drawn sensor models (see ``draw_sensor``).
        physics: hidden physics of every truth simulation (``HiddenPhysicsSpec.from_mapping``; none by default).
        window, holdout_fraction: the fit window of ``identify`` [s] and its held-out fraction.
        seed: root of every random number.
    """

    programmes: tuple[Mapping, ...]
    densities: tuple[float, ...]
    duration: float = 2.0
    ramp_time: float = 0.2
    fluids_per_shard: int = 10
    sensors_per_fluid: int = 10
    viscosity: tuple[float, float] = (1e-3, 10.0)
    laws: Mapping = field(default_factory=lambda: {"newtonian": 1.0})
    sensor: Mapping = field(default_factory=dict)
    physics: Mapping | None = None
    window: float = 2.0
    holdout_fraction: float = 0.25
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.programmes or not self.densities:
            raise ConfigError("pairs.design: programmes and densities must both be non-empty")
        for name, value, unit in (("duration", self.duration, "s"), ("window", self.window, "s")):
            if not (is_number(value) and value > 0):
                raise ConfigError(f"pairs.design.{name} = {value!r} {unit}; expected a positive time in {unit}")
        if not (is_number(self.ramp_time) and self.ramp_time >= 0):
            raise ConfigError(f"pairs.design.ramp_time = {self.ramp_time!r} s; expected a time >= 0 in s")
        for p in self.programmes:
            if set(p) != {"radius", "speed"} or not all(is_number(p[k]) and p[k] > 0 for k in p):
                raise ConfigError(f"pairs.design.programmes: {dict(p)}; expected {{radius: m, speed: m/s}}, both "
                                  "positive")
            period = 2 * math.pi * p["radius"] / p["speed"]
            if self.duration < period + self.ramp_time:
                raise ConfigError(f"pairs.design.duration = {self.duration} s is shorter than one stirring period "
                                  f"({period:.3g} s) after the {self.ramp_time} s ramp of programme {dict(p)}")
        for rho in self.densities:
            if not 500.0 <= rho <= 3000.0:
                raise ConfigError(f"pairs.design.densities: {rho}; expected a liquid's density in kg/m^3")
        for name in ("fluids_per_shard", "sensors_per_fluid"):
            value = getattr(self, name)
            if not is_whole(value, 1):
                raise ConfigError(f"pairs.design.{name} = {value!r}; expected a whole number of at least 1")
        lo, hi = self.viscosity
        if not 0 < lo < hi:
            raise ConfigError(f"pairs.design.viscosity = {self.viscosity}; expected 0 < low < high in Pa s")
        check_choices("pairs.design.laws", list(self.laws), sorted(LAW_DRAWS))
        if not self.laws or not all(is_number(p) and p >= 0 for p in self.laws.values()) \
                or not sum(self.laws.values()) > 0:
            raise ConfigError(f"pairs.design.laws = {dict(self.laws)}; expected probabilities >= 0 [1] of one law "
                              "or more, not all 0")
        check_choices("pairs.design.sensor", list(self.sensor), [f.name for f in fields(SensorModel)])
        try:
            HiddenPhysicsSpec.from_mapping(self.physics)
        except (TypeError, ValueError) as error:
            raise ConfigError(f"pairs.design.physics: {error}") from None
        if not (is_number(self.holdout_fraction) and 0.0 <= self.holdout_fraction < 1.0):
            raise ConfigError(f"pairs.design.holdout_fraction = {self.holdout_fraction!r}; expected a fraction of "
                              "the window in [0, 1)")
        if not is_whole(self.seed, 0):
            raise ConfigError(f"pairs.design.seed = {self.seed!r}; expected a whole number of at least 0")

    @property
    def shards(self) -> int:
        return len(self.programmes) * len(self.densities)

    @property
    def pairs(self) -> int:
        return self.shards * self.fluids_per_shard * self.sensors_per_fluid

    def group(self, shard: int) -> tuple[Mapping, float]:
        """(programme, density) of ``shard``."""
        if not 0 <= shard < self.shards:
            raise ConfigError(f"shard = {shard}; expected 0 <= shard < {self.shards} (programmes x densities)")
        return self.programmes[shard // len(self.densities)], float(self.densities[shard % len(self.densities)])

    def digest(self) -> str:
        """A short hash of the design: shards written under another design are refused."""
        return _digest(asdict(self))

    def group_digest(self) -> str:
        """A short hash of the fields a group's simulations depend on (``GROUP_FIELDS``): a design that draws more
        or other fluids or sensors reuses the groups of one that did not."""
        return _digest({k: v for k, v in asdict(self).items() if k in GROUP_FIELDS})


#: The design's fields that a group's ladder and effective shear rates depend on.
GROUP_FIELDS = ("programmes", "densities", "duration", "ramp_time", "sensor", "physics", "window", "holdout_fraction")


def _digest(fields: Mapping) -> str:
    return hashlib.sha256(json.dumps(_plain(fields), sort_keys=True).encode()).hexdigest()[:16]


def draw_fluid(rng: np.random.Generator, design: PairDesign, shear_rate_of, density: float) -> tuple[Fluid, float]:
    """A fluid whose apparent viscosity η at the stir's effective shear rate γ̇ = ``shear_rate_of(η)`` [1/s] is
    log-uniform over ``design.viscosity``, of a law family drawn with ``design.laws`` probabilities and a random
    shape (``LAW_DRAWS``); returns the fluid and γ̇."""
    names = sorted(design.laws)
    p = np.array([design.laws[n] for n in names], dtype=float)
    lo, hi = design.viscosity
    for _ in range(1000):  # a draw whose parameters fall outside the law's bounds is drawn again
        name = names[rng.choice(len(names), p=p / p.sum())]
        target = math.exp(rng.uniform(math.log(lo), math.log(hi)))
        shear_rate = shear_rate_of(target)
        params = LAW_DRAWS[name](rng, target, shear_rate)
        if all(s.bounds[0] <= params[k] <= s.bounds[1] for k, s in LAWS[name].specs.items()):
            break
    else:
        raise ValueError("pairs.design: no fluid within the laws' bounds in 1000 draws; check viscosity and laws")
    fluid = Fluid(name=f"{name} {target:.4g} Pa s", density=density, law={"name": name, "params": params},
                  source="diffstir.rectifier.pairs.draw_fluid")
    return fluid, shear_rate


def _newtonian(rng, eta, g):
    return {"eta": eta}


def _power_law(rng, eta, g):
    n = rng.uniform(0.4, 1.3)  # shear-thinning to shear-thickening (corn starch)
    return {"k": eta / g ** (n - 1.0), "n": n}


def _carreau(rng, eta, g):
    n, lam, ratio = rng.uniform(0.3, 0.8), math.exp(rng.uniform(math.log(0.1), math.log(10.0))), 1e-2
    f = (1.0 + (lam * g) ** 2) ** ((n - 1.0) / 2.0)  # η = η∞ + (η0 − η∞) f
    eta_inf = max(ratio * eta, 1e-4)
    return {"eta0": eta_inf + (eta - eta_inf) / f, "eta_inf": eta_inf, "lam": lam, "n": n}


def _cross(rng, eta, g):
    n, lam, ratio = rng.uniform(0.5, 1.0), math.exp(rng.uniform(math.log(0.1), math.log(10.0))), 1e-2
    f = 1.0 / (1.0 + (lam * g) ** n)  # η = η∞ + (η0 − η∞) f
    eta_inf = max(ratio * eta, 1e-4)
    return {"eta0": eta_inf + (eta - eta_inf) / f, "eta_inf": eta_inf, "lam": lam, "n": n}


def _herschel_bulkley(rng, eta, g):
    share, n = rng.uniform(0.1, 0.5), rng.uniform(0.5, 1.0)  # the yield stress's share of the stress at g
    stress = eta * g
    return {"tau_y": share * stress, "k": (1.0 - share) * stress / g ** n, "n": n}


#: Random shapes of each law family with η(γ̇) equal to a target: (rng, η [Pa·s], γ̇ [1/s]) -> SI parameters.
LAW_DRAWS = {"newtonian": _newtonian, "power_law": _power_law, "carreau": _carreau, "cross": _cross,
             "herschel_bulkley": _herschel_bulkley}


def draw_sensor(rng: np.random.Generator, ranges: Mapping) -> SensorModel:
    """A sensor model with fields drawn from ``ranges``: a [low, high] pair is drawn uniformly (log-uniformly for
    ``noise_std``), a {mean, std} mapping normally, and a plain value is kept."""
    values = {}
    for key, spec in ranges.items():
        if isinstance(spec, Mapping):
            values[key] = float(rng.normal(spec["mean"], spec["std"]))
        elif isinstance(spec, (list, tuple)) and len(spec) == 2 and key != "axis":
            lo, hi = float(spec[0]), float(spec[1])
            values[key] = math.exp(rng.uniform(math.log(lo), math.log(hi))) if key == "noise_std" and lo > 0 \
                else float(rng.uniform(lo, hi))
        else:
            values[key] = tuple(spec) if isinstance(spec, (list, tuple)) else spec
    return SensorModel(**values)


@dataclass(frozen=True)
class ShardPaths:
    """The files of one shard under the pair set's directory."""

    pairs: Path
    failures: Path
    group: Path

    @classmethod
    def of(cls, out: Path, shard: int) -> "ShardPaths":
        stem = Path(out) / "shards" / f"shard-{shard:04d}"
        return cls(stem.with_suffix(".jsonl"), stem.with_suffix(".failures.jsonl"), stem.with_suffix(".group.json"))


def run_shard(design: PairDesign, shard: int, out: str | Path, *, truth_config: SimConfig | FiniteElementTruth,
              estimator_config: SimConfig, retries: int = 2, log=print) -> dict:
    """Make the pairs of ``shard`` into ``out``/shards (resuming), and return the shard's counts. The truth is a
    2-D or 3-D MPM simulation (a ``SimConfig``) or the 3-D cup by finite elements (a ``FiniteElementTruth``)."""
    physics = HiddenPhysicsSpec.from_mapping(design.physics)
    if isinstance(truth_config, FiniteElementTruth) and (physics.in_material or physics.slip_length > 0):
        raise ConfigError("pairs.design.physics: hidden physics needs an MPM truth (lab/sim@truth=pairs2d or "
                          "truth2d); the 3-D finite-element truth (fe3d) holds a generalized-Newtonian law only")
    paths = ShardPaths.of(Path(out), shard)
    paths.pairs.parent.mkdir(parents=True, exist_ok=True)
    programme, density = design.group(shard)
    trajectory = stirring_programme([{"speed": programme["speed"], "duration": design.duration}],
                                    radius=programme["radius"], ramp_time=design.ramp_time)
    done = _finished_fluids(paths.pairs, design.digest())
    group = _group(design, shard, paths.group, trajectory, density, physics, truth_config, estimator_config, log)
    _update_references(paths.pairs, group, log)
    ladder = ViscosityLadder(tuple(group["ladder"]["viscosities"]), tuple(group["ladder"]["mean_abs"]))
    failures = []
    for k in range(design.fluids_per_shard):
        fluid_id = f"s{shard:04d}-f{k:03d}"
        if fluid_id in done:
            continue
        for attempt in range(retries + 1):
            try:
                lines = _fluid_pairs(design, shard, k, fluid_id, group, ladder, trajectory, density, physics,
                                     truth_config, estimator_config)
                with paths.pairs.open("a", encoding="utf-8") as f:
                    f.write("".join(json.dumps(line) + "\n" for line in lines))
                log(f"shard {shard}: {fluid_id} done ({len(lines)} pairs, {lines[0]['truth_seconds']:.1f} s)")
                break
            except Exception as exc:  # noqa: BLE001 - every failure is recorded, retried, then reported
                log(f"shard {shard}: {fluid_id} attempt {attempt + 1} failed: {exc!r}")
                if attempt == retries:
                    failures.append({"fluid_id": fluid_id, "error": repr(exc), "traceback": traceback.format_exc(),
                                     "attempts": retries + 1, "design": design.digest()})
    if failures:
        with paths.failures.open("a", encoding="utf-8") as f:
            f.write("".join(json.dumps(x) + "\n" for x in failures))
    elif paths.failures.exists():
        paths.failures.unlink()  # every fluid that failed before has its pairs now
    finished = _finished_fluids(paths.pairs, design.digest())
    return {"shard": shard, "fluids": len(finished), "expected_fluids": design.fluids_per_shard,
            "failed": [x["fluid_id"] for x in failures]}


def _group(design, shard, path, trajectory, density, physics, truth_config, estimator_config, log) -> dict:
    """The group's ladder and effective shear rates, simulated once and kept in ``path``, with the truth's
    numerics: a group kept for another truth is refused (its sample times and its pairs are that truth's)."""
    group = json.loads(path.read_text()) if path.exists() else {}
    truth = truth_config.numerics()
    if group.get("truth", truth) != truth:
        raise ValueError(f"{path}: made for another truth ({group['truth']}, not {truth}); use another out "
                         "directory")
    # groups written before group digests existed carry the whole design's digest
    same_group = group.get("group_digest", group.get("design")) in (design.group_digest(), design.digest())
    if same_group and group.get("shear_rate_method") == SHEAR_RATE_METHOD:
        if group.get("group_digest") != design.group_digest() or "truth" not in group:
            group.update(group_digest=design.group_digest(), truth=truth)
            path.write_text(json.dumps(group))
        return group
    started = time.perf_counter()
    # the group's sampling from a silent recording of the same path (no simulation): the finite elements' step
    # times, or for an MPM truth mid-step force times, which for any step shorter than the sampling interval give
    # the same sample times
    times = (truth_config.times(trajectory) if isinstance(truth_config, FiniteElementTruth)
             else np.linspace(1e-6, design.duration - 1e-6, int(design.duration * 1e4) + 1))
    silent = TruthSimulation.silent(Fluid("silent", density, {"name": "newtonian", "params": {"eta": 1.0}}),
                                    trajectory, Rig(), times, estimator_config, physics)
    template = read_truth(silent, SensorModel(**_fixed(design.sensor))).recording
    problem = _problem(template, estimator_config, density, design)
    if same_group:  # measured before γ̇_eff's definition changed: keep the ladder
        ladder = ViscosityLadder(tuple(group["ladder"]["viscosities"]), tuple(group["ladder"]["mean_abs"]))
    else:
        ladder = ViscosityLadder.simulate(problem)
    rates = {str(eta): effective_shear_rate(problem, eta) for eta in RATE_PROBES}
    group = {"design": design.digest(), "group_digest": design.group_digest(), "truth": truth,
             "shard": shard, "density": density,
             "programme": dict(design.group(shard)[0]),
             "ladder": {"viscosities": list(ladder.viscosities), "mean_abs": list(ladder.mean_abs)},
             "effective_shear_rates": rates, "shear_rate_method": SHEAR_RATE_METHOD,
             "times": problem.times.tolist(), "seconds": group.get("seconds", 0.0) + time.perf_counter() - started}
    path.write_text(json.dumps(group))
    log(f"shard {shard}: ladder and effective shear rate in {group['seconds']:.1f} s")
    return group


def _update_references(path: Path, group: Mapping, log) -> None:
    """Recompute the reference viscosity of every pair in ``path`` whose γ̇_eff was measured by another method
    than ``group``'s: the fixed point η_ref = η_law(γ̇_eff(η_ref)) of its stored law (its fluid's truth simulation
    and readings do not depend on γ̇_eff)."""
    if not path.exists():
        return
    lines = [json.loads(x) for x in path.read_text(encoding="utf-8").splitlines() if x.strip()]
    stale = [r for r in lines if r.get("shear_rate_method") != group["shear_rate_method"]]
    if not stale:
        return
    for r in stale:
        params = within_bounds(r["law"], r["law_parameters"])  # stored in float32: round-off may cross a bound
        law = make_fluid_law({"name": r["law"], "params": params}).double()
        eta = r["reference_viscosity"]
        for _ in range(50):
            rate = group_shear_rate(group, eta)
            eta = float(law(torch.tensor([rate], dtype=torch.float64)).item())
        r.update(reference_viscosity=eta, effective_shear_rate=rate, shear_rate_method=group["shear_rate_method"])
    write_text_atomically(path, "".join(json.dumps(r) + "\n" for r in lines))
    log(f"shard {group['shard']}: references of {len(stale)} pairs recomputed at the group's effective shear rates")


def group_shear_rate(group: Mapping, eta: float) -> float:
    """The group's effective shear rate [1/s] for a fluid of Newtonian-equivalent viscosity ``eta`` [Pa·s]."""
    etas = np.log([float(k) for k in group["effective_shear_rates"]])
    rates = np.log(list(group["effective_shear_rates"].values()))
    return float(math.exp(np.interp(math.log(eta), etas, rates)))


def _fixed(ranges: Mapping) -> dict:
    """The sensor fields that are not drawn (the template recording only needs its mode and sampling)."""
    keep = {"mode", "axis", "one_sided", "sample_rate"}
    return {k: (tuple(v) if isinstance(v, (list, tuple)) else v) for k, v in ranges.items() if k in keep}


def _problem(recording, config: SimConfig, density: float, design: PairDesign) -> StirProblem:
    return StirProblem(recording, config, density, Windows.of(recording, design.window, design.holdout_fraction))


def _fluid_pairs(design, shard, k, fluid_id, group, ladder, trajectory, density, physics, truth_config,
                 estimator_config) -> list[dict]:
    seeds = np.random.SeedSequence([design.seed, shard, k]).spawn(design.sensors_per_fluid + 1)
    rng = np.random.default_rng(seeds[0])
    fluid, shear_rate = draw_fluid(rng, design, lambda eta: group_shear_rate(group, eta), density)
    law = fluid.make_law()
    reference = float(law(torch.tensor([shear_rate], dtype=torch.float64)).item())
    started = time.perf_counter()
    truth = simulate_truth(fluid, trajectory, sim_config=truth_config, physics=physics,
                           seed=int(seeds[0].generate_state(1)[0]))
    truth_seconds = time.perf_counter() - started
    lines = []
    for s in range(design.sensors_per_fluid):
        sensor_rng = np.random.default_rng(seeds[s + 1])
        sensor = draw_sensor(sensor_rng, design.sensor)
        seed = int(seeds[s + 1].generate_state(1)[0])
        lab = read_truth(truth, sensor, seed=seed, name=f"{fluid_id}-r{s:02d}")
        rho = density_estimate(lab.recording, None)
        problem = _problem(lab.recording, estimator_config, rho["value"], design)
        if not np.array_equal(problem.times, np.asarray(group["times"])):
            raise RuntimeError(f"{fluid_id}: the recording's sample times differ from the group's ladder")
        lines.append({
            "format": PAIRS_FORMAT, "design": design.digest(), "pair_id": f"{fluid_id}-r{s:02d}",
            "fluid_id": fluid_id, "shard": shard,
            "mean_stirring_speed": mean_stirring_speed(problem),
            "preliminary_viscosity": ladder.estimate(problem),
            "reference_viscosity": reference,
            "resolves": ladder.resolves(problem.mean_reading()),
            "effective_shear_rate": shear_rate, "shear_rate_method": group["shear_rate_method"],
            "law": fluid.law["name"], "law_parameters": law.parameters_si(),
            "zero_shear_viscosity": float(law.zero_shear_viscosity().item()),
            "density": density, "density_estimate": rho["value"],
            "programme": dict(group["programme"]), "sensor": sensor.as_dict(), "sensor_seed": seed,
            "physics": physics.as_dict(), "truth_seconds": truth_seconds,
            "truth_config": truth_config.numerics(), "estimator_config": estimator_config.numerics(),
        })
    return lines


def _finished_fluids(path: Path, digest: str) -> set[str]:
    if not path.exists():
        return set()
    fluids = set()
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            raise ValueError(f"{path}:{number}: not a JSON line (a shard file cut mid-write?); "
                             "delete that line to resume") from None
        if record.get("design") != digest:
            raise ValueError(f"{path}:{number}: written under another pair design ({record.get('design')} != "
                             f"{digest}); use another out directory")
        fluids.add(record["fluid_id"])
    return fluids


def collect(design: PairDesign, out: str | Path) -> dict:
    """Gather every shard's pairs into ``out``/pairs.jsonl and write ``out``/manifest.json: counts per shard,
    missing and failed fluids, seeds and the data's SHA-256. ``complete`` is false unless every pair exists."""
    out = Path(out)
    shards, lines, failed = [], [], []
    for shard in range(design.shards):
        paths = ShardPaths.of(out, shard)
        records = []
        if paths.pairs.exists():
            records = [json.loads(x) for x in paths.pairs.read_text(encoding="utf-8").splitlines() if x.strip()]
        fluids = sorted({r["fluid_id"] for r in records})
        failures = ([json.loads(x)["fluid_id"] for x in paths.failures.read_text().splitlines() if x.strip()]
                    if paths.failures.exists() else [])
        failed += failures
        shards.append({"shard": shard, "programme": dict(design.group(shard)[0]), "density": design.group(shard)[1],
                       "pairs": len(records), "fluids": len(fluids), "failed": failures,
                       "missing_fluids": design.fluids_per_shard - len(fluids)})
        lines += records
    lines.sort(key=lambda r: r["pair_id"])
    text = "".join(json.dumps(r, sort_keys=True) + "\n" for r in lines)
    write_text_atomically(out / "pairs.jsonl", text)
    truth_seconds = {r["fluid_id"]: r["truth_seconds"] for r in lines}
    manifest = {
        "format": PAIRS_FORMAT, "design": _plain(asdict(design)), "design_digest": design.digest(),
        "pairs": len(lines), "expected_pairs": design.pairs, "fluids": len(truth_seconds),
        "complete": len(lines) == design.pairs and not failed, "failed": failed,
        "sha256": hashlib.sha256(text.encode()).hexdigest(),
        "truth_seconds_total": sum(truth_seconds.values()),
        "group_seconds_total": sum(json.loads(ShardPaths.of(out, s).group.read_text())["seconds"]
                                   for s in range(design.shards) if ShardPaths.of(out, s).group.exists()),
        "shards": shards,
    }
    write_text_atomically(out / "manifest.json", json.dumps(manifest, indent=1) + "\n")
    return manifest


def design_from_mapping(cfg: Mapping) -> PairDesign:
    """A ``PairDesign`` from a plain mapping (a Hydra config's ``design`` node)."""
    cfg = dict(cfg)
    cfg["programmes"] = tuple(dict(p) for p in cfg["programmes"])
    cfg["densities"] = tuple(float(x) for x in cfg["densities"])
    cfg["viscosity"] = tuple(float(x) for x in cfg["viscosity"])
    cfg["laws"] = dict(cfg.get("laws") or {"newtonian": 1.0})
    cfg["sensor"] = dict(cfg.get("sensor") or {})
    return PairDesign(**cfg)


def _plain(value):
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value
