"""Diagnose a fit: locate the mismatch, fit every candidate extension, name the missing physics, and show the fit
improve.

    diag = diagnose(recording, identification, config=COARSE_STAGE, settings=DiagnosisSettings(window=3.0))
    diag.verdict, diag.sentence
    diag.write("out/")            # diagnosis.json, diagnosis.md, plots

``identification`` is an :class:`~diffstir.fitting.Identification` or a ``diffstir-fit`` report.json; the
selected law is the base. The whole recording is compared (or its first ``settings.window`` seconds), all samples
fitted:
the stops and reversals that tell look-alike effects apart must be inside.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..fitting import Identification, StirProblem, Windows, characteristic_shear_rate
from ..mpm import SimConfig
from ..recording import Recording
from ..report_files import Report
from .base import BaseFit, base_from_identification, law_from_report, noise_level, simulate_base
from .candidates import Context, accel_reading, check_names
from .compare import CandidateFit, fit_candidates, rank, second_budget
from .locate import locate
from .report import markdown, plot_all
from .settings import DiagnosisSettings

#: Confidence words for the separation ΔBIC between the verdict and the runner-up (Kass and Raftery 1995).
SURE = ((10.0, "very sure"), (6.0, "fairly sure"))


@dataclass
class Diagnosis(Report):
    """What :func:`diagnose` found: ``summary()`` (diagnosis.json, SI units), ``report()`` (diagnosis.md),
    ``plots(out)`` (residual.png, before_after.png, candidates.png), ``write(out)`` all of them."""

    stem = "diagnosis"

    recording: Recording
    problem: StirProblem
    base: BaseFit
    location: dict
    fits: dict[str, CandidateFit]
    ranking: list[dict]
    verdict: str
    evidence: dict
    seconds: float

    @property
    def refit(self) -> CandidateFit:
        """The model shown as the improved fit: the verdict's, the best candidate when ambiguous, else none."""
        if self.verdict == "ambiguous":
            return self.fits[self.evidence["best"]]
        return self.fits[self.verdict]

    @property
    def sentence(self) -> str:
        """What was left out, how strong it is and how sure the diagnosis is, in one sentence."""
        ev, none = self.evidence, self.fits["none"]
        if self.verdict == "none":
            test = ev["residual_test"]
            if not test["needed"]:
                return (f"Nothing was left out that matters: the residual passes for the noise (RSS/(N σ²) = "
                        f"{test['excess']:.2f}, limit {test['excess_limit']:.2f}; lag-1 autocorrelation "
                        f"{test['autocorrelation']:.2f}, limit {test['autocorrelation_limit']:.2f}).")
            return (f"Something is left out that no candidate explains: the residual is "
                    f"{self.location['rms_over_noise']:.2g} times the noise, but the best extension ({ev['best']}) "
                    f"improves the BIC by {ev['gain_over_none']:.1f} and removes {ev['explained']:.0%} of the "
                    f"mismatch (an effect is named above {ev['thresholds']['evidence']:g} and "
                    f"{ev['thresholds']['explained']:.0%}).")
        if self.verdict == "ambiguous":
            tied = " and ".join(ev["tied"])
            cut = ev["unconverged_contenders"]
            gap = max(cut.values()) if cut else 0.0
            promise = (f"to come within ΔBIC {gap:.1f} of the best" if gap >= 0 else
                       f"to beat the best by ΔBIC {-gap:.1f}")
            why = (f"ΔBIC {ev['separation']:.1f} < {ev['thresholds']['distinct']:g}" if not cut else
                   f"the fit of {' and '.join(cut)} stopped on its budget of simulations, and its next step "
                   f"promises {promise}")
            return (f"Something was left out (ΔBIC {ev['gain_over_none']:.0f} against no extension), but {tied} "
                    f"explain it about equally well ({why}): this recording cannot tell them apart; a programme "
                    "with stops and reversals may, or a larger max_iterations.")
        fit = self.fits[self.verdict]
        strength = float(np.sqrt(np.mean((fit.predicted - none.predicted) ** 2)) /
                         np.sqrt(np.mean(self.problem.measured ** 2)))
        sure = next((w for limit, w in SURE if ev["separation"] >= limit), "unsure")
        params = "; ".join(_param(k, v, fit.units[k], fit.ci95[k]) for k, v in fit.params.items()
                           if k != "viscosity_scale")
        caveat = f" Caveat: {fit.warning}." if fit.warning else ""
        return (f"Left out: {fit.summary} ({params}); it changes the reading by {strength:.0%} of its rms and "
                f"modelling it cuts the loss from {none.loss:.3g} N to {fit.loss:.3g} N. The diagnosis is {sure}: "
                f"ΔBIC {ev['gain_over_none']:.0f} against no extension and {ev['separation']:.0f} against the "
                f"runner-up ({ev['runner_up']}).{caveat}")

    def summary(self) -> dict:
        """diagnosis.json: verdict, sentence, ranking, evidence, location, base and refit (SI units)."""
        location = {k: v for k, v in self.location.items() if not k.startswith("_")}
        refit = self.refit
        return {
            "recording": str(self.recording.path) if self.recording.path else self.recording.name,
            "verdict": self.verdict, "sentence": self.sentence, "ranking": self.ranking, "evidence": self.evidence,
            "location": location,
            "base": {"law": self.base.law.name, "params": self.base.params, "units": dict(self.base.law.units),
                     "density": self.base.density, "source": self.base.source,
                     "loss": float(np.mean(np.abs(self.problem.measured - self.base.predicted)))},
            "refit": {"effect": refit.name, "loss_before": self.fits["none"].loss, "loss_after": refit.loss,
                      "fluid_before": {"name": self.base.law.name, "params": self.base.params},
                      "fluid_after": refit.law},
            "window": {"start": self.problem.windows.start, "end": self.problem.windows.end, "unit": "s"},
            "dead_start": self.problem.windows.dead_start.summary(),
            "simulation": {"dim": self.problem.config.dim, "dx": self.problem.config.dx,
                           "sound_speed": self.problem.config.sound_speed},
            "simulations": self.base.simulations + sum(f.simulations for f in self.fits.values()),
            "seconds": self.seconds,
        }

    def report(self) -> str:
        """diagnosis.md: the verdict, where the mismatch is, every candidate's score and the refit."""
        return markdown(self.summary())

    def plots(self, out: Path) -> dict[str, Path]:
        """residual.png, before_after.png and candidates.png in ``out``."""
        return plot_all(self, out)


