"""The simulator's numerics beyond the closed forms: the transfers' numerical viscosity, and, with a compressible
pressure, the packing the grid measures and the sound speed a viscous stir needs."""

from __future__ import annotations

import math

import pytest
import torch

from diffstir.mpm import StirringSimulator
from diffstir.mpm.packing import packed_volume_ratio
from diffstir.mpm.step import node_fill, p2g
from diffstir.rheology import Newtonian
from diffstir.rig import Rig
from diffstir.trajectory import circle
from problems import fitting_default, numerical_viscosity

SLICE = fitting_default()
COMPRESSIBLE = SLICE.replace(pressure="compressible")  # the fine slice with its pressure from a sound speed


@pytest.mark.parametrize("dt", [1e-3, 2.5e-4])
def test_transfers_add_little_viscosity_at_any_time_step(dt, cache_dir):
    """APIC transfers alone damp an 8-cell shear wave as a viscosity of 8e-5 m²/s at Δt = 1 ms and 2e-4 m²/s at
    0.25 ms (as much as a 0.2 Pa·s fluid has, and growing as Δt shrinks: forces depended on the time step). With the
    FLIP share the transfers must stay below a quarter of the thinnest resolved fluid's 2e-4 m²/s at both steps."""
    assert numerical_viscosity(SLICE.replace(dt=dt), cache_dir) < 5e-5
    assert numerical_viscosity(SLICE.replace(dt=dt, flip=0.0), cache_dir) > 5e-5  # the defect the share removes


def test_resting_fluid_measures_its_own_packing(cache_dir):
    """After settling, the packing the grid measures, with the cup's walls and the rod counted as resting fluid, is
    the particles' own volume ratio (with a compressible pressure, whose J it relaxes): no particle of the 2-D slice
    lies at a free surface (every one relaxes at 90 % of the full rate or more: its emptiest stencil node is 95 %
    full); both ratios' rms deviation from 1 is under a quarter of the compression δ the compressible slice allows a
    stir (3 %: the rest's pressure noise κ·rms stays small against the stir's pressure), and no particle's J is off
    by the whole δ."""
    sim = StirringSimulator(Newtonian(eta=1.0), Rig(), COMPRESSIBLE, density=1000.0, cache_dir=cache_dir)
    trajectory = circle(radius=0.015, speed=0.1, duration=0.1)
    state = sim.initial_state(trajectory)
    buffer, stencil = p2g(sim.scene, state, 1e-3)
    pose = sim._poses(trajectory, trajectory.t[:2])[0]
    packed, inside = packed_volume_ratio(node_fill(sim.scene, buffer[:, 2], pose), stencil)
    assert float(inside.min()) > 0.9
    delta = COMPRESSIBLE.compressibility
    assert float((packed - 1).square().mean().sqrt()) < delta / 4
    assert float((state.J - 1).square().mean().sqrt()) < delta / 4
    assert float((state.J - 1).abs().max()) < delta


def test_sound_speed_follows_a_viscous_stirs_pressure(cache_dir):
    """ρ c² δ equals the larger of ρU² and the viscous pressure 2πηU / (a [ln(b/a) − (b² − a²)/(b² + a²)]): at
    0.1 m/s the sound speed stays at its least for water and grows as sqrt(η) for viscous fluids; and a 1 Pa·s stir
    at that sound speed compresses the fluid by less than δ on average."""
    rig, trajectory = Rig(), circle(radius=0.015, speed=0.1, duration=0.3)
    a, b, u = rig.rod.radius, rig.cup.radius, trajectory.max_speed(rig.rod.radius)
    delta = COMPRESSIBLE.compressibility
    for eta in (0.001, 1.0, 4.0):
        c = StirringSimulator(Newtonian(eta=eta), rig, COMPRESSIBLE, cache_dir=cache_dir).sound_speed(trajectory)
        pressure = max(1000.0 * u**2, 2 * math.pi * eta * u / (a * (math.log(b / a) - (b**2 - a**2) / (b**2 + a**2))))
        assert c == pytest.approx(max(COMPRESSIBLE.sound_speed, math.sqrt(pressure / (1000.0 * delta))), rel=1e-6)
    sim = StirringSimulator(Newtonian(eta=1.0), rig, COMPRESSIBLE, density=1000.0, cache_dir=cache_dir)
    with torch.no_grad():
        final = sim(trajectory).state
    assert float((1 - final.J).abs().mean()) < delta
