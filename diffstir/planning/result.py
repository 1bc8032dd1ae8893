"""A plan as the user gets it: the programme to stir, what it is expected to tell, and the single-speed stir beside
it; as JSON, markdown, the programme's YAML (a ``lab/programme`` option), the rod's path as CSV (``diffstir-record
stir.file=``) and a figure of the planned speeds and shear rates."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from ..lab.programme import programme_path, programme_speed
from ..plots import pyplot, save_figure
from ..report_files import Report
from .calibration import Calibration
from .design import Assessment, PlanSettings
from .prior import Prior

#: Where a plan's programme goes in its output folder: a config group of its own for ``--config-dir``.
PROGRAMME = "lab/programme/planned.yaml"
#: Samples per second of the rod's path written for the arm.
PATH_RATE = 100.0


@dataclass
class StirPlan(Report):
    """The planned programme's ``assessment``, the single-speed ``baseline``'s, and what they were computed from."""

    assessment: Assessment
    baseline: Assessment
    calibration: Calibration
    prior: Prior
    settings: PlanSettings
    seconds: float

    stem = "plan"

    def summary(self) -> dict:
        return {"plan": self.assessment.to_dict(), "single_speed": self.baseline.to_dict(),
                "calibration": self.calibration.to_dict(),
                "prior": {k: list(v) if isinstance(v, tuple) else v for k, v in self.prior.__dict__.items()},
                "analysis": "diffstir-fit experiment=flow_curve recordings=[<the planned recording>]",
                "seconds": self.seconds}

    def report(self) -> str:
        plan, base = self.assessment, self.baseline
        p = plan.programme
        lines = [f"# Stirring plan ({self.settings.budget:g} s on a {1000 * p.radius:g} mm circle)", "",
                 f"- Speeds: {', '.join(f'{u:g}' for u in p.speeds)} m/s, {p.duration:.3g} s each, ramps of "
                 f"{p.ramp_time:.3g} s; effective shear rates {', '.join(f'{g:.3g}' for g in plan.shear_rates)} 1/s "
                 f"(k_s = {self.calibration.shear_rate_factor:.3g}).",
                 f"- Expected information gain: {plan.gain:.3g} nats per parameter, against {base.gain:.3g} for "
                 f"{base.programme.speeds[0]:g} m/s alone; expected evidence between the laws: "
                 f"{plan.discrimination:.2f} nats per pair, against {base.discrimination:.2f} (the criterion, their "
                 f"sum: {plan.score:.3g} against {base.score:.3g}).",
                 f"- Analyse the recording with `{self.summary()['analysis']}`.", "",
                 "| law | gain, plan | gain, one speed | predicted 95 % CI at the prior's centre (plan) |",
                 "|---|---|---|---|"]
        for name in self.prior.laws:
            cis = "; ".join(f"{k} {_interval(v)}" for k, v in plan.intervals[name].items())
            lines.append(f"| {name} | {plan.law_gains[name]:.3g} | {base.law_gains[name]:.3g} | {cis} |")
        lines += ["", "Expected ΔBIC of the rival law (columns) when the fluid follows the row's law; above 10 the "
                  "rival is ruled out very strongly (one speed in brackets):", "",
                  "| true \\ rival | " + " | ".join(self.prior.laws) + " |",
                  "|---|" + "---|" * len(self.prior.laws)]
        for a in self.prior.laws:
            cells = ["-" if a == b else f"{plan.evidence[a][b]:.1f} ({base.evidence[a][b]:.1f})"
                     for b in self.prior.laws]
            lines.append(f"| {a} | " + " | ".join(cells) + " |")
        return "\n".join(lines) + "\n"

    def plots(self, out: Path) -> dict[str, Path]:
        plt = pyplot()
        fig, (top, bottom) = plt.subplots(2, 1, figsize=(6.5, 5), sharex=True)
        t = np.linspace(0.0, self.settings.budget, 800)
        for assessment, label in ((self.assessment, "plan"), (self.baseline, "one speed")):
            p = assessment.programme
            speed = programme_speed(t, p.segments(), p.ramp_time)
            top.plot(t, speed, label=label)
            bottom.plot(t, self.calibration.shear_rate_factor * np.abs(speed) / self.calibration.rod_radius,
                        label=label)
        top.set_ylabel("speed [m/s]")
        bottom.set_ylabel("γ̇_eff [1/s]")
        bottom.set_yscale("log")
        slowest = min(min(self.assessment.shear_rates), min(self.baseline.shear_rates))
        bottom.set_ylim(bottom=slowest / 3)  # the ramps from rest would stretch the axis down to zero
        bottom.set_xlabel("t [s]")
        top.legend()
        fig.tight_layout()
        return {"png": save_figure(fig, Path(out) / "plan.png")}

    def write(self, out: str | Path) -> dict[str, Path]:
        """``plan.json``, ``plan.md``, ``plan.png``, ``lab/programme/planned.yaml`` (``diffstir-synth --config-dir
        OUT lab/programme=planned``) and ``stir_path.csv`` in ``out``."""
        return {**super().write(out), **write_programme(self.assessment.programme.to_dict(), out)}


def write_programme(programme: dict, out: str | Path) -> dict[str, Path]:
    """``programme`` (radius [m], ramp_time [s], segments of speed [m/s] and duration [s]) in ``out`` as
    ``PROGRAMME`` (a ``lab/programme`` option) and ``stir_path.csv``, the rod's path (t [s], x, y [m]) at
    ``PATH_RATE`` for the arm."""
    paths = {"programme": Path(out) / PROGRAMME, "path": Path(out) / "stir_path.csv"}
    paths["programme"].parent.mkdir(parents=True, exist_ok=True)
    paths["programme"].write_text("# diffstir-synth lab/programme: the planned stir (diffstir-plan)\n"
                                  + yaml.safe_dump(programme, sort_keys=False))
    path = programme_path(programme, PATH_RATE)
    np.savetxt(paths["path"], np.column_stack([path.t, path.xy]), delimiter=",", header="t,x,y", comments="",
               fmt="%.6f")
    return paths


def _interval(entry: dict) -> str:
    lo, hi = entry["ci95"]
    if lo is None and hi is None:
        return "[not identified]"
    ends = ["-" if v is None else f"{v:.3g}" for v in (lo, hi)]
    return f"[{ends[0]}, {ends[1]}]" + ("" if entry["identifiable"] else " (not identifiable)")
