"""Identification against a 3-D truth the simulator did not make (docs/accuracy.md, "Against a 3-D truth").

Per case, a rig and a fluid: the virtual lab writes a recording whose force is the stir in the 3-D cup by finite
elements (``lab/sim=fe3d``, conf/lab/sim/fe3d.yaml) read through the paper's sensor (conf/lab/sensor/paper.yaml,
seed = case index), and the default fit (conf/fit.yaml: coarse2d then slice2d, the first 2 s, model error 0.03)
identifies it with the fluid's own law, twice: with the slice correction (the default, F'_2D h C) and without it
(the paper's extruded slice, F'_2D h). Reported per fit: the law's parameters with their 95 % intervals, the law's
apparent viscosity at the fit's effective shear rate against the truth's there, the errors, whether the intervals
hold the truth, and the law the fit selects (the Newtonian law is always fitted too; where the BIC prefers it,
``diffstir-fit`` reports its viscosity instead).

Rigs: the project's default (conf/rig/paper.yaml on a 15 mm circle) and the study's ``shallow`` rig, both in the
slice-correction study (scripts/slice_error.py), and ``held_out``, a rig the study never saw. Fluids: Newtonian
from 0.03 to 10 Pa·s at one speed, and 0.1 Pa·s at a quarter of it (``_slow``); power-law (thinning and
thickening), Carreau and Herschel-Bulkley fluids at three speeds inside the fitted 1.5 s and a fourth in the
held-out 0.5 s.

    python scripts/truth3d_benchmark.py --out docs/data/truth3d.json --recordings outputs/truth3d --jobs 2
    python scripts/truth3d_benchmark.py --cases project/newtonian_1 --out /tmp/t3.json
    python scripts/truth3d_benchmark.py --recordings outputs/truth3d --sim compressibility=0.003 --out /tmp/c.json
    python scripts/truth3d_benchmark.py --cases held_out/power_law_1.3 --fit fine_iterations=8 --out /tmp/f.json
    python scripts/truth3d_benchmark.py --models default --recordings outputs/truth3d --out /tmp/s.json --jobs 2
    python scripts/truth3d_benchmark.py --table docs/data/truth3d.json            # the markdown tables only
    python scripts/truth3d_benchmark.py --compare project/newtonian_0.1           # where the forces differ
    python scripts/truth3d_benchmark.py --compare held_out/power_law_1.3 \\
        --windows 0.3:0.5 0.5:0.7 0.8:1 1:1.2 1.3:1.5 1.7:2
``--compare RIG/FLUID`` locates a mismatch: the rod's force over the case's stir in the frame turning with it
(drag against the motion, radial outwards; means over windows) from the 3-D finite elements, the same elements'
2-D slab times the immersion, and the fitting simulator's 2-D slice (sim=slice2d with ``--sim``) times the
immersion, all at the truth's law, before any sensor or fit.

``--models default`` fits each case as ``diffstir-fit`` does, with conf/fit.yaml's laws and the BIC's selection
among them, once (with the slice correction): the selected law, the class it shows over the probed shear rates
against the truth's (``diffstir.fitting.family``'s rules applied to the truth's law), the report's apparent viscosity
with the selection's uncertainty, and every law's BIC, held-out loss and apparent viscosity.

``--recordings DIR`` keeps each case's recording and truth there (``DIR/<rig>_<fluid>``) and reuses them when
present, so other fit settings (``--sim KEY=VALUE``, applied to both resolutions; ``--fit KEY=VALUE``, conf/fit.yaml's
fit block) run without the truth's cost.
Needs the validation extra (``pip install -c constraints.txt -e ".[validation]"``).
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import sys
import time
import signal
from multiprocessing import get_context
from pathlib import Path

import yaml

from diffstir.fitting import FitSettings
from diffstir.fitting.uncertainty import MAX_FACTOR

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
RAMP = 0.2  # s
ONE_SPEED = [{"speed": 0.08, "duration": 2.0}]  # m/s, s
SLOW = [{"speed": 0.02, "duration": 7.2}]  # m/s, s: a thin fluid stirred as an inertia-dominated report advises,
# for one turn of the widest circle, which a recording spans (diffstir.recording.validate); the fit takes its first 2 s
SPEED_STEPS = [{"speed": s, "duration": 0.5} for s in (0.04, 0.08, 0.16, 0.11)]  # m/s, s: the default fit's
# first 1.5 s hold three speeds a factor 4 apart; its held-out last 0.5 s, a fourth it never saw between them
RIGS = {  # cup radius, fill height, cup height, rod radius, immersion depth, circle radius [m]
    "project": (0.0425, 0.13005, 0.165, 0.0125, 0.080, 0.015),
    "shallow": (0.0475, 0.090, 0.120, 0.0125, 0.040, 0.020),
    "held_out": (0.045, 0.095, 0.120, 0.011, 0.070, 0.022),
}
FLUIDS = {  # name: (density [kg/m³], law, programme)
    "newtonian_0.03": (1000.0, {"name": "newtonian", "params": {"eta": 0.03}}, ONE_SPEED),
    "newtonian_0.1": (1100.0, {"name": "newtonian", "params": {"eta": 0.1}}, ONE_SPEED),
    "newtonian_1": (1200.0, {"name": "newtonian", "params": {"eta": 1.0}}, ONE_SPEED),
    "newtonian_5": (1260.0, {"name": "newtonian", "params": {"eta": 5.0}}, ONE_SPEED),
    "power_law_0.6": (1050.0, {"name": "power_law", "params": {"k": 1.5, "n": 0.6}}, SPEED_STEPS),
    "power_law_1.3": (1150.0, {"name": "power_law", "params": {"k": 0.3, "n": 1.3}}, SPEED_STEPS),
    "carreau": (1100.0, {"name": "carreau", "params": {"eta0": 2.0, "eta_inf": 0.01, "lam": 1.0, "n": 0.5}},
                SPEED_STEPS),
    "herschel_bulkley": (1100.0, {"name": "herschel_bulkley", "params": {"tau_y": 1.0, "k": 0.8, "n": 0.6}},
                         SPEED_STEPS),
    "newtonian_10": (1400.0, {"name": "newtonian", "params": {"eta": 10.0}}, ONE_SPEED),
    "newtonian_0.1_slow": (1100.0, {"name": "newtonian", "params": {"eta": 0.1}}, SLOW),
}  # a new fluid goes last: a case's sensor seed is its index in CASES
CASES = [f"{rig}/{fluid}" for fluid in FLUIDS for rig in RIGS]
RECTIFIER = ROOT / "checkpoints" / "rectifier" / "rectifier.ckpt"


def table_order(case: str) -> tuple:
    """Where ``case`` sits in a table: Newtonian fluids first by viscosity (the faster stir first), then the others
    as in CASES."""
    if case not in CASES:
        return (2, 0.0, 0)
    law = FLUIDS[case.split("/")[1]][1]
    newtonian = law["name"] == "newtonian"
    return (0 if newtonian else 1, law["params"]["eta"] if newtonian else 0.0, CASES.index(case))


def rig_of(name: str):
    from diffstir.rig import Cup, Rig, Rod

    cup_radius, fill, height, rod_radius, immersion, _ = RIGS[name]
    return Rig(cup=Cup(radius=cup_radius, fill_height=fill, height=height),
               rod=Rod(radius=rod_radius, immersion_depth=immersion, length=0.25))


def fe_config():
    """The 3-D truth's default discretisation, ``conf/lab/sim/fe3d.yaml``."""
    from diffstir.lab import FiniteElementTruth

    settings = yaml.safe_load((CONF / "lab/sim/fe3d.yaml").read_text())
    return FiniteElementTruth(**{k: v for k, v in settings.items() if k != "_target_"})


