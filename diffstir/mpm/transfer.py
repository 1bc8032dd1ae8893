"""The particle-grid transfers of MLS-MPM with quadratic B-splines: scatter to the nodes, gather to the particles.

With w_pk the weight of particle p's stencil node k, o_k ∈ {0, 1, 2}^d that node's offset and s_k = [o_k, 1]:

    scatter:  G[i, c]    = Σ_{p,k: node(p,k) = i} w_pk P[c, p, :] · s_k     (p2g: momentum, mass)
    gather:   P[c, p, :] = Σ_k w_pk G[node(p,k), c] s_k                    (g2p: velocity and its first moment)

P is component-major, (C, N, d + 1); G is (num_nodes, C). The two are adjoint, and both depend on the particles'
positions through the weights, which are differentiated too.

Two implementations give the same numbers. ``fused=False``: torch tensor ops, on any device (under
``torch.compile`` inductor fuses them with their neighbours). ``fused=True``: C++ loops for the CPU
(``csrc/transfer.cpp``, compiled on first use with ``torch.utils.cpp_extension`` and cached per machine) that
compute each particle's weights once and touch each of its nodes once, with their own derivatives in reverse and
forward mode, registered as torch operators so that ``torch.compile`` calls them from its graph; the torch ops
build (C, N, 3^d) intermediates and scatter them instead.

The build directory is keyed by everything that changes the build (``build_key``: torch's version, the compiler's
path and ``--version``, the flags, the source's SHA-256, Python's extension ABI), so that environments of the same
key share one build and environments of different keys never rebuild each other's. Processes that start together
build the kernels once: the first holds a lock file that names its pid, host and start time while it compiles, the
others wait for it; a lock whose owner has died on this host is taken over at once with a one-line notice
(``build_lock``).
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import json
import logging
import os
import shutil
import socket
import subprocess
import sys
import sysconfig
import time
from contextlib import contextmanager
from pathlib import Path

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from .grid import Stencil

log = logging.getLogger(__name__)
SOURCE = Path(__file__).parent / "csrc" / "transfer.cpp"
NAME = "diffstir_transfer"
FLAGS = ("-O3",)
#: Age [s] past which a lock of another host, whose owner cannot be asked, counts as left by a dead builder: a
#: build takes about 50 s.
STALE_LOCK_SECONDS = 600.0


@functools.cache
def _build():
    """The compiled kernels' module and None, or None and the error that stopped the build (tried once)."""
    try:
        directory = build_directory()
        directory.mkdir(parents=True, exist_ok=True)
        built = directory / "built.json"
        if not built.exists():
            with build_lock(directory):
                if not built.exists():
                    log.info("compiling the fused transfer kernels (%s) into %s: about 50 s, once per build key",
                             SOURCE, directory)
                    (directory / "lock").unlink(missing_ok=True)  # torch's own lock, left by a killed builder
                    from torch.utils.cpp_extension import load
                    load(name=NAME, sources=[str(SOURCE)], extra_cflags=list(FLAGS), build_directory=str(directory))
                    built.write_text(json.dumps(build_key(), indent=1) + "\n")
        return _import(directory / f"{NAME}.so"), None
    except Exception as error:  # compiler, ninja or header missing: a build problem, not a simulation one
        return None, error


def _import(library: Path):
    """The built extension module ``library``, imported without asking ninja whether it is up to date (its build
    directory's key says so)."""
    if NAME in sys.modules:
        return sys.modules[NAME]
    spec = importlib.util.spec_from_file_location(NAME, library)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    sys.modules[NAME] = module
    return module


@functools.cache
def build_key() -> dict:
    """Everything that changes the compiled kernels: torch's version, the C++ compiler (``$CXX``, else ``c++``: its
    path and ``--version``), the flags, the source's SHA-256 and Python's extension ABI (``EXT_SUFFIX``)."""
    compiler = shutil.which(os.environ.get("CXX", "c++")) or os.environ.get("CXX", "c++")
    try:
        version = subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        version = ""
    return {"torch": torch.__version__, "compiler": compiler, "compiler_version": version.strip(),
            "flags": list(FLAGS), "source_sha256": hashlib.sha256(SOURCE.read_bytes()).hexdigest(),
            "abi": sysconfig.get_config_var("EXT_SUFFIX")}


def build_directory() -> Path:
    """Where the kernels are compiled and cached: ``$TORCH_EXTENSIONS_DIR`` (default ``~/.cache/torch_extensions``)
    / ``diffstir_transfer-<first 16 hex digits of the SHA-256 of build_key()>``."""
    root = os.environ.get("TORCH_EXTENSIONS_DIR") or Path.home() / ".cache" / "torch_extensions"
    digest = hashlib.sha256(json.dumps(build_key(), sort_keys=True).encode()).hexdigest()
    return Path(root) / f"{NAME}-{digest[:16]}"