def _param(name: str, value: float, unit: str, ci) -> str:
    unit = "" if unit == "1" else f" {unit}"
    if ci is None:
        return f"{name} = {value:.3g}{unit}, not identifiable"
    if ci[0] is not None and ci[1] is not None:
        return f"{name} = {value:.3g}{unit}, 95 % CI {ci[0]:.3g} to {ci[1]:.3g}"
    return f"{name} = {value:.3g}{unit}"


def diagnose(recording: Recording, identification: Identification | str | Path, *, config: SimConfig,
             settings: DiagnosisSettings | None = None, progress: bool = False, workers: int = 1) -> Diagnosis:
    """Locate the mismatch between ``recording`` and its identification, fit every candidate extension, and name
    the missing physics (see the module docstring and ``compare``).

    Args:
        recording: the recording.
        identification: an ``Identification`` or the path of a ``diffstir-fit`` report.json (or its directory).
        config: the simulator's resolution for the physics candidates (the coarse 2-D slice is the cheap choice).
        settings: the window, candidates, iterations and thixotropy's starting rebuild time (``DiagnosisSettings``;
            None: its defaults, those of ``diffstir-diagnose``). Candidates whose fit was cut short by
            ``settings.max_iterations`` but might still come within reach of the best (``compare``) get as many
            again, and so does the best when its own fit was cut short.
        progress: print one line per fitted candidate.
        workers: processes that fit the physics candidates side by side (``compare.fit_candidates``; 1: in this
            process). The result does not depend on it.
    """
    started = time.perf_counter()
    settings = DiagnosisSettings() if settings is None else settings
    names = check_names(settings.candidates)
    if isinstance(identification, Identification):
        density = identification.density["value"]
    else:
        law, density, source = law_from_report(identification)
    windows = Windows.of(recording, settings.window, 0.0)
    windows.dead_start.require_signal()
    problem = StirProblem(recording, config, density, windows)
    if isinstance(identification, Identification):
        base = base_from_identification(identification, problem)
    else:
        base = simulate_base(problem, law, density, source)
    noise = noise_level(problem.measured, recording.sensor.resolution)
    ctx = Context(times=problem.times, measured=problem.measured, base_reading=base.predicted,
                  scale_column=base.scale_column,
                  accel_reading=accel_reading(problem.times, problem.velocity, recording.sensor), noise=noise,
                  shear_rate=characteristic_shear_rate(problem), duration=problem.trajectory.duration,
                  rebuild_time=float(settings.rebuild_time), law=base.law,
                  rod_radius=problem.rig.rod.radius)
    xy = np.stack([recording.x[problem.index], recording.y[problem.index]], axis=-1)
    location = locate(problem.times, xy, problem.velocity, problem.measured, base.predicted, noise,
                      problem.rig.rod.radius)

    def report(fit: CandidateFit) -> None:
        if progress:
            state = fit.note or f"loss {fit.loss:.4g} N, {fit.simulations} simulations, {fit.seconds:.0f} s"
            print(f"diagnose {fit.name}: {state}", flush=True)

    fits = fit_candidates(names, ctx, problem, max_iterations=settings.max_iterations, on_fit=report,
                          workers=workers)
    ranking, verdict, evidence = rank(fits, problem.measured, noise)
    again = second_budget(fits, verdict, evidence)
    if again:
        fits.update(fit_candidates(again, ctx, problem, max_iterations=settings.max_iterations, on_fit=report,
                                   workers=workers, resume=fits))
        ranking, verdict, evidence = rank(fits, problem.measured, noise)
    return Diagnosis(recording=recording, problem=problem, base=base, location=location, fits=fits,
                     ranking=ranking, verdict=verdict, evidence=evidence, seconds=time.perf_counter() - started)
