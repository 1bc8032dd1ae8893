"""The 3-D finite-element reference of the stir (scripts/stir_reference_3d.py) against closed forms, the 2-D
reference, and its own energy balance, on coarse meshes.

The meshes are affine: the rod's circle of radius a is a polygon with edges about one cell h long, whose mean
radius is short by h²/(12 a). A quantity F with sensitivity S = d ln F / d ln a then reads low by about
S h²/(12 a²), the tolerance used here (the measured error falls as h^1.6-1.8 from 6 to 3 mm cells, the polygon's
second order, docs/validation.md).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import pytest

pytest.importorskip("skfem")
pytest.importorskip("gmsh")
pytest.importorskip("pyamg")

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import stir_reference_3d as ref  # noqa: E402

from diffstir.lab import stokes3d  # noqa: E402

PAPER = stokes3d.CupRig()
A, B = PAPER.rod_radius, PAPER.cup_radius


def polygon_error(sensitivity: float, cell: float) -> float:
    """The relative error S h²/(12 a²) of a polygonal rod of edge ``cell`` [m]."""
    return sensitivity * cell**2 / (12 * A**2)


def centred(cell: float) -> tuple[stokes3d.CupRig, stokes3d.RigMesh]:
    rig = ref.long_rod(dataclasses.replace(PAPER, orbit=0.0), cell)
    return rig, stokes3d.build_mesh(rig, cell)


def test_margules_torque_converges_to_the_closed_form():
    """A centred rod spinning through the whole depth, slip ends: 4π η ω a² b² / (b² − a²) per length; S = 2b²/(b² −
    a²). The error falls from 6 to 4 mm cells by at least the first order, and at 4 mm is within the polygon's and
    the issue's 2 %."""
    exact = ref.couette_torque(1.0, 0.01 / A, A, B)
    errors = {}
    for cell in (0.006, 0.004):
        rig, mesh = centred(cell)
        result = stokes3d.solve(mesh, 1.0, 0.01, motion="spin")
        errors[cell] = abs(-result.torque / rig.fill / exact - 1)
    sensitivity = 2 * B**2 / (B**2 - A**2)
    assert errors[0.004] < min(0.02, polygon_error(sensitivity, 0.004))
    assert errors[0.004] < errors[0.006] / 1.5


def test_translating_rod_drag_matches_the_exact_2d_drag():
    """A centred rod translating through the whole depth, slip ends: 4π η U / [ln(b/a) − (b² − a²)/(b² + a²)] per
    length; S = (1 − 4a²b²/(a² + b²)²) / [ln(b/a) − (b² − a²)/(b² + a²)]."""
    rig, mesh = centred(0.004)
    result = stokes3d.solve(mesh, 2.0, 0.01, motion="translate")
    denominator = math.log(B / A) - (B**2 - A**2) / (B**2 + A**2)
    sensitivity = (1 - 4 * A**2 * B**2 / (A**2 + B**2) ** 2) / denominator
    ratio = result.drag / rig.fill / ref.translating_rod_drag(2.0, 0.01, A, B)
    assert abs(ratio - 1) < min(0.02, polygon_error(sensitivity, 0.004))
    assert abs(result.force[0]) < 1e-3 * result.drag  # no lift on a centred rod in Stokes flow


def test_eccentric_rod_matches_the_2d_reference_and_the_slab():
    """The paper's cross-section (rod on the 30 mm circle, 5 mm from the wall) through the whole depth with slip
    ends, stirred in Stokes flow: its drag per length is the 2-D reference's (scripts/stir_reference.py, another
    mesh and code) within the issue's 2 %, and so is the slab's (``slab_force``) that the slice's error is
    measured with."""
    cell = 0.004
    rig = ref.long_rod(PAPER, cell)
    long = stokes3d.solve(stokes3d.build_mesh(rig, cell), 1.0, 0.01)
    slab = stokes3d.slab_force(PAPER, cell, 1.0, 0.01)
    reference = ref.stokes_2d(PAPER, 1.0, 0.01, mesh=(160, 32))
    assert long.drag / rig.fill == pytest.approx(reference, rel=0.02)
    assert slab.drag == pytest.approx(reference, rel=0.02)


