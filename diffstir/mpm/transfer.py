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

Processes that start together build the kernels once: the first holds a lock file in the build directory while it
compiles, the others wait. torch's own wait has no timeout, so a builder killed mid-build would leave every later
process waiting forever; a lock older than ``STALE_LOCK_SECONDS`` is removed with a warning instead
(``wait_for_build_lock``).
"""

from __future__ import annotations

import functools
import logging
import os
import time
from pathlib import Path

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from .grid import Stencil

log = logging.getLogger(__name__)
SOURCE = Path(__file__).parent / "csrc" / "transfer.cpp"
#: Age [s] past which the build lock was left by a process that died while building: a build takes about 50 s.
STALE_LOCK_SECONDS = 600.0


@functools.cache
def _build():
    """The compiled kernels' module and None, or None and the error that stopped the build (tried once)."""
    from torch.utils.cpp_extension import load
    log.info("loading the fused transfer kernels (%s; compiled on a machine's first use, about 50 s)", SOURCE)
    try:
        directory = build_directory()
        directory.mkdir(parents=True, exist_ok=True)
        wait_for_build_lock(directory)
        return load(name="diffstir_transfer", sources=[str(SOURCE)], extra_cflags=["-O3"],
                    build_directory=str(directory)), None
    except Exception as error:  # compiler, ninja or header missing: a build problem, not a simulation one
        return None, error


def build_directory() -> Path:
    """Where the kernels are compiled and cached: ``$TORCH_EXTENSIONS_DIR`` (default ``~/.cache/torch_extensions``)
    / ``diffstir_transfer-<torch version>``, rebuilt for each torch."""
    root = os.environ.get("TORCH_EXTENSIONS_DIR") or Path.home() / ".cache" / "torch_extensions"
    return Path(root) / f"diffstir_transfer-{torch.__version__.replace('+', '_')}"


def wait_for_build_lock(directory: Path, stale_after: float = STALE_LOCK_SECONDS, poll: float = 1.0) -> None:
    """Return once ``directory`` holds no build lock (``lock``): while another process builds, wait, polling every
    ``poll`` s; a lock older than ``stale_after`` [s] is a dead builder's and is removed, with a warning."""
    lock = directory / "lock"
    while True:
        try:
            age = time.time() - lock.stat().st_mtime
        except FileNotFoundError:
            return
        if age > stale_after:
            log.warning("removing the fused kernels' build lock %s, left %.0f s ago by a process that did not "
                        "finish its build", lock, age)
            lock.unlink(missing_ok=True)
            return
        time.sleep(min(poll, stale_after - age + 0.01))


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