def sim_config(name: str, sim_settings: dict | None = None):
    """The fitting simulator's preset ``conf/sim/<name>.yaml`` with ``sim_settings`` (``--sim``) applied."""
    from dataclasses import replace

    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    return replace(instantiate(OmegaConf.load(CONF / f"sim/{name}.yaml")), **(sim_settings or {}))


def lab_recording(index: int, case: str, recordings: Path | None = None):
    """The case's 3-D truth recording through the paper's sensor (seed = ``index``), kept in and reused from
    ``recordings``: (recording, truth, seconds the truth took)."""
    import numpy as np

    from diffstir.lab import Fluid, SensorModel, stirring_programme, synthesise, truth_path, write_lab_recording
    from diffstir.recording import load_recording

    rig_name, fluid_name = case.split("/")
    density, law, programme = FLUIDS[fluid_name]
    fluid = Fluid(name=fluid_name, density=density, law=law)
    trajectory = stirring_programme(programme, radius=RIGS[rig_name][-1], ramp_time=RAMP)
    sensor = SensorModel(**yaml.safe_load((CONF / "lab/sensor/paper.yaml").read_text()))
    started = time.perf_counter()
    kept = recordings / case.replace("/", "_") if recordings else None
    if kept is not None and kept.exists():
        recording = load_recording(kept)
        path = trajectory.poses(recording.t)[0]
        if not (abs(recording.duration - trajectory.t[-1]) < 0.05
                and np.allclose(path, np.stack([recording.x, recording.y], axis=-1), atol=1e-4)):
            sys.exit(f"{kept}: kept for another stir than this benchmark's programme for {case}; remove it or "
                     "choose another --recordings")
        return recording, json.loads(truth_path(kept).read_text()), time.perf_counter() - started
    lab = synthesise(fluid, trajectory, rig=rig_of(rig_name), sim_config=fe_config(), sensor=sensor, seed=index)
    if kept is not None:
        write_lab_recording(lab, kept)
    return lab.recording, lab.truth, time.perf_counter() - started