def _process_start(pid: int) -> int | None:
    """The start time of process ``pid`` in clock ticks since boot (/proc/<pid>/stat), None where unknown."""
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19])
    except (OSError, IndexError, ValueError):
        return None


def _owner_alive(owner: dict) -> bool:
    """Whether the process that wrote a lock's ``owner`` record, on this host, still runs (the same pid started
    at the same time)."""
    if int(owner.get("pid", 0)) <= 0:
        return False
    try:
        os.kill(int(owner["pid"]), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    start = owner.get("process_start")
    return start is None or _process_start(int(owner["pid"])) in (None, start)


@contextmanager
def build_lock(directory: Path, stale_after: float = STALE_LOCK_SECONDS, poll: float = 0.5):
    """Hold ``directory``/build.lock: a file created exclusively that records this process's pid, host, process
    start and the time [s since the epoch]. While another live process holds it, wait, polling every ``poll`` s,
    with one notice naming it; a lock whose owner has died on this host (or, of another host, older than
    ``stale_after`` [s]) is taken over at once with a one-line notice."""
    lock = directory / "build.lock"
    record = json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "started": time.time(),
                         "process_start": _process_start(os.getpid())})
    told = False
    while True:
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            owner = _read_owner(lock)
            if owner is None:
                continue
            dead = (not _owner_alive(owner) if owner.get("host") == socket.gethostname()
                    else time.time() - owner.get("started", 0.0) > stale_after)
            if dead:
                log.warning("taking over the fused kernels' build lock %s of pid %s on %s, which is gone", lock,
                            owner.get("pid"), owner.get("host"))
                lock.unlink(missing_ok=True)
            else:
                if not told:
                    log.warning("waiting for pid %s on %s, which has been building the fused kernels for %.0f s "
                                "(%s)", owner.get("pid"), owner.get("host"), time.time() - owner.get("started", 0.0),
                                lock)
                    told = True
                time.sleep(poll)
            continue
        with os.fdopen(fd, "w") as file:
            file.write(record)
        break
    try:
        yield
    finally:
        lock.unlink(missing_ok=True)


def _read_owner(lock: Path, settle: float = 5.0) -> dict | None:
    """A lock's owner record; None where the lock is gone. A lock that stays empty or unreadable for ``settle`` s
    (its owner died between creating and writing it) reads as a dead owner's."""
    waited = 0.0
    while True:
        try:
            return json.loads(lock.read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError):
            if waited >= settle:
                return {"pid": 0, "host": socket.gethostname(), "started": 0.0}
            time.sleep(0.1)
            waited += 0.1


def kernels():
    """The compiled C++ kernels, built on first use (about 50 s, then cached in ``build_directory()``).

    Raises RuntimeError, naming what failed, where they cannot be built (no C++ compiler or ninja)."""
    module, error = _build()
    if module is None:
        raise RuntimeError(f"the fused transfer kernels ({SOURCE}) could not be built: {error}; "
                           "set sim.kernels=torch to run without them") from error
    return module


def use_fused(kernels_setting: str, device: torch.device) -> bool:
    """Whether a scene on ``device`` runs the fused kernels under ``sim.kernels`` = ``kernels_setting``
    (``SimConfig.kernels``); builds them where they are to be used.

    Raises RuntimeError where ``"fused"`` was asked for and they cannot be built; ``"auto"`` then warns and takes
    the torch ops."""
    if kernels_setting == "fused":
        kernels()
        return True
    if kernels_setting == "torch" or device.type != "cpu":
        return False
    module, error = _build()
    if module is None:
        log.warning("the fused transfer kernels could not be built (%s); the transfers run as torch ops", error)
        return False
    return True


def scatter(particles: Tensor, st: Stencil, num_nodes: int, points: Tensor, fused: bool) -> Tensor:
    """G (num_nodes, C) from particle rows P (C, N, d + 1) through the stencil ``st``; ``points`` the stencil's
    s_k = [o_k, 1], (3^d, d + 1) (``Scene.stencil_points``)."""
    if fused:
        return _Scatter.apply(particles, st.frac, st.index, num_nodes)
    columns, n, _ = particles.shape
    contrib = (particles.reshape(-1, points.shape[1]) @ points.T).view(columns, n, -1) * st.weights()
    buffer = torch.zeros(columns, num_nodes, dtype=particles.dtype, device=particles.device)
    index = st.index.view(1, -1).expand(columns, -1)
    return buffer.scatter_add(1, index, contrib.view(columns, -1)).T.contiguous()


