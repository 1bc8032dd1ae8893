"""The particle-grid transfers: the fused C++ kernels against the torch ops, their derivatives and their adjointness."""

from __future__ import annotations

import pytest
import torch

from diffstir.mpm import SimConfig, StirringSimulator
from diffstir.mpm.grid import Grid, flat_index, quadratic_stencil
from diffstir.mpm.transfer import gather, scatter, use_fused
from diffstir.rheology import Carreau
from diffstir.rig import Rig
from diffstir.trajectory import circle

needs_kernels = pytest.mark.skipif(not use_fused("auto", torch.device("cpu")),
                                   reason="the fused kernels do not build here (no C++ compiler or ninja)")


def _setup(d: int, count: int = 20, seed: int = 0):
    """A float64 grid of 8^d nodes with ``count`` particles inside, away from its edges."""
    generator = torch.Generator().manual_seed(seed)
    grid = Grid(origin=torch.full((d,), -0.1, dtype=torch.float64), shape=(8,) * d, dx=0.05)
    offsets = grid.stencil_offsets()
    points = torch.cat([offsets, torch.ones(len(offsets), 1, dtype=torch.int64)], 1).double()
    x = -0.1 + 0.05 * (1.6 + 4.8 * torch.rand(count, d, generator=generator, dtype=torch.float64))
    return grid, flat_index(offsets, grid.strides()), points, x.requires_grad_(True)


def _stencil(grid, offset_index, x, fused):
    return quadratic_stencil(grid, x, offset_index, grid.strides(), weights=not fused)


@needs_kernels
@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("columns", [1, 3, 4, 7])
def test_fused_transfers_equal_the_torch_ops_with_their_derivatives(d, columns):
    """Scatter and gather give the torch ops' values to float64 rounding, and their derivatives with respect to the
    values and the particles' positions (through the B-spline weights) match central differences (gradcheck)."""
    grid, offset_index, points, x = _setup(d)
    values = torch.randn(columns, x.shape[0], d + 1, dtype=torch.float64, requires_grad=True)
    nodal = torch.randn(grid.num_nodes, columns, dtype=torch.float64, requires_grad=True)

    def to_grid(values, x, fused=True):
        return scatter(values, _stencil(grid, offset_index, x, fused), grid.num_nodes, points, fused)

    def to_particles(nodal, x, fused=True):
        return gather(nodal, _stencil(grid, offset_index, x, fused), points, fused)

    torch.testing.assert_close(to_grid(values, x), to_grid(values, x, fused=False), rtol=1e-12, atol=1e-14)
    torch.testing.assert_close(to_particles(nodal, x), to_particles(nodal, x, fused=False), rtol=1e-12, atol=1e-14)
    assert torch.autograd.gradcheck(to_grid, (values, x))
    assert torch.autograd.gradcheck(to_particles, (nodal, x))


@needs_kernels
@pytest.mark.parametrize("d", [2, 3])
def test_scatter_and_gather_are_adjoint(d):
    """<scatter(P), G> = <P, gather(G)>: p2g and g2p move momentum and velocity through the same weights."""
    grid, offset_index, points, x = _setup(d, count=50, seed=1)
    st = _stencil(grid, offset_index, x.detach(), fused=True)
    values = torch.randn(d, 50, d + 1, dtype=torch.float64)
    nodal = torch.randn(grid.num_nodes, d, dtype=torch.float64)
    left = (scatter(values, st, grid.num_nodes, points, True) * nodal).sum()
    right = (values * gather(nodal, st, points, True)).sum()
    assert float(left) == pytest.approx(float(right), rel=1e-12)


@needs_kernels
def test_a_stencil_off_the_grid_is_an_error_not_a_stray_write():
    grid, offset_index, points, x = _setup(2)
    st = _stencil(grid, offset_index, x.detach(), fused=True)
    st.index = st.index + grid.num_nodes  # every stencil past the last node
    with pytest.raises(RuntimeError, match="off the grid"):
        scatter(torch.zeros(1, x.shape[0], 3, dtype=torch.float64), st, grid.num_nodes, points, True)


@needs_kernels
@pytest.mark.parametrize("wall_pressure", [False, True])
def test_simulator_forces_and_gradients_do_not_depend_on_the_kernels(wall_pressure):
    """A 2-D stir with FLIP and volume relaxation on, with and without boundary particles: forces and the gradient
    of a loss with respect to every law parameter agree between ``sim.kernels=fused`` and ``torch`` to float64
    rounding amplified over the rollout."""
    trajectory = circle(radius=0.015, speed=0.05, duration=0.02, ramp_time=0.01)
    runs = []
    for kernels in ("fused", "torch"):
        law = Carreau(eta0=1.0, eta_inf=0.05, lam=0.3, n=0.5, dtype=torch.float64)
        config = SimConfig(dim=2, dx=0.005, sound_speed=2.0, dtype="float64", dt=1e-3, checkpoint_every=7,
                           wall_pressure=wall_pressure, kernels=kernels)
        result = StirringSimulator(law, Rig(), config, density=1000.0)(trajectory)
        loss = (result.force**2).sum(-1).mean()
        runs.append((result.force.detach(), torch.autograd.grad(loss, list(law.parameters()))))
    torch.testing.assert_close(runs[0][0], runs[1][0], rtol=1e-9, atol=1e-12)
    for fused, ops in zip(runs[0][1], runs[1][1]):
        torch.testing.assert_close(fused, ops, rtol=1e-9, atol=1e-15)


def test_kernels_setting_is_checked():
    with pytest.raises(ValueError, match="sim.kernels"):
        SimConfig(kernels="triton")
    with pytest.raises(ValueError, match="runs on the CPU"):
        SimConfig(kernels="fused", device="cuda")