def case_row(case: str, truth: dict, truth_seconds: float, sim_settings: dict | None,
             fit_settings: dict | None = None) -> dict:
    """What a row records of its case: the rig, the fluid, its law and programme, the truth's simulator, and the
    settings (``--sim``, ``--fit``) its fits ran with."""
    rig_name, fluid_name = case.split("/")
    density, law, programme = FLUIDS[fluid_name]
    return {"case": case, "rig": rig_name, "fluid": fluid_name, "law": law, "density": density,
            "programme": programme, "circle_radius": RIGS[rig_name][-1], "truth": truth["simulator"],
            "truth_seconds": truth_seconds, "sim_settings": sim_settings or {}, "fit_settings": fit_settings or {}}


def true_viscosity(fluid_name: str, shear_rate: float) -> float:
    """The case's fluid's viscosity [Pa·s] at ``shear_rate`` [1/s]."""
    import torch

    from diffstir.lab import Fluid

    density, law, _ = FLUIDS[fluid_name]
    with torch.no_grad():
        return float(Fluid(name=fluid_name, density=density, law=law).make_law().double()(
            torch.tensor([shear_rate], dtype=torch.float64))[0])


def run_case(index: int, case: str, recordings: Path | None = None, sim_settings: dict | None = None,
             fit_settings: dict | None = None) -> dict:
    """One case: the 3-D truth recording (kept in and reused from ``recordings``), then the fit with and without
    the slice correction, both resolutions with ``sim_settings``, the fit with ``fit_settings``."""
    import torch

    from diffstir.identification import identify
    from diffstir.rectifier.apply import load_rectifier, refine

    torch.set_num_threads(1)
    fluid_name = case.split("/")[1]
    law = FLUIDS[fluid_name][1]
    recording, truth, truth_seconds = lab_recording(index, case, recordings)
    fine, coarse = sim_config("slice2d", sim_settings), sim_config("coarse2d", sim_settings)
    row = case_row(case, truth, truth_seconds, sim_settings, fit_settings)
    for corrected in (True, False):
        t0 = time.perf_counter()
        result = identify(recording, (law["name"],), config=fine, coarse=coarse, baseline=False, size_estimate=False,
                          progress=False, fit=FitSettings(**{**(fit_settings or {}), "slice_correction": corrected}))
        summary = result.summary()
        fitted = summary["laws"][law["name"]]
        apparent = fitted["apparent_viscosity"]
        rate = apparent["effective_shear_rate"]
        eta_true = true_viscosity(fluid_name, rate)
        lo, hi = apparent["at_effective_shear_rate_ci95"]
        row["corrected" if corrected else "slice_only"] = {
            "params": fitted["params"], "ci95": fitted["ci95"], "identifiable": fitted["identifiable"],
            "effective_shear_rate": rate, "eta": apparent["at_effective_shear_rate"], "eta_ci95": [lo, hi],
            "eta_true": eta_true, "error": apparent["at_effective_shear_rate"] / eta_true - 1.0,
            "covered": lo <= eta_true <= hi, "slice_correction": summary["slice_correction"],
            "viscous_share": summary["resolvable"].get("viscous_share"),
            "viscous_speed": summary["resolvable"].get("viscous_speed"), "resolvable": summary["resolvable"],
            "selected": summary["selected"],
            "seconds": time.perf_counter() - t0,
            **({"n_error": fitted["params"]["n"] - law["params"]["n"],
                "n_covered": _holds(fitted["ci95"].get("n"), law["params"]["n"])} if "n" in law["params"] else {}),
        }
        if corrected:  # the shipped rectifier on the preliminary estimate, with diffstir-fit's checks but its
            # output whether or not its held-out verdict lets diffstir-fit apply it: what it would do is measured
            rectifier, metadata = load_rectifier(RECTIFIER)
            verdict = metadata.get("held_out", {"applies": False, "reason": "records no held-out verdict"})
            refined = refine(rectifier, {**metadata, "held_out": {**verdict, "applies": True}}, result.preliminary,
                             result.density["value"], str(RECTIFIER))
            row["rectifier"] = {"preliminary": refined["preliminary"], "value": refined["value"],
                                "applied_by_diffstir_fit": verdict["applies"], "verdict": verdict["reason"],
                                "note": refined["note"], "eta_true": eta_true,
                                "effective_shear_rate": result.preliminary.get("effective_shear_rate", rate)}
    return row


