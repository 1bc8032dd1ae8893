"""The slice's correction (diffstir/slice_correction.py) against the 3-D finite-element study it is fitted to
(docs/data/slice_error.json), its physical limits, its range and its input checks."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import pytest

from diffstir.slice_correction import slice_correction

ROOT = Path(__file__).resolve().parents[1]
STUDY = json.loads((ROOT / "docs" / "data" / "slice_error.json").read_text())["rows"]
PAPER = dict(cup_radius=0.0475, fill_height=0.125, rod_radius=0.0125, immersion_depth=0.105, orbit_radius=0.030)


def arguments(row: dict) -> dict:
    return dict(cup_radius=row["cup_radius_m"], fill_height=row["fill_m"], rod_radius=row["rod_radius_m"],
                immersion_depth=row["immersion_m"], orbit_radius=row["orbit_m"], flow_index=row["law"].get("n", 1.0),
                reynolds=row["reynolds"])


@pytest.mark.parametrize("row", STUDY, ids=lambda r: f"{r['rig']}-{r['law'].get('n', 1)}-Re{r['reynolds']:.2g}")
def test_the_model_reproduces_the_study_within_three_sigma(row):
    correction = slice_correction(**arguments(row))
    assert correction.inside
    assert abs(correction.factor / row["ratio"] - 1) <= 3 * correction.sigma


def test_the_scatter_of_the_study_about_the_model_is_its_sigma():
    """σ is the rows' root-mean-square relative residual; within 3σ a normal scatter holds 99.7 % (above),
    within 1σ about two thirds."""
    residuals = [slice_correction(**arguments(r)).factor / r["ratio"] - 1 for r in STUDY]
    sigma = slice_correction(**PAPER).sigma
    assert sum(abs(r) <= sigma for r in residuals) >= 0.5 * len(residuals)


def test_the_factor_tends_to_one_as_the_rod_gets_long():
    """The tip's added length a ℓ is fixed, so factor − 1 falls as 1/h."""
    short = slice_correction(**{**PAPER, "fill_height": 0.080, "immersion_depth": 0.060})
    long = slice_correction(**{**PAPER, "fill_height": 2.020, "immersion_depth": 2.000})
    assert abs(long.factor - 1) == pytest.approx(abs(short.factor - 1) * 0.060 / 2.000, rel=1e-9)
    assert abs(long.factor - 1) < 1e-3


def test_a_small_gap_under_the_tip_adds_force_as_the_study_shows():
    """The disc of the tip shears the fluid under it as η U π a² / g: a smaller gap, a larger factor."""
    near = slice_correction(**{**PAPER, "fill_height": 0.115})  # g = 10 mm
    far = slice_correction(**{**PAPER, "fill_height": 0.155})  # g = 50 mm
    assert near.factor > far.factor


def test_outside_the_swept_range_sigma_widens():
    inside = slice_correction(**PAPER)
    thin = slice_correction(**PAPER, flow_index=0.2)
    fast = slice_correction(**PAPER, reynolds=300.0)
    assert inside.inside and not thin.inside and not fast.inside
    assert thin.sigma > inside.sigma and fast.sigma > inside.sigma


@pytest.mark.parametrize("name", ["cup_radius", "fill_height", "rod_radius", "immersion_depth", "orbit_radius"])
def test_a_negative_length_is_refused_naming_it_and_its_unit(name):
    expected = ("the rod's distance from the cup's axis, >= 0 m" if name == "orbit_radius"
                else "a positive length in m")  # a rod on the axis has orbit_radius 0
    with pytest.raises(ValueError, match=f"^{name} = -0.01 m; expected {expected}$"):
        slice_correction(**{**PAPER, name: -0.01})


def test_a_rod_that_does_not_fit_in_the_cup_is_refused():
    with pytest.raises(ValueError, match="orbit_radius = 0.04 m.*does not fit.*in m"):
        slice_correction(**{**PAPER, "orbit_radius": 0.040})
    with pytest.raises(ValueError, match="immersion_depth = 0.13 m reaches the bottom"):
        slice_correction(**{**PAPER, "immersion_depth": 0.130})


def test_bad_flow_index_and_reynolds_are_refused():
    with pytest.raises(ValueError, match="flow_index"):
        slice_correction(**PAPER, flow_index=0.0)
    with pytest.raises(ValueError, match="reynolds"):
        slice_correction(**PAPER, reynolds=-1.0)


@pytest.mark.parametrize("value", [True, "0.05", float("nan")])
def test_a_length_or_group_that_is_not_a_finite_number_is_refused_in_one_line(value):
    for name in ("rod_radius", "flow_index", "reynolds"):
        with pytest.raises(ValueError, match=f"^{name} = {re.escape(repr(value))}"):
            slice_correction(**{**PAPER, name: value})


@pytest.mark.slow
def test_a_fresh_finite_element_ratio_off_the_table_lies_within_two_sigma():
    """A rig not in the study (cup 45 mm, rod 11 mm on a 22 mm circle, 70 mm immersed, 25 mm gap), Stokes, the cup
    on 4.5 mm cells and the slab on 1.5 mm (the study's coarse meshes read about 1 % high, the reason for the
    fine slab here; docs/accuracy.md)."""
    pytest.importorskip("skfem")
    pytest.importorskip("gmsh")
    pytest.importorskip("pyamg")
    from diffstir.lab import stokes3d

    rig = stokes3d.CupRig(cup_radius=0.045, fill=0.095, rod_radius=0.011, gap=0.025, orbit=0.022)
    cup = stokes3d.solve(stokes3d.build_mesh(rig, 0.0045), 1.0, 0.1)
    slab = stokes3d.slab_force(rig, 0.0015, 1.0, 0.1)
    ratio = cup.drag / (slab.drag * rig.immersion)
    correction = slice_correction(rig.cup_radius, rig.fill, rig.rod_radius, rig.immersion, rig.orbit)
    assert abs(correction.factor / ratio - 1) <= 2 * correction.sigma
    assert dataclasses.is_dataclass(correction)
