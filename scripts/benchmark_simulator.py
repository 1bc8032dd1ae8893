"""Time the simulator: ms per step forward and forward+backward, and gradient memory, next to a reference run.

    python scripts/benchmark_simulator.py [--scenes paper3d slice2d] [--steps 100] [--threads 1]
                                          [--variants eager compiled] [--reference-tree DIR] [--repeats 3]
    python scripts/benchmark_simulator.py --gradient-steps 8000 [--scenes paper3d]
    python scripts/benchmark_simulator.py --profile --scenes paper3d --variants compiled [--steps 50]
    python scripts/benchmark_simulator.py --device cuda --variants eager compiled cpu

Every variant of a scene runs in this one process, interleaved (variant A, B, A, B, ...), and the table gives each
variant's time as a ratio to the first variant (the reference, the eager step by default): on a shared machine the
absolute ms move with the other jobs, the ratios much less. Variants:

- ``eager``: the simulator as configured, ``SimConfig.compile = False`` (on the CPU the transfers run as the fused
  C++ kernels, ``SimConfig.kernels = "auto"``).
- ``unfused``: eager with the transfers as torch ops, ``SimConfig.kernels = "torch"``.
- ``compiled``: ``SimConfig.compile = True`` (compiled once in an untimed warm-up run), the fused transfers called
  from the compiled graph.
- ``compiled-unfused``: compiled with the transfers as torch ops, which inductor fuses with the rest of the step.
- ``projection``: ``SimConfig.pressure = "projection"`` (2-D scenes only), the incompressible pressure; its time
  step is longer (no acoustic limit), so compare the cost per simulated second from the dt column too.
- ``walls``: ``SimConfig.wall_pressure = True``, boundary particles in the solids carrying the fluid's pressure.
- ``cpu``: the eager step on the CPU, the reference a GPU's variants are compared with (``--device cuda``).
- ``reference``: another checkout's simulator (``--reference-tree DIR``, a directory holding a ``diffstir``
  package, e.g. ``git worktree add /tmp/diffstir-ref <commit>``), imported side by side under another name;
  ``reference-projection``: that checkout's ``projection`` variant.

Times are the fastest of ``--repeats`` warm runs (a rollout of ``--steps`` steps; forward without gradients, and
forward plus the backward pass of mean |F| through the checkpointed rollout). Memory: the bytes of tensors that
autograd keeps for one step and for one state (the checkpoint of a segment), measured with saved-tensor hooks, and
from them the memory that a gradient through 8000 steps holds with the configured checkpoint segments:
ceil(8000 / segment) states plus one recomputed segment's graph. ``peak RSS`` is the process's maximum resident
set size (Linux ru_maxrss) over the whole run.

``--gradient-steps N`` measures memory directly instead: for each scene (eager, its configured checkpointing), the
growth of the process's peak resident set size over one N-step gradient of mean |F|, after a 50-step warm-up (on a
GPU, the growth of the device's peak allocated memory).

``--device cuda`` runs every variant but ``cpu`` on the GPU; each timed rollout ends with the device's queue drained
(``torch.cuda.synchronize``).

``--profile`` prints, for each scene and variant, where a warm forward rollout spends its time: ``torch.profiler``'s
operators by self time, and for a compiled variant inductor's generated kernels (``cpp.enable_kernel_profile``).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import importlib
import math
import os
import platform
import re
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

import torch
import torch._inductor.config

SCENES = {  # slice2d, coarse2d and fine3d with the default numerics (FLIP share, packing relaxation; the pressure
    # as configured by the variant), paper3d with the paper's
    "paper3d": dict(dim=3, dx=0.01, sound_speed=4.5, cfl=0.45, dt=1e-3, settle_time=0.3, flip=0.0,
                    volume_relaxation=0.0),
    "fine3d": dict(dim=3, dx=0.005, sound_speed=10.0, settle_time=0.3),
    "slice2d": dict(dim=2, dx=0.0025, sound_speed=1.0),
    "coarse2d": dict(dim=2, dx=0.005, sound_speed=1.0, dt_max=0.002),
}
VARIANTS = ["eager", "unfused", "compiled", "compiled-unfused", "projection", "walls", "cpu", "reference",
            "reference-projection"]
HORIZON = 8000  # steps: the paper's 8 s recording at 1 ms


def import_reference(tree: Path):
    """The ``diffstir`` package of another checkout, importable as ``diffstir_reference`` (its torch operators as
    ``diffstir_reference::``)."""
    target = Path(tempfile.mkdtemp(prefix="diffstir-reference-"))
    shutil.copytree(tree / "diffstir", target / "diffstir_reference")
    for path in (target / "diffstir_reference").rglob("*.py"):
        text = path.read_text()
        path.write_text(re.sub(r"\bdiffstir(?=[.: ])", "diffstir_reference", text))
    sys.path.insert(0, str(target))
    return {name: importlib.import_module(f"diffstir_reference.{name}")
            for name in ("mpm", "rheology", "rig", "trajectory")}


def build(variant: str, scene: str, reference, device: str = "cpu") -> tuple:
    """The simulator and trajectory function of one variant, on ``device`` (the ``cpu`` variant on the CPU)."""
    modules = reference if variant.startswith("reference") else {
        "mpm": importlib.import_module("diffstir.mpm"), "rheology": importlib.import_module("diffstir.rheology"),
        "rig": importlib.import_module("diffstir.rig"), "trajectory": importlib.import_module("diffstir.trajectory")}
    known = {f.name for f in dataclasses.fields(modules["mpm"].SimConfig)}  # an older checkout lacks newer settings
    settings = {k: v for k, v in SCENES[scene].items() if k in known}
    if variant in ("compiled", "compiled-unfused"):
        settings["compile"] = True
    if variant == "compiled-unfused":
        settings["kernels"] = "torch"
    if variant in ("projection", "reference-projection"):
        settings["pressure"] = "projection"
    if variant == "walls":
        settings["wall_pressure"] = True
    if variant == "unfused":
        settings["kernels"] = "torch"
    if "device" in known:
        settings["device"] = "cpu" if variant == "cpu" else device
    law = modules["rheology"].Carreau(eta0=1.0, eta_inf=0.01, lam=0.5, n=0.6)
    sim = modules["mpm"].StirringSimulator(law, modules["rig"].Rig(), modules["mpm"].SimConfig(**settings),
                                           density=1000.0)
    return sim, modules["trajectory"].circle


def rollout(sim, trajectory, initial, grad: bool) -> float:
    """Wall time of one rollout [s], with the backward pass of mean |F| when ``grad``."""
    start = time.perf_counter()
    with torch.set_grad_enabled(grad):
        result = sim(trajectory, initial=initial)
        if grad:
            result.force.abs().mean().backward()
    if result.force.is_cuda:
        torch.cuda.synchronize()
    return time.perf_counter() - start


def saved_bytes(sim, trajectory, initial) -> tuple[float, float]:
    """Bytes autograd saves per step without checkpointing, and the bytes of one state."""
    storages: dict[int, int] = {}

    def pack(t):
        if isinstance(t, torch.Tensor) and t.device.type != "meta":
            storages[t.untyped_storage().data_ptr()] = t.untyped_storage().nbytes()
        return t

    config = sim.config
    sim.config = config.replace(checkpoint_every=0)
    try:
        with torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t):
            result = sim(trajectory, initial=initial)
    finally:
        sim.config = config
    steps = len(result.times)
    state = sum(t.numel() * t.element_size() for t in initial.tensors())
    return sum(storages.values()) / steps, state


def profile(variant: str, scene: str, reference, steps: int, device: str) -> None:
    """Print the operators (and a compiled variant's kernels) of one warm forward rollout of ``steps`` steps by self
    time."""
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    torch._inductor.config.cpp.enable_kernel_profile = True  # compiled kernels appear by name
    sim, circle_fn = build(variant, scene, reference, device)
    dt = sim.time_step(circle_fn(0.015, 0.1, 1.0, ramp_time=0.2))
    trajectory = circle_fn(0.015, 0.1, steps * dt, ramp_time=0.2)
    initial = sim.initial_state(trajectory)
    rollout(sim, trajectory, initial, False)  # warm-up and compilation
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if sim.config.device != "cpu" else [])
    with torch_profile(activities=activities) as prof:
        seconds = rollout(sim, trajectory, initial, False)
    print(f"{scene}, {variant}: {1e3 * seconds / steps:.2f} ms/step under the profiler, {steps} steps")
    print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=12, max_name_column_width=90))


def peak_memory(device: str) -> float:
    """The process's peak resident set size [MiB], or on a GPU the device's peak allocated memory."""
    if device == "cpu":
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return torch.cuda.max_memory_allocated() / 2**20


def gradient_memory(scene: str, steps: int, device: str) -> None:
    """Print the growth of peak memory [MiB] over one ``steps``-step gradient of the ``eager`` variant of
    ``scene``."""
    sim, circle_fn = build("eager", scene, None, device)
    dt = sim.time_step(circle_fn(0.015, 0.1, 1.0, ramp_time=0.2))
    warm, full = (circle_fn(0.015, 0.1, n * dt, ramp_time=0.2) for n in (50, steps))
    initial = sim.initial_state(full)
    rollout(sim, warm, initial, grad=True)
    before = peak_memory(device)
    wall = rollout(sim, full, initial, grad=True)
    after = peak_memory(device)
    print(f"| {scene} | {steps} | {sim.config.checkpoint_every} | {before:.0f} | {after:.0f} | {after - before:.0f} "
          f"| {wall:.0f} |", flush=True)


def machine(device: str) -> str:
    """The CPU, and the GPU where ``device`` names one."""
    cpu = f"{platform.machine()}, {os.cpu_count()} CPUs"
    return cpu if device == "cpu" else f"{cpu}, {torch.cuda.get_device_name(torch.device(device))}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--scenes", nargs="+", default=["paper3d", "slice2d"], choices=list(SCENES))
    parser.add_argument("--variants", nargs="+", default=["eager", "compiled"], choices=VARIANTS)
    parser.add_argument("--reference-tree", type=Path, help="checkout whose diffstir is the 'reference' variant")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--gradient-steps", type=int, help="measure the peak memory of one gradient this long")
    parser.add_argument("--profile", action="store_true", help="print where a forward rollout spends its time")
    parser.add_argument("--device", default="cpu", help="torch device of every variant but 'cpu', e.g. cuda")
    args = parser.parse_args()
    if any(v.startswith("reference") for v in args.variants) and args.reference_tree is None:
        parser.error("the 'reference' variants need --reference-tree DIR")
    reference = import_reference(args.reference_tree) if args.reference_tree else None
    torch.set_num_threads(args.threads)
    if args.profile:
        for scene in args.scenes:
            for variant in args.variants:
                profile(variant, scene, reference, args.steps, args.device)
        return
    if args.gradient_steps:
        print(f"{datetime.date.today()}, torch {torch.__version__}, {args.threads} thread(s), float32, eager, "
              f"{machine(args.device)}")
        peak = "peak RSS" if args.device == "cpu" else "peak GPU memory"
        print(f"| scene | steps | checkpoint segment | {peak} before [MiB] | after [MiB] | growth [MiB] | wall [s] |")
        print("|---|---|---|---|---|---|---|")
        for scene in args.scenes:
            gradient_memory(scene, args.gradient_steps, args.device)
        return
    load = os.getloadavg()[0]
    print(f"{datetime.date.today()}, {machine(args.device)}, load average {load:.1f} at start, "
          f"torch {torch.__version__}, {args.threads} thread(s), float32, {args.steps} steps per rollout, "
          f"fastest of {args.repeats}")
    print("| scene | particles | grid | dt [ms] | variant | forward [ms/step] | fwd+bwd [ms/step] "
          "| forward ratio | fwd+bwd ratio |")
    print("|---|---|---|---|---|---|---|---|---|")
    memory = []
    for scene in args.scenes:
        runs = {}
        for variant in args.variants:
            sim, circle_fn = build(variant, scene, reference, args.device)
            dt = sim.time_step(circle_fn(0.015, 0.1, 1.0, ramp_time=0.2))
            trajectory = circle_fn(0.015, 0.1, args.steps * dt, ramp_time=0.2)
            initial = sim.initial_state(trajectory)
            for grad in (False, True):  # warm-up (and compilation) outside the timing
                rollout(sim, trajectory, initial, grad)
            runs[variant] = (sim, trajectory, initial, {False: math.inf, True: math.inf})
        for _ in range(args.repeats):
            for grad in (False, True):
                for variant, (sim, trajectory, initial, best) in runs.items():
                    best[grad] = min(best[grad], rollout(sim, trajectory, initial, grad))
        first = next(iter(runs.values()))[3]
        for variant, (sim, trajectory, initial, best) in runs.items():
            steps = round(trajectory.duration / sim.time_step(trajectory))
            fwd, both = (1e3 * best[g] / steps for g in (False, True))
            print(f"| {scene} | {initial.num_particles} | {'x'.join(map(str, sim.scene.grid.shape))} | "
                  f"{1e3 * trajectory.duration / steps:.3f} | {variant} | {fwd:.2f} | {both:.2f} | "
                  f"{first[False] / best[False]:.2f} | {first[True] / best[True]:.2f} |", flush=True)
        for variant, (sim, trajectory, initial, _) in runs.items():
            per_step, state = saved_bytes(sim, trajectory, initial)
            segment = sim.config.checkpoint_every or HORIZON
            estimate = math.ceil(HORIZON / segment) * state + min(segment, HORIZON) * per_step
            memory.append((scene, variant, per_step, state, segment, estimate))
    print()
    print("| scene | variant | saved per step [MB] | state [MB] | checkpoint segment [steps] "
          "| 8000-step gradient [GB] |")
    print("|---|---|---|---|---|---|")
    for scene, variant, per_step, state, segment, estimate in memory:
        print(f"| {scene} | {variant} | {per_step / 1e6:.2f} | {state / 1e6:.3f} | {segment} | {estimate / 1e9:.2f} |")
    print(f"peak RSS of this process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")


if __name__ == "__main__":
    main()