def true_class(fluid_name: str, band: tuple[float, float], shear_rate: float) -> str:
    """The class the case's fluid shows over the probed ``band`` [1/s] around the stir's effective ``shear_rate``
    [1/s]: the report's classification of a fitted law (``diffstir.fitting.family.law_family``) applied to the
    truth's law, which has no uncertainty."""
    import numpy as np

    from diffstir.fitting import FitModel
    from diffstir.fitting.family import law_family
    from diffstir.fitting.uncertainty import Uncertainty

    law = FLUIDS[fluid_name][1]
    model = FitModel.named(law["name"], **law["params"])
    exact = Uncertainty(covariance=np.zeros((model.size, model.size)), ci95={}, identifiable={}, at_bound={},
                        effective_samples=math.inf, residual_std=0.0)
    return law_family(model, model.theta(), exact, band, shear_rate)["class"]


def run_selection_case(index: int, case: str, recordings: Path | None = None,
                       sim_settings: dict | None = None, fit_settings: dict | None = None) -> dict:
    """One case fitted as ``diffstir-fit`` does, with every law of conf/fit.yaml's ``model`` and the BIC's
    selection (the corotated baseline, which takes no part in it, and the size estimate, beside the fits, left
    out): the selected law, its class over the probed shear rates against the truth's, the report's apparent
    viscosity with the selection's uncertainty, and every law's BIC, held-out loss and apparent viscosity."""
    import torch

    from diffstir.identification import identify

    torch.set_num_threads(1)
    fluid_name = case.split("/")[1]
    recording, truth, truth_seconds = lab_recording(index, case, recordings)
    models = yaml.safe_load((CONF / "fit.yaml").read_text())["model"]
    started = time.perf_counter()
    result = identify(recording, models, config=sim_config("slice2d", sim_settings),
                      coarse=sim_config("coarse2d", sim_settings), baseline=False, size_estimate=False, progress=False,
                      fit=FitSettings(**(fit_settings or {})))
    summary = result.summary()
    apparent = summary["apparent_viscosity"]
    rate = apparent["effective_shear_rate"]
    eta_true = true_viscosity(fluid_name, rate)
    lo, hi = apparent["at_effective_shear_rate_ci95"]
    band = summary["shear_rate_range"]
    return {**case_row(case, truth, truth_seconds, sim_settings, fit_settings), "models": models,
            "selection": {
                "selected": summary["selected"], "class": (summary["family"] or {}).get("class"),
                "true_class": true_class(fluid_name, band, rate) if band[1] > band[0] > 0 else None,
                "band": band, "effective_shear_rate": rate, "eta_true": eta_true,
                "eta": apparent["at_effective_shear_rate"], "eta_ci95": [lo, hi],
                "selected_law_ci95": apparent["selected_law_ci95"], "law_weights": apparent["law_weights"],
                "error": apparent["at_effective_shear_rate"] / eta_true - 1.0, "covered": lo <= eta_true <= hi,
                "laws": {name: {"bic": fit["bic"], "loss": fit["loss"], "holdout_loss": fit["holdout_loss"],
                                "eta": fit["apparent_viscosity"]["at_effective_shear_rate"],
                                "eta_ci95": fit["apparent_viscosity"]["at_effective_shear_rate_ci95"],
                                "class": (fit["family"] or {}).get("class"), "params": fit["params"]}
                         for name, fit in summary["laws"].items()},
                "seconds": time.perf_counter() - started}}


