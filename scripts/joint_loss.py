"""The loss a law reaches on every speed at once, at parameters you choose, on a fluid of the behaviour benchmark
(docs/accuracy-behaviour.md, Behaviour classification): how well a law *could* fit the joint problem, apart from how
far the joint fit got.

The fluid is stirred by the lab along the benchmark's programme as ``behaviour_benchmark.py`` stirs it (same truth
grid, sensor preset, noise seed and speeds, with the same options); every constant-speed window goes into one
``JointProblem`` on ``--fit-sim``, and each ``--law`` is simulated once, at its own sound speed
(``SimConfig.compressibility``). ``--save`` writes the lab recording, ``--recording`` reads it back instead of
simulating the truth again.

Besides the loss and the rms residual, each law's rms residual after the best amplitude per speed window
(a_w = p_w·m_w / p_w·p_w, the least-squares scale of the simulated readings p_w onto the measured m_w) and those
amplitudes: what is left when the simulator's force error is an amplitude per speed, as the model error σ_m
assumes; where a law's waveform itself is off, the rescaled residual stays above the other laws'.

``--sound-speed-factors`` also simulates each law with its rollout's sound speed held at c·f for each factor f:
a change the readings should not notice, so what they do is the simulation's jitter, window by window. The last
table gives each law's BIC at each sound speed as the joint fit takes it (``fitting.selection.bic``, N_eff of the
best law at its own sound speed), with one variance for all windows and, with ``--window-scales`` s_w [N] (the
benchmark report's ``points[].loss``), with each window's residuals in units of its s_w (``JointProblem``).

    python scripts/joint_loss.py --fluid bingham --fit-sim sim/coarse2d.yaml --truth-sim sim/coarse2d.yaml \\
        --truth-dx 0.004 --law bingham:tau_y=3,eta_p=0.1 power_law:k=2.73,n=0.12
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from behaviour_benchmark import FLUIDS, ROOT, add_lab_arguments, lab_recording
from diffstir.behaviour.joint import JointProblem
from diffstir.density import combined_density
from diffstir.fitting.models import FitModel
from diffstir.fitting.optimise import Readings
from diffstir.fitting.selection import bic
from diffstir.fitting.uncertainty import effective_samples
from diffstir.fitting.windows import speed_windows
from diffstir.recording import load_recording, save_recording


def parse_law(text: str) -> FitModel:
    """``name:k=v,k=v`` → the law ``name`` at those SI parameters."""
    name, _, rest = text.partition(":")
    pairs = [item.split("=") for item in rest.split(",") if item]
    if any(len(pair) != 2 for pair in pairs):
        raise SystemExit(f"--law {text!r}: expected name:param=value,param=value")
    return FitModel.named(name, **{key: float(value) for key, value in pairs})


def per_window_amplitudes(predicted: np.ndarray, measured: np.ndarray,
                          windows: list[np.ndarray]) -> tuple[list[float], np.ndarray]:
    """The least-squares amplitude a_w = p·m / p·p of the simulated readings ``predicted`` [N] onto ``measured`` [N]
    in each window (sample indices ``windows``), and the readings rescaled by them [N]."""
    rescaled, amplitudes = predicted.copy(), []
    for index in windows:
        p = predicted[index]
        amplitudes.append(float(p @ measured[index] / (p @ p)))
        rescaled[index] = amplitudes[-1] * p
    return amplitudes, rescaled


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fluid", default="bingham", choices=list(FLUIDS))
    parser.add_argument("--fit-sim", default="sim/slice2d.yaml", help="fitting grid, a file under conf/")
    add_lab_arguments(parser)
    parser.add_argument("--law", nargs="+", required=True, help="laws to simulate, name:param=value,...")
    parser.add_argument("--recording", default=None, help="read the lab recording from this directory")
    parser.add_argument("--save", default=None, help="write the lab recording to this directory")
    parser.add_argument("--sound-speed-factors", type=float, nargs="+", default=[],
                        help="also simulate each law with its sound speed held at c times each factor")
    parser.add_argument("--window-scales", type=float, nargs="+", default=None,
                        help="each window's residual scale [N], for the weighted BIC")
    args = parser.parse_args()
    torch.set_num_threads(1)
    models = [parse_law(text) for text in args.law]
    fit_config = instantiate(OmegaConf.load(ROOT / "conf" / args.fit_sim))
    if args.recording is not None:
        recording = load_recording(args.recording)
    else:
        t0 = time.perf_counter()
        recording = lab_recording(args.fluid, args).recording
        print(f"lab recording: {time.perf_counter() - t0:.0f} s")
        if args.save is not None:
            save_recording(recording, args.save, overwrite=True)
    windows = speed_windows(recording)
    density = combined_density([recording], None)["value"]
    problem = JointProblem(windows, fit_config, density, args.window_scales)
    times = problem.problems[0].times[problem.masks[0]]
    in_window = [np.flatnonzero((times > w.start) & (times <= w.end)) for w in windows]
    print(f"{args.fluid} ({FLUIDS[args.fluid][1]}), fitted on {args.fit_sim}; {problem.measured.size} samples in "
          f"the windows, mean |reading| {np.mean(np.abs(problem.measured)):.5f} N\n")
    print("| law | parameters (SI) | sound speed [m/s] | loss [N] | rms residual [N] | rms per window [N] | "
          "rms after an amplitude per window [N] | amplitudes | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    residuals = {}
    for k, model in enumerate(models):
        own = problem.problems[0].simulator(model.material).sound_speed(problem.problems[0].trajectory)
        for factor in [None, *args.sound_speed_factors]:
            held = problem if factor is None else JointProblem(
                windows, replace(fit_config, rollout_sound_speed=own * factor), density, args.window_scales)
            t0 = time.perf_counter()
            reading = Readings(held, model)(model.theta())
            rest = reading - problem.measured
            residuals[k, factor] = rest
            amplitudes, rescaled = per_window_amplitudes(reading, problem.measured, in_window)
            params = ", ".join(f"{key} {v:.4g}" for key, v in model.params_si().items())
            speed = f"{own:.4g}" if factor is None else f"{own:.4g} x {factor:g}"
            print(f"| {model.name} | {params} | {speed} | {problem.loss(reading):.5f} | "
                  f"{np.sqrt(np.mean(rest**2)):.5f} | "
                  f"{', '.join(f'{np.sqrt(np.mean(rest[i] ** 2)):.4f}' for i in in_window)} | "
                  f"{np.sqrt(np.mean((rescaled - problem.measured)**2)):.5f} | "
                  f"{', '.join(f'{a:.3f}' for a in amplitudes)} | {time.perf_counter() - t0:.0f} |", flush=True)
    print_bic_table(models, args.sound_speed_factors, residuals, problem.weights, args.window_scales is not None)


def print_bic_table(models: list[FitModel], factors: list[float], residuals: dict, weights: np.ndarray,
                    weighted: bool) -> None:
    """Each law's BIC at its own sound speed and at each factor of it, unweighted and (``weighted``) with the
    residuals times ``weights``, N_eff from the best law at its own sound speed in each."""
    kinds = [("one variance", np.ones_like(weights))] + ([("per window", weights)] if weighted else [])
    print("\n| law | BIC | " + " | ".join(["own c", *(f"c x {f:g}" for f in factors)]) + " | spread |")
    print("|---|---|" + "---|" * (len(factors) + 2))
    for label, w in kinds:
        best = min(range(len(models)), key=lambda k: float(np.sum((w * residuals[k, None]) ** 2)))
        n_effective = effective_samples(w * residuals[best, None])
        for k, model in enumerate(models):
            values = [bic(w * residuals[k, f], model.size, n_effective) for f in [None, *factors]]
            print(f"| {model.name} {k} | {label} (N_eff {n_effective:.0f}) | "
                  + " | ".join(f"{v:.1f}" for v in values) + f" | {max(values) - min(values):.1f} |")


if __name__ == "__main__":
    main()
