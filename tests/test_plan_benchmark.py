"""The plan benchmark's store of truth simulations (scripts/plan_benchmark.py --truths): a stored truth reads back
as the simulation it was, and one made from other settings is refused."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import plan_benchmark as bench  # noqa: E402

from diffstir.lab import read_truth  # noqa: E402


def a_truth(fluid_name: str, kind: str) -> bench.TruthSimulation:
    """A truth of the ``kind`` programme with a force [N] that no simulation made: the store keeps arrays, not
    physics."""
    _, trajectory = bench.programme(bench.PROGRAMMES[kind])
    rng = np.random.default_rng(0)
    times = np.linspace(trajectory.t[0] + 5e-4, trajectory.t[-1], 400)
    truth = bench.TruthSimulation.silent(bench.fluid_named(fluid_name), trajectory, bench.Rig(), times,
                                         bench.truth_simulator())
    truth.force = rng.normal(0.0, 0.1, (times.size, 2))
    truth.discretisation = {"particles": 5192, "grid": [50, 50]}
    truth.per_unit_length, truth.slice_factor = True, 0.95
    return truth


def test_a_stored_truth_reads_back_as_the_simulation_it_was(tmp_path):
    truth = a_truth("bingham", "planned")
    path = tmp_path / "bingham_planned.npz"
    bench.store_truth(path, truth, 12.5, bench.truth_identity(truth.fluid, "planned"))
    back, seconds = bench.stored_truth(path, "bingham", "planned")
    assert seconds == 12.5
    np.testing.assert_array_equal(back.times, truth.times)
    np.testing.assert_array_equal(back.force, truth.force)
    assert (back.dt, back.discretisation, back.per_unit_length, back.slice_factor) == (
        truth.dt, truth.discretisation, truth.per_unit_length, truth.slice_factor)
    sensor = bench.sensor_preset("paper")
    read, read_back = (read_truth(t, sensor, seed=3).recording for t in (truth, back))
    np.testing.assert_array_equal(read.force, read_back.force)
    assert list(tmp_path.iterdir()) == [path]  # no partial file left


def test_a_truth_made_from_other_settings_is_refused(tmp_path):
    truth = a_truth("bingham", "example")
    identity = bench.truth_identity(truth.fluid, "example")
    identity["sim"]["dx"] *= 2
    path = tmp_path / "bingham_example.npz"
    bench.store_truth(path, truth, 1.0, json.loads(json.dumps(identity)))
    with pytest.raises(SystemExit, match="bingham_example.npz: made from other settings"):
        bench.stored_truth(path, "bingham", "example")
    assert bench.stored_truth(tmp_path / "absent.npz", "bingham", "example") is None


def test_a_truth_of_the_default_plan_is_refused_for_another_plans_programme(tmp_path, monkeypatch):
    truth = a_truth("bingham", "planned")
    path = tmp_path / "bingham_planned.npz"
    bench.store_truth(path, truth, 1.0, bench.truth_identity(truth.fluid, "planned"))
    spec, _ = bench.programme(bench.PROGRAMMES["planned"])
    other = tmp_path / "planned.yaml"  # the default plan with its slowest level halved
    other.write_text(json.dumps({**spec, "segments": [{**spec["segments"][0], "speed": 0.005},
                                                      *spec["segments"][1:]]}))
    monkeypatch.setitem(bench.PROGRAMMES, "planned", bench.PROGRAMMES["planned"])
    monkeypatch.setattr(bench, "SIM_SETTINGS", {})
    bench.use_settings(other, {})
    assert bench.programme(bench.PROGRAMMES["planned"])[0]["segments"][0]["speed"] == 0.005
    with pytest.raises(SystemExit, match="bingham_planned.npz: made from other settings"):
        bench.stored_truth(path, "bingham", "planned")
    # nor for other simulator settings (--sim)
    bench.use_settings(bench.CONF / "lab" / "programme" / "paper_plan.yaml", {"dt_max": 5e-4})
    assert bench.truth_simulator().dt_max == 5e-4
    with pytest.raises(SystemExit, match="bingham_planned.npz: made from other settings"):
        bench.stored_truth(path, "bingham", "planned")