def compare(case: str, sim_settings: dict | None = None,
            windows=((0.0, 0.2), (0.2, 0.5), (0.5, 1.0), (1.0, 1.5), (1.5, 2.0))) -> str:
    """The markdown table of ``--compare``: mean drag and radial force [N] over ``windows`` [s], the fitting
    simulator (sim=slice2d) with ``sim_settings``."""
    import numpy as np
    import torch

    from diffstir.lab import Fluid, stirring_programme, stokes3d
    from diffstir.lab.fe_truth import circle_motion
    from diffstir.mpm import StirringSimulator

    torch.set_num_threads(1)
    rig_name, fluid_name = case.split("/")
    density, law, programme = FLUIDS[fluid_name]
    rig, orbit = rig_of(rig_name), RIGS[rig_name][-1]
    fluid = Fluid(name=fluid_name, density=density, law=law)
    trajectory = stirring_programme(programme, radius=orbit, ramp_time=RAMP)
    config = fe_config()
    times = np.arange(0.0, trajectory.t[-1] + config.dt / 2, config.dt)
    _, angle, rate, acceleration = circle_motion(trajectory, times)
    cup = stokes3d.CupRig.of(rig, orbit)
    fe_law = law["params"]["eta"] if law["name"] == "newtonian" else fluid.make_law()
    forces = {}
    for label, mesh in (("3-D finite elements", stokes3d.build_mesh(cup, config.cell, growth=config.growth)),
                        ("2-D slab × h", stokes3d.slab_mesh(cup, 0.003))):
        history = stokes3d.stir_history(mesh, fe_law, times, angle, rate, acceleration, density=density)
        scale = cup.immersion if mesh.thickness else 1.0
        along = np.where(rate < 0, -1.0, 1.0)  # the frame's y is +θ, the motion's direction for Ω > 0
        forces[label] = (times, -along * history.frame_force[:, 1] * scale, history.frame_force[:, 0] * scale)
    simulator = StirringSimulator(fluid.make_law(), rig, sim_config("slice2d", sim_settings), density=density)
    with torch.no_grad():
        result = simulator(trajectory)
    t = result.times.numpy()
    force = result.force.double().numpy()[:, :2] * rig.rod.immersion_depth
    theta = np.interp(t, times, angle)
    along = np.where(np.interp(t, times, rate) < 0, -1.0, 1.0)
    label = "MPM sim=slice2d" + "".join(f", {k}={v}" for k, v in (sim_settings or {}).items()) + " × h"
    forces[label] = (t, -along * (-np.sin(theta) * force[:, 0] + np.cos(theta) * force[:, 1]),
                     np.cos(theta) * force[:, 0] + np.sin(theta) * force[:, 1])
    lines = ["| force [N] | " + " | ".join(f"({a:g}, {b:g}] s" for a, b in windows) + " |",
             "|---|" + "---|" * len(windows)]
    for part, index in (("drag", 1), ("radial", 2)):
        for label, columns in forces.items():
            cells = []
            for a, b in windows:
                inside = (columns[0] > a) & (columns[0] <= b)
                cells.append(f"{columns[index][inside].mean():.4g}")
            lines.append(f"| {part}, {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _attempt(job: tuple) -> tuple[str, dict | None, str]:
    """``run_case`` (``run_selection_case`` for ``--models default``) in a worker: (case, row, "") or (case, None,
    the error) so that one failure stops no other."""
    index, case, recordings, sim_settings, fit_settings, models = job
    run = run_selection_case if models == "default" else run_case
    try:
        return case, run(index, case, recordings, sim_settings, fit_settings), ""
    except Exception as error:
        return case, None, f"{type(error).__name__}: {error}"


def _settings(items: list[str]) -> dict:
    """``KEY=VALUE`` items as a dict, each value a boolean, a number or text."""
    return {k: _number_or_text(v) for k, _, v in (item.partition("=") for item in items)}


def _number_or_text(value: str) -> bool | int | float | str:
    if value.lower() in ("true", "false"):
        return value.lower() == "true"
    for kind in (int, float):
        try:
            return kind(value)
        except ValueError:
            pass
    return value


def _holds(interval, value: float) -> bool:
    return interval is not None and interval[0] <= value <= interval[1]


def _verdict(fit: dict) -> str:
    """Whether the fit's 95 % interval holds the truth; "not identifiable" where the fit says so."""
    if not all(fit["identifiable"].values()):
        return "not identifiable"
    return "yes" if fit["covered"] else "no"


def _estimate(fit: dict) -> str:
    """The fitted apparent viscosity [Pa·s] with its 95 % interval; "open" where the interval spans more than the
    factor ``MAX_FACTOR`` either way that makes a log-scaled value identifiable (it then says nothing)."""
    eta, (lo, hi) = fit["eta"], fit["eta_ci95"]
    return f"{eta:.4g} [open]" if _open(fit) else f"{eta:.4g} [{lo:.4g}, {hi:.4g}]"


def _selects(fit: dict, law: str) -> str:
    """" (N selected)" where the fit selects another law than the fluid's own (the Newtonian one), else ""."""
    selected = fit.get("selected", law)
    return "" if selected == law else f" ({SHORT.get(selected, selected)} selected)"


def _open(fit: dict) -> bool:
    """Whether the apparent viscosity's interval spans more than the factor ``MAX_FACTOR`` either way."""
    eta, (lo, hi) = fit["eta"], fit["eta_ci95"]
    return not (math.isfinite(lo) and math.isfinite(hi) and lo > 0
                and hi <= MAX_FACTOR * eta and eta <= MAX_FACTOR * lo)


def table(rows: list[dict]) -> str:
    """The markdown table of ``rows``: per case the corrected fit and the slice-only one, and the reading's viscous
    share e of the corrected fit (the report's ``resolvable.viscous_share``) with, where it is below one half, the
    slower mean speed the report advises (``resolvable.viscous_speed``; "unresolved" where the report says the sensor
    would not resolve the viscosity there)."""
    lines = ["| rig | fluid | γ̇_eff [1/s] | e | η true [Pa·s] | η fitted [95 % CI] (corrected) | error | holds | "
             "C | η slice-only [95 % CI] | error | holds | n error (corrected / slice-only) | truth [s] | fits [s] |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: table_order(r["case"])):
        c, s = r["corrected"], r["slice_only"]
        n = (f"{c['n_error']:+.3f} / {s['n_error']:+.3f}" if "n_error" in c else "-")
        factor = c["slice_correction"]["factor"] if c["slice_correction"] else float("nan")
        share = f"{c['viscous_share']:.2f}" if c.get("viscous_share") is not None else "-"
        if c.get("viscous_speed") is not None:
            resolves = c.get("resolvable", {}).get("viscous_speed_resolves")
            share += f" (≤ {c['viscous_speed']:.2g} m/s{', unresolved' if resolves is False else ''})"
        lines.append(
            f"| {r['rig']} | {r['fluid']} | {c['effective_shear_rate']:.3g} | {share} | {c['eta_true']:.4g} | "
            f"{_estimate(c)}{_selects(c, r['law']['name'])} | {100 * c['error']:+.1f} % | {_verdict(c)} | "
            f"{factor:.3f} | {_estimate(s)}{_selects(s, r['law']['name'])} | {100 * s['error']:+.1f} % | "
            f"{_verdict(s)} | {n} | {r['truth_seconds']:.0f} | "
            f"{c['seconds']:.0f} + {s['seconds']:.0f} |")
    if rows:
        counts = {k: [_verdict(r[k]) for r in rows] for k in ("corrected", "slice_only")}
        lines.append("")
        lines.append("Intervals holding the truth, of the identifiable fits: " + ", ".join(
            f"{k.replace('_', '-')} {v.count('yes')}/{len(v) - v.count('not identifiable')}"
            for k, v in counts.items()) + ".")
    return "\n".join(lines)


SHORT = {"newtonian": "N", "carreau": "Ca", "cross": "Cr", "herschel_bulkley": "HB", "power_law": "PL"}


def selection_table(rows: list[dict]) -> str:
    """The markdown table of ``--models default`` rows: per case the truth's class over the probed shear rates,
    the selected law and its class, the report's apparent viscosity with the selection's uncertainty against the
    truth, and every law's BIC above the best with its own apparent viscosity's error."""
    lines = ["| rig | fluid | γ̇ band [1/s] | true class | selected (BIC weight) | its class | η true [Pa·s] | "
             "η reported [95 % CI] | error | holds | selected law's own CI holds | each law: ΔBIC, η error |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    rows = sorted(rows, key=lambda r: table_order(r["case"]))
    for r in rows:
        s = r["selection"]
        best = min(fit["bic"] for fit in s["laws"].values())
        laws = "; ".join(f"{SHORT.get(name, name)} {fit['bic'] - best:.1f}, "
                         f"{100 * (fit['eta'] / s['eta_true'] - 1):+.1f} %"
                         for name, fit in sorted(s["laws"].items(), key=lambda item: item[1]["bic"]))
        weights = ", ".join(f"{SHORT.get(n, n)} {w:.2f}" for n, w in sorted(s["law_weights"].items(),
                                                                           key=lambda item: -item[1]))
        lines.append(
            f"| {r['rig']} | {r['fluid']} | {s['band'][0]:.2g}-{s['band'][1]:.2g} | {s['true_class']} | "
            f"{s['selected']} ({weights}) | {s['class']} | {s['eta_true']:.4g} | "
            f"{_estimate(s)} | {100 * s['error']:+.1f} % | "
            f"{'open' if _open(s) else 'yes' if s['covered'] else 'no'} | "
            f"{'yes' if _holds(s['selected_law_ci95'], s['eta_true']) else 'no'} | {laws} |")
    if rows:
        picks = [r["selection"] for r in rows]
        closed = [p for p in picks if not _open(p)]
        lines += ["", f"Class right {sum(p['class'] == p['true_class'] for p in picks)}/{len(picks)}; "
                  f"apparent viscosity within 10 % {sum(abs(p['error']) <= 0.1 for p in picks)}/{len(picks)}; "
                  f"reported intervals holding the truth, of those not open, {sum(p['covered'] for p in closed)}"
                  f"/{len(closed)} (the selected law's own "
                  f"{sum(_holds(p['selected_law_ci95'], p['eta_true']) for p in closed)}/{len(closed)})."]
        for criterion, key in (("the lowest held-out loss (fit.selection=holdout)", "holdout_loss"),
                               ("the lowest loss (fit.selection=loss, the paper's)", "loss")):
            chosen = [(p, min(p["laws"].values(), key=lambda fit: fit[key])) for p in picks]
            close = sum(abs(fit["eta"] / p["eta_true"] - 1) <= 0.1 for p, fit in chosen)
            lines.append(f"The same fits selected by {criterion}: class right "
                         f"{sum(fit['class'] == p['true_class'] for p, fit in chosen)}/{len(chosen)}; its law's "
                         f"apparent viscosity within 10 % {close}/{len(chosen)}, its own interval holding the truth "
                         f"{sum(_holds(fit['eta_ci95'], p['eta_true']) for p, fit in chosen)}/{len(chosen)}.")
    return "\n".join(lines)


def tables(rows: list[dict]) -> str:
    """The markdown tables of ``rows``: the selection's for ``--models default`` rows, otherwise the own law's
    fits' and the shipped rectifier's."""
    if rows and "selection" in rows[0]:
        return selection_table(rows)
    return table(rows) + "\n\n" + rectifier_table(rows)


def rectifier_table(rows: list[dict]) -> str:
    """The shipped rectifier against the 3-D truth: |relative error| of the preliminary estimate (before) and of the
    refined one (after, where the rectifier refines), MAE, RMSE, median and p90, by fluid; beside them the MAE of
    the fitted law's apparent viscosity (the report's answer) on the same cases."""
    import numpy as np

    lines = ["| fluid | cases | refined | before: MAE | RMSE | median | p90 | after: MAE | RMSE | median | p90 | "
             "fitted law: MAE |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    groups: dict[str, list[dict]] = {}
    for r in sorted(rows, key=lambda r: table_order(r["case"])):
        if "rectifier" in r:
            groups.setdefault(r["fluid"], []).append({**r["rectifier"], "fit_error": r["corrected"]["error"]})
    groups["all"] = [x for entries in list(groups.values()) for x in entries]

    def stats(errors) -> str:
        e = np.abs(np.asarray(errors, dtype=float))
        if e.size == 0:
            return "- | - | - | -"
        return (f"{100 * e.mean():.1f} % | {100 * np.sqrt((e ** 2).mean()):.1f} % | {100 * np.median(e):.1f} % | "
                f"{100 * np.percentile(e, 90):.1f} %")

    for fluid, entries in groups.items():
        refined = [x for x in entries if x["value"] is not None]
        before = [x["preliminary"] / x["eta_true"] - 1 for x in refined]
        after = [x["value"] / x["eta_true"] - 1 for x in refined]
        fitted = np.abs([x["fit_error"] for x in refined])
        lines.append(f"| {fluid} | {len(entries)} | {len(refined)} | {stats(before)} | {stats(after)} | "
                     f"{100 * fitted.mean():.1f} % |" if refined else f"| {fluid} | {len(entries)} | 0 | "
                     f"{stats([])} | {stats([])} | - |")
    notes = sorted({x["note"] for entries in groups.values() for x in entries if x["value"] is None})
    if notes:
        text = "; ".join(notes)
        lines += ["", text[0].upper() + text[1:] + "."]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=CASES, choices=CASES, metavar="RIG/FLUID",
                        help=f"cases to run (default: all {len(CASES)})")
    parser.add_argument("--out", type=Path, help="the JSON rows (resumed: finished cases are skipped)")
    parser.add_argument("--jobs", type=int, default=1, help="cases side by side, one thread each")
    parser.add_argument("--recordings", type=Path, help="keep (and reuse) each case's recording and truth here")
    parser.add_argument("--sim", nargs="+", default=[], metavar="KEY=VALUE",
                        help="SimConfig settings for both fit resolutions, e.g. compressibility=0.003 or "
                        "pressure=projection")
    parser.add_argument("--fit", nargs="+", default=[], metavar="KEY=VALUE",
                        help="FitSettings for every fit (conf/fit.yaml's fit block), e.g. fine_iterations=8")
    parser.add_argument("--models", choices=("own", "default"), default="own",
                        help="own: each fluid's own law, with and without the slice correction (default); default: "
                        "conf/fit.yaml's laws and the BIC's selection among them")
    parser.add_argument("--windows", nargs="+", default=["0:0.2", "0.2:0.5", "0.5:1", "1:1.5", "1.5:2"],
                        metavar="START:END", help="--compare's time windows [s] (default: %(default)s)")
    parser.add_argument("--table", type=Path, help="print the tables of an existing JSON file and exit")
    parser.add_argument("--compare", choices=CASES, metavar="RIG/FLUID",
                        help="print where the forces of the truth, the slab and the fitting simulator differ, and exit")
    args = parser.parse_args()
    sim_settings, fit_settings = _settings(args.sim), _settings(args.fit)
    try:  # an unknown or invalid setting is refused before any simulation
        FitSettings(**fit_settings)
    except (TypeError, ValueError) as error:
        sys.exit(f"--fit {' '.join(args.fit)}: {error}")
    if args.compare:
        windows = [tuple(float(x) for x in w.split(":")) for w in args.windows]
        print(compare(args.compare, sim_settings, windows))
        return
    if args.table:
        print(tables(json.loads(args.table.read_text())["rows"]))
        return
    data = json.loads(args.out.read_text()) if args.out and args.out.exists() else {
        "description": __doc__.splitlines()[0], "command": "python scripts/truth3d_benchmark.py "
        + " ".join(sys.argv[1:]), "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, {platform.platform()}",
        "started": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "models": args.models, "rows": []}
    if data.get("models", "own") != args.models:
        sys.exit(f"{args.out}: its rows are of --models {data.get('models', 'own')}; expected --models {args.models} "
                 "(choose another --out)")
    done = {r["case"] for r in data["rows"]}
    todo = [(CASES.index(c), c) for c in args.cases if c not in done]
    print(f"{len(todo)} cases to run ({len(done)} done)", flush=True)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # end the workers too (the pool's terminate below)
    pool = get_context("spawn").Pool(max(1, args.jobs), maxtasksperchild=1)
    try:
        for case, row, error in pool.imap_unordered(_attempt, [(i, c, args.recordings, sim_settings, fit_settings,
                                                                 args.models) for i, c in todo]):
            if row is None:
                print(f"{case}: failed: {error}", flush=True)
                continue
            data["rows"].append(row)
            data["finished"] = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
            if args.out:
                args.out.parent.mkdir(parents=True, exist_ok=True)
                tmp = args.out.with_suffix(".tmp")
                tmp.write_text(json.dumps(data, indent=1, default=float))
                tmp.replace(args.out)
            if "selection" in row:
                c = row["selection"]
                print(f"{row['case']}: {c['selected']} selected, η {c['eta']:.4g} against {c['eta_true']:.4g} "
                      f"({100 * c['error']:+.1f} %)", flush=True)
            else:
                c = row["corrected"]
                print(f"{row['case']}: η {c['eta']:.4g} against {c['eta_true']:.4g} ({100 * c['error']:+.1f} %), "
                      f"slice-only {100 * row['slice_only']['error']:+.1f} %", flush=True)
    finally:
        pool.terminate()
        pool.join()
    print(tables(data["rows"]))


if __name__ == "__main__":
    main()