@needs_kernels
@pytest.mark.parametrize("d", [2, 3])
def test_forward_mode_tangents_equal_the_torch_ops(d):
    """In forward mode (``sensitivity``) the fused transfers give the primal they give without a tangent, and the
    tangent in the values and the positions that forward mode through the torch ops gives."""
    from torch.autograd import forward_ad
    grid, offset_index, points, x = _setup(d, count=6, seed=2)
    values = torch.randn(3, 6, d + 1, dtype=torch.float64)
    nodal = torch.randn(grid.num_nodes, 2, dtype=torch.float64)
    dx, dvalues, dnodal = torch.randn_like(x), torch.randn_like(values), torch.randn_like(nodal)

    def to_grid(values, x, fused):
        return scatter(values, _stencil(grid, offset_index, x, fused), grid.num_nodes, points, fused)

    def to_particles(nodal, x, fused):
        return gather(nodal, _stencil(grid, offset_index, x, fused), points, fused)

    for function, inputs, tangents in [(to_grid, (values, x.detach()), (dvalues, dx)),
                                       (to_particles, (nodal, x.detach()), (dnodal, dx))]:
        duals = {}
        for fused in (True, False):
            with forward_ad.dual_level():
                out = function(*(forward_ad.make_dual(i, t) for i, t in zip(inputs, tangents)), fused)
                duals[fused] = forward_ad.unpack_dual(out)
        torch.testing.assert_close(duals[True].primal, function(*inputs, True), rtol=0, atol=0)
        torch.testing.assert_close(duals[True].tangent, duals[False].tangent, rtol=1e-12, atol=1e-13)


def test_without_a_compiler_auto_takes_the_torch_ops_and_fused_says_why(monkeypatch, caplog):
    """A machine where the kernels do not build still simulates (``auto``, with a warning); asking for them
    (``fused``) is an error that names the cause and the setting that avoids it."""
    from diffstir.mpm import transfer
    monkeypatch.setattr(transfer, "_build", lambda: (None, OSError("c++: command not found")))
    with caplog.at_level("WARNING", logger="diffstir.mpm.transfer"):
        assert transfer.use_fused("auto", torch.device("cpu")) is False
    assert "command not found" in caplog.text
    with pytest.raises(RuntimeError, match=r"command not found.*sim.kernels=torch"):
        transfer.use_fused("fused", torch.device("cpu"))


def _lock_of(directory, pid: int, host: str | None = None, started: float | None = None) -> None:
    import json
    import socket
    import time

    from diffstir.mpm.transfer import _process_start
    (directory / "build.lock").write_text(json.dumps({
        "pid": pid, "host": host or socket.gethostname(), "started": time.time() if started is None else started,
        "process_start": _process_start(pid)}))


def test_a_dead_builders_lock_is_taken_over_at_once_with_a_notice(tmp_path, caplog):
    import subprocess
    import sys
    import time

    from diffstir.mpm.transfer import build_lock
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    _lock_of(tmp_path, int(dead.stdout))  # a builder killed while it held the lock, a moment ago
    started = time.monotonic()
    with caplog.at_level("WARNING", logger="diffstir.mpm.transfer"), build_lock(tmp_path):
        owner = (tmp_path / "build.lock").read_text()
    assert time.monotonic() - started < 1.0
    assert f"build.lock of pid {int(dead.stdout)}" in caplog.text and "gone" in caplog.text
    assert f'"pid": {__import__("os").getpid()}' in owner and not (tmp_path / "build.lock").exists()


def test_a_live_builders_lock_is_waited_for_and_another_hosts_old_lock_taken_over(tmp_path, caplog):
    import subprocess
    import sys
    import threading
    import time

    from diffstir.mpm.transfer import build_lock
    builder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        _lock_of(tmp_path, builder.pid)  # alive: waited for until it lets go after 0.5 s
        threading.Timer(0.5, (tmp_path / "build.lock").unlink).start()
        started = time.monotonic()
        with caplog.at_level("WARNING", logger="diffstir.mpm.transfer"), build_lock(tmp_path, poll=0.05):
            pass
        assert 0.45 < time.monotonic() - started < 5.0 and f"waiting for pid {builder.pid}" in caplog.text
    finally:
        builder.kill()
        builder.wait()
    _lock_of(tmp_path, 1, host="another-host", started=time.time() - 3600.0)
    started = time.monotonic()
    with build_lock(tmp_path, stale_after=600.0):
        pass
    assert time.monotonic() - started < 1.0


def test_the_build_is_keyed_by_what_changes_it_and_reused_without_a_rebuild(monkeypatch, tmp_path):
    import hashlib
    import sysconfig

    import torch.utils.cpp_extension

    from diffstir.mpm import transfer
    key = transfer.build_key()
    assert key["torch"] == torch.__version__ and key["abi"] == sysconfig.get_config_var("EXT_SUFFIX")
    assert key["source_sha256"] == hashlib.sha256(transfer.SOURCE.read_bytes()).hexdigest()
    assert key["flags"] == ["-O3"] and key["compiler"] and "compiler_version" in key
    directory = transfer.build_directory()
    monkeypatch.setattr(transfer, "build_key", lambda: {**key, "compiler": "/opt/other/c++"})
    assert transfer.build_directory() != directory and transfer.build_directory().parent == directory.parent
    monkeypatch.undo()
    transfer.kernels()  # built (or found built) under its key
    # a process of another environment with the same key reuses the build: no compiler, no ninja, no wait
    monkeypatch.setattr(torch.utils.cpp_extension, "load", lambda *a, **k: pytest.fail("rebuilt"))
    transfer._build.cache_clear()
    try:
        assert transfer.kernels() is not None
    finally:
        transfer._build.cache_clear()