def test_power_law_couette_torque():
    """η = k γ̇^(n−1), n = 0.6, spinning centred rod: 2π k a² [2ω / (n (1 − (a/b)^(2/n)))]ⁿ per length, S = 2 + 2q/(1
    − q), q = (a/b)^(2/n); on 6 mm cells within the polygon's error (3.9 %)."""
    from diffstir.rheology import PowerLaw

    rig, mesh = centred(0.006)
    law = PowerLaw(k=1.0, n=0.6, shear_rate_reg=1e-6)
    result = stokes3d.solve(mesh, law, 0.01, motion="spin", tol=1e-4)
    q = (A / B) ** (2 / 0.6)
    exact = ref.power_law_couette_torque(1.0, 0.6, 0.01 / A, A, B)
    assert -result.torque / rig.fill == pytest.approx(exact, rel=polygon_error(2 + 2 * q / (1 - q), 0.006))
    assert result.iterations > 2


def test_stir_in_the_cup_dissipates_the_drags_work():
    """In Stokes flow the rod's power is the fluid's dissipation, drag × U = ∫ 2η D:D dV; the discrete reaction
    keeps it to round-off. The paper's rig on 6 mm cells, 1 Pa·s at 0.1 m/s; its rod is h/a = 8.4 radii long, so
    the tip's and the free surface's end effects move the drag from the slice's F' h by a few per cent (1.6 % on
    converged meshes, docs/validation.md), within 10 % here."""
    mesh = stokes3d.build_mesh(PAPER, 0.006)
    assert {name: len(mesh.mesh.boundaries[name]) > 0 for name in stokes3d.BOUNDARIES} == dict.fromkeys(stokes3d.BOUNDARIES,
                                                                                                    True)
    result = stokes3d.solve(mesh, 1.0, 0.1)
    assert result.dissipation == pytest.approx(result.drag * 0.1, rel=1e-6)
    slab = stokes3d.slab_force(PAPER, 0.006, 1.0, 0.1)
    assert result.drag / (slab.drag * PAPER.immersion) == pytest.approx(1.0, abs=0.1)


def test_krylov_solver_agrees_with_the_direct_one():
    """MINRES with the AMG and pressure-mass preconditioner solves the same system: the drag agrees to 1e-6."""
    mesh = stokes3d.build_mesh(PAPER, 0.008)
    direct = stokes3d.solve(mesh, 1.0, 0.1, solver="direct")
    krylov = stokes3d.solve(mesh, 1.0, 0.1, solver="krylov")
    assert krylov.drag == pytest.approx(direct.drag, rel=1e-6)
    assert krylov.torque == pytest.approx(direct.torque, rel=1e-4, abs=1e-9)


def test_inertial_slab_matches_the_2d_reference_at_steady_state():
    """Navier-Stokes in the turning frame (Picard): the 2-D stir of docs/validation.md (cup 42.5 mm, rod on a 15 mm
    circle at 0.1 m/s, 1 Pa·s, Re = 2.5) as a slab on 4 mm cells against the transient 2-D reference's steady drag
    3.3678 N/m and radial force +0.3038 N/m (converged to 0.02 %). The drag within the issue's 2 %; the radial
    force, an inertial force a tenth of the drag, converges as h^2.1 (4.2 % low on 6 mm cells, 0.4 % on 2 mm), so
    within twice its 4 mm estimate 4.2 % × (4/6)², 3.7 %."""
    rig = stokes3d.CupRig(cup_radius=0.0425, orbit=0.015)
    result = stokes3d.slab_force(rig, 0.004, 1.0, 0.1, inertia=True)
    assert result.drag == pytest.approx(3.3678, rel=0.02)
    assert result.radial == pytest.approx(0.3038, rel=2 * 0.042 * (4 / 6) ** 2)
    assert 2 < result.iterations < 20


def test_a_fixed_point_that_has_not_converged_raises():
    """A shear-thinning law stopped after two Picard steps reports it rather than returning a force."""
    from diffstir.rheology import PowerLaw

    _, mesh = centred(0.008)
    with pytest.raises(RuntimeError, match="did not converge in 2 iterations"):
        stokes3d.solve(mesh, PowerLaw(k=1.0, n=0.6, shear_rate_reg=1e-6), 0.01, motion="spin", max_iterations=2)