def gather(grid: Tensor, st: Stencil, points: Tensor, fused: bool) -> Tensor:
    """P (C, N, d + 1) from node values G (num_nodes, C) through the stencil ``st``; ``points`` as in
    ``scatter``."""
    if fused:
        return _Gather.apply(grid, st.frac, st.index)
    n, k = st.index.shape
    columns = grid.shape[1]
    at_nodes = grid.T.contiguous().index_select(1, st.index.view(-1)).view(columns, n, k)
    return ((at_nodes * st.weights()).view(columns * n, k) @ points).view(columns, n, -1)


# The kernels as torch operators, so that torch.compile calls them from its graph instead of breaking it. With
# ``dfrac`` scatter and gather give their tangent in the positions (forward mode).
@torch.library.custom_op("diffstir::transfer_scatter", mutates_args=())
def _scatter_op(particles: Tensor, frac: Tensor, index: Tensor, num_nodes: int,
                dfrac: Tensor | None = None) -> Tensor:
    return kernels().scatter(particles, frac, index, num_nodes, dfrac)


@_scatter_op.register_fake
def _(particles, frac, index, num_nodes, dfrac=None):
    return particles.new_empty(num_nodes, particles.shape[0])


@torch.library.custom_op("diffstir::transfer_gather", mutates_args=())
def _gather_op(grid: Tensor, frac: Tensor, index: Tensor, dfrac: Tensor | None = None) -> Tensor:
    return kernels().gather(grid, frac, index, dfrac)


@_gather_op.register_fake
def _(grid, frac, index, dfrac=None):
    return grid.new_empty(grid.shape[1], frac.shape[0], frac.shape[1] + 1)


@torch.library.custom_op("diffstir::transfer_frac_grad", mutates_args=())
def _frac_grad_op(grid: Tensor, particles: Tensor, frac: Tensor, index: Tensor) -> Tensor:
    return kernels().frac_grad(grid, particles, frac, index)


@_frac_grad_op.register_fake
def _(grid, particles, frac, index):
    return frac.new_empty(frac.shape)


class _Scatter(torch.autograd.Function):
    @staticmethod
    def forward(particles, frac, index, num_nodes):
        return _scatter_op(particles, frac, index, num_nodes)

    @staticmethod
    def setup_context(ctx, inputs, output):
        particles, frac, index, ctx.num_nodes = inputs
        ctx.save_for_backward(particles, frac, index)
        ctx.save_for_forward(particles, frac, index)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_grid):
        particles, frac, index = ctx.saved_tensors
        grad_grid = grad_grid.contiguous()
        grad_particles = _gather_op(grad_grid, frac, index) if ctx.needs_input_grad[0] else None
        grad_frac = _frac_grad_op(grad_grid, particles, frac, index) if ctx.needs_input_grad[1] else None
        return grad_particles, grad_frac, None, None

    @staticmethod
    def jvp(ctx, d_particles, d_frac, _index, _num_nodes):
        particles, frac, index = ctx.saved_tensors
        tangent = torch.zeros(ctx.num_nodes, particles.shape[0], dtype=particles.dtype)
        if d_particles is not None:
            tangent = tangent + _scatter_op(d_particles.contiguous(), frac, index, ctx.num_nodes)
        if d_frac is not None:
            tangent = tangent + _scatter_op(particles, frac, index, ctx.num_nodes, d_frac.contiguous())
        return tangent


class _Gather(torch.autograd.Function):
    @staticmethod
    def forward(grid, frac, index):
        return _gather_op(grid, frac, index)

    @staticmethod
    def setup_context(ctx, inputs, output):
        grid, frac, index = inputs
        ctx.save_for_backward(grid, frac, index)
        ctx.save_for_forward(grid, frac, index)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_particles):
        grid, frac, index = ctx.saved_tensors
        grad_particles = grad_particles.contiguous()
        grad_grid = _scatter_op(grad_particles, frac, index, grid.shape[0]) if ctx.needs_input_grad[0] else None
        grad_frac = _frac_grad_op(grid, grad_particles, frac, index) if ctx.needs_input_grad[1] else None
        return grad_grid, grad_frac, None

    @staticmethod
    def jvp(ctx, d_grid, d_frac, _index):
        grid, frac, index = ctx.saved_tensors
        tangent = torch.zeros(grid.shape[1], frac.shape[0], frac.shape[1] + 1, dtype=grid.dtype)
        if d_grid is not None:
            tangent = tangent + _gather_op(d_grid.contiguous(), frac, index)
        if d_frac is not None:
            tangent = tangent + _gather_op(grid, frac, index, d_frac.contiguous())
        return tangent
