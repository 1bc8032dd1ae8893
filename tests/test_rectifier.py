"""The rectifier: the preliminary estimator, the pair synthesis (shards, resume, failures), training and use."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from diffstir.fitting.initial import ViscosityLadder
from diffstir.mpm import SimConfig
from diffstir.mpm.config import COARSE_STAGE
from diffstir.rectifier import pairs as pairs_module
from diffstir.rectifier.apply import load_rectifier, refine
from diffstir.rectifier.model import Rectifier
from diffstir.rectifier.pairs import LAW_DRAWS, PairDesign, collect, draw_fluid, run_shard
from diffstir.rectifier.training import PairData, evaluate, held_out_verdict, split_fluids, train
from diffstir.rheology import LAWS

FAST = SimConfig(dim=2, dx=0.01, sound_speed=2.0)


def test_ladder_inverts_a_reading_linear_in_viscosity_exactly():
    # F = F0 + b η between probes (Stokes drag on an inertial part) is what the ladder interpolates exactly
    etas = (1e-3, 1e-2, 1e-1, 1.0, 10.0)
    ladder = ViscosityLadder(etas, tuple(0.02 + 0.05 * e for e in etas))
    for eta in (0.003, 0.05, 0.7, 4.0, 30.0):  # 30: beyond the top probe, on the extended top segment
        assert ladder.invert(0.02 + 0.05 * eta) == pytest.approx(eta, rel=1e-9)
    assert ladder.invert(0.0) == 1e-3 and not ladder.resolves(0.0)
    assert ladder.invert(1e6, upper=1e3) == 1e3


def test_ladder_drops_the_inertial_floor():
    # thin fluids read the same inertial force: those probes carry no viscosity information
    ladder = ViscosityLadder((1e-3, 1e-2, 1e-1, 1.0), (0.0101, 0.0100, 0.0102, 0.03))
    assert not ladder.resolves(0.0101)
    assert ladder.invert(0.0101) == pytest.approx(0.01)  # at or below the floor: its highest viscosity
    assert ladder.resolves(0.0102)
    assert ladder.invert(0.02) == pytest.approx(0.1 + 0.9 * (0.02 - 0.0102) / (0.03 - 0.0102))


@pytest.mark.parametrize("law", sorted(LAW_DRAWS))
def test_drawn_fluids_have_the_target_viscosity_at_the_shear_rate(law):
    design = PairDesign(programmes=({"radius": 0.012, "speed": 0.1},), densities=(1000.0,), laws={law: 1.0})
    rng = np.random.default_rng(1)
    for _ in range(50):
        shear_rate = 10 ** rng.uniform(0.0, 1.0)
        fluid, g = draw_fluid(rng, design, lambda eta: shear_rate, 1000.0)
        assert g == shear_rate and fluid.law["name"] == law
        target = float(fluid.name.split()[-3])  # "<law> <target> Pa s", 4 significant digits
        eta = fluid.make_law()(torch.tensor([g], dtype=torch.float64)).item()
        # the regularised laws differ by (g_c / g)^2 << 1e-3 at g >= 1 1/s; the name keeps 4 digits
        assert eta == pytest.approx(target, rel=1e-3)
        assert 1e-3 <= target <= 10.0


def small_design(**changes):
    base = dict(programmes=({"radius": 0.012, "speed": 0.1},), densities=(1000.0,), duration=1.0, ramp_time=0.1,
                fluids_per_shard=2, sensors_per_fluid=3, viscosity=(0.3, 3.0), laws={"newtonian": 1.0},
                sensor={"mode": "tangential", "sample_rate": 100.0, "resolution": 0.001,
                        "noise_std": [0.001, 0.002], "gain_error": {"mean": 0.0, "std": 0.01}},
                window=1.0, holdout_fraction=0.25, seed=3)
    base.update(changes)
    return PairDesign(**base)


@pytest.fixture(scope="module")
def shard(tmp_path_factory):
    out = tmp_path_factory.mktemp("pairs")
    design = small_design()
    report = run_shard(design, 0, out, truth_config=FAST, estimator_config=FAST, log=lambda _: None)
    return design, out, report


def test_a_shard_writes_every_pair_and_the_estimator_recovers_its_own_truth(shard):
    design, out, report = shard
    assert report == {"shard": 0, "fluids": 2, "expected_fluids": 2, "failed": []}
    lines = [json.loads(x) for x in (out / "shards" / "shard-0000.jsonl").read_text().splitlines()]
    assert len(lines) == design.pairs == 6
    for p in lines:
        # truth and estimator share the resolution here, so the gap is the sensor's (noise averaged over ~75
        # samples, a gain error of 1 % std) and the ladder's linear interpolation of ln F in ln η between 0.1 and 1
        # or 1 and 10 Pa s: on this grid d ln F / d ln η rises from 0.3 to 0.6 across them, a curvature of about
        # 0.15 that bends ln F by up to (ln 10)² 0.15 / 8 = 0.1 between probes, 0.1 / 0.55 = 18 % in η
        assert p["resolves"]
        assert p["preliminary_viscosity"] == pytest.approx(p["reference_viscosity"], rel=0.2)
        assert p["mean_stirring_speed"] == pytest.approx(0.1, rel=0.15)  # the ramp lowers the mean
        assert p["density_estimate"] == pytest.approx(1000.0, rel=0.02)
    assert len({p["fluid_id"] for p in lines}) == 2


def test_a_finished_shard_resumes_without_simulating(shard, monkeypatch):
    design, out, _ = shard

    def no_simulation(*args, **kwargs):
        raise AssertionError("a finished shard simulated again")

    monkeypatch.setattr(pairs_module, "simulate_truth", no_simulation)
    assert run_shard(design, 0, out, truth_config=FAST, estimator_config=FAST, log=lambda _: None)["fluids"] == 2
    manifest = collect(design, out)
    assert manifest["complete"] and manifest["pairs"] == 6 and manifest["fluids"] == 2
    assert (out / "pairs.jsonl").read_text().count("\n") == 6


def test_a_shard_measured_with_an_older_shear_rate_is_rereferenced_without_truth_simulations(shard, tmp_path,
                                                                                          monkeypatch):
    # a change of γ̇_eff's definition changes every reference η_law(γ̇_eff) but no truth simulation or reading:
    # resuming re-measures the group's rates (keeping its ladder) and recomputes references from the stored laws
    import shutil

    design, out, _ = shard
    copy = tmp_path / "pairs"
    shutil.copytree(out / "shards", copy / "shards")
    group_file = copy / "shards" / "shard-0000.group.json"
    group = json.loads(group_file.read_text())
    group_file.write_text(json.dumps({**group, "shear_rate_method": "an older one"}))
    pairs_file = copy / "shards" / "shard-0000.jsonl"
    before = [json.loads(x) for x in pairs_file.read_text().splitlines()]
    pairs_file.write_text("".join(json.dumps({**r, "shear_rate_method": "an older one"}) + "\n" for r in before))

    def no_simulation(*args, **kwargs):
        raise AssertionError("re-referencing simulated a truth or a ladder again")

    monkeypatch.setattr(pairs_module, "simulate_truth", no_simulation)
    monkeypatch.setattr(pairs_module.ViscosityLadder, "simulate", no_simulation)
    monkeypatch.setattr(pairs_module, "effective_shear_rate", lambda problem, eta: 2.0 if eta < 1.0 else 3.0)
    assert run_shard(design, 0, copy, truth_config=FAST, estimator_config=FAST, log=lambda _: None)["fluids"] == 2
    assert json.loads(group_file.read_text())["ladder"] == group["ladder"]
    after = [json.loads(x) for x in pairs_file.read_text().splitlines()]
    assert [r["preliminary_viscosity"] for r in after] == [r["preliminary_viscosity"] for r in before]
    for r in after:
        law = LAWS[r["law"]](**r["law_parameters"]).double()
        rate = r["effective_shear_rate"]
        assert 2.0 - 1e-9 <= rate <= 3.0 + 1e-9 and r["shear_rate_method"] == pairs_module.SHEAR_RATE_METHOD
        assert r["reference_viscosity"] == pytest.approx(float(law(torch.tensor([rate], dtype=torch.float64))),
                                                         rel=1e-6)


def test_failing_fluids_are_retried_recorded_and_reported(shard, tmp_path, monkeypatch):
    design, out, _ = shard
    (tmp_path / "shards").mkdir()
    for name in ("shard-0000.group.json",):  # reuse the group's ladder: only the fluids fail
        (tmp_path / "shards" / name).write_text((out / "shards" / name).read_text())
    calls = []

    def failing(*args, **kwargs):
        calls.append(1)
        raise FloatingPointError("non-finite force")

    monkeypatch.setattr(pairs_module, "simulate_truth", failing)
    report = run_shard(design, 0, tmp_path, truth_config=FAST, estimator_config=FAST, retries=1, log=lambda _: None)
    assert len(calls) == 4 and report["failed"] == ["s0000-f000", "s0000-f001"]
    manifest = collect(design, tmp_path)
    assert not manifest["complete"] and manifest["failed"] == ["s0000-f000", "s0000-f001"]
    assert manifest["shards"][0]["missing_fluids"] == 2


def test_a_design_that_only_draws_more_fluids_reuses_the_groups(shard, tmp_path, monkeypatch):
    # the ladder and γ̇_eff depend on the programme, density, sensor and fit window, not on how many fluids or
    # sensor models a shard draws: five times the fluids must not simulate the group again
    design, out, _ = shard
    (tmp_path / "shards").mkdir()
    group_file = tmp_path / "shards" / "shard-0000.group.json"
    group_file.write_text((out / "shards" / "shard-0000.group.json").read_text())

    def no_simulation(*args, **kwargs):
        raise AssertionError("the group was simulated again")

    def stop_before_the_truth(*args, **kwargs):  # the fluids' truth simulations are not what this test is about
        raise RuntimeError("stopped before the truth simulation")

    monkeypatch.setattr(pairs_module.ViscosityLadder, "simulate", no_simulation)
    monkeypatch.setattr(pairs_module, "effective_shear_rate", no_simulation)
    monkeypatch.setattr(pairs_module, "simulate_truth", stop_before_the_truth)
    more = small_design(fluids_per_shard=4, sensors_per_fluid=1)
    assert more.digest() != design.digest() and more.group_digest() == design.group_digest()
    run_shard(more, 0, tmp_path, truth_config=FAST, estimator_config=FAST, retries=0, log=lambda _: None)
    assert json.loads(group_file.read_text())["group_digest"] == design.group_digest()
    assert small_design(duration=1.5).group_digest() != design.group_digest()


def test_a_shard_of_another_design_is_refused(shard):
    design, out, _ = shard
    with pytest.raises(ValueError, match="another pair design"):
        run_shard(small_design(seed=4), 0, out, truth_config=FAST, estimator_config=FAST, log=lambda _: None)


def test_a_shard_with_the_3d_finite_element_truth_samples_as_its_truth_and_records_it(tmp_path, monkeypatch):
    """The 3-D truth (``lab/sim@truth=fe3d``) steps to the programme's last sample, so the group samples its
    template on those steps; the pairs and the group record the truth's numerics, a group kept for another truth is
    refused, and hidden physics, which the finite elements do not model, is refused before any simulation."""
    pytest.importorskip("skfem")
    pytest.importorskip("gmsh")
    from diffstir.errors import ConfigError
    from diffstir.lab import FiniteElementTruth

    ladder = ViscosityLadder((1e-3, 1e-2, 1e-1, 1.0, 10.0), (0.01, 0.011, 0.02, 0.1, 1.0))  # the estimator's own
    monkeypatch.setattr(pairs_module.ViscosityLadder, "simulate", classmethod(lambda cls, problem: ladder))
    monkeypatch.setattr(pairs_module, "effective_shear_rate", lambda problem, eta: 5.0)  # simulated elsewhere
    truth = FiniteElementTruth(cell=0.008, dt=0.005)
    design = small_design(fluids_per_shard=1, sensors_per_fluid=2, viscosity=(5.0, 10.0))
    report = run_shard(design, 0, tmp_path, truth_config=truth, estimator_config=FAST, log=lambda _: None)
    assert report == {"shard": 0, "fluids": 1, "expected_fluids": 1, "failed": []}
    lines = [json.loads(x) for x in (tmp_path / "shards" / "shard-0000.jsonl").read_text().splitlines()]
    assert len(lines) == 2
    assert all(p["truth_config"] == {"kind": "fe3d", "cell": 0.008, "growth": 3.0, "dt": 0.005} for p in lines)
    group = json.loads((tmp_path / "shards" / "shard-0000.group.json").read_text())
    assert group["truth"] == truth.numerics() and group["times"][-1] <= design.duration
    with pytest.raises(ValueError, match="another truth"):
        run_shard(design, 0, tmp_path, truth_config=FAST, estimator_config=FAST, log=lambda _: None)
    hidden = small_design(physics={"thixotropy": {"alpha": 1.0, "breakdown": 0.05, "rebuild_time": 5.0,
                                                  "initial_structure": 1.0}})
    with pytest.raises(ConfigError, match="hidden physics needs an MPM truth"):
        run_shard(hidden, 0, tmp_path / "hidden", truth_config=truth, estimator_config=FAST, log=lambda _: None)
    assert not (tmp_path / "hidden").exists()


def synthetic_pairs(n_fluids=120, per_fluid=4, seed=0):
    """Pairs with a known systematic gap: η_p = 0.6 η_ref^1.1 (U / 0.05 m/s)^0.3, with 5 % noise per reading."""
    rng = np.random.default_rng(seed)
    pairs = []
    for f in range(n_fluids):
        eta, speed = 10 ** rng.uniform(-2, 1), rng.uniform(0.03, 0.12)
        for r in range(per_fluid):
            prelim = 0.6 * eta**1.1 * (speed / 0.05) ** 0.3 * math.exp(rng.normal(0, 0.05))
            pairs.append({"fluid_id": f"f{f:03d}", "pair_id": f"f{f:03d}-r{r}", "mean_stirring_speed": speed,
                          "preliminary_viscosity": prelim, "reference_viscosity": eta, "resolves": True,
                          "density_estimate": 1000.0, "estimator_config": {"dim": 2, "dx": 0.005,
                                                                           "sound_speed": 1.0}})
    return pairs


def test_split_is_by_fluid():
    pairs = synthetic_pairs(n_fluids=50)
    test, val, train = split_fluids(pairs, [0.2, 0.1], seed=0)
    ids = [{p["fluid_id"] for p in part} for part in (test, val, train)]
    assert not (ids[0] & ids[1] or ids[0] & ids[2] or ids[1] & ids[2])
    assert [len(i) for i in ids] == [10, 5, 35] and len(test) + len(val) + len(train) == len(pairs)


@pytest.fixture(scope="module", params=[False, True], ids=["absolute", "residual"])
def trained(tmp_path_factory, request):
    import lightning as L

    path = tmp_path_factory.mktemp("rect") / "pairs.jsonl"
    path.write_text("".join(json.dumps(p) + "\n" for p in synthetic_pairs()))
    L.seed_everything(0)
    data = PairData(path, ["mean_stirring_speed", "preliminary_viscosity"], batch_size=32)
    module, trainer = train(data, epochs=40, metadata={"estimator": {"dim": 2, "dx": 0.005, "sound_speed": 1.0}},
                            residual=request.param)
    ckpt = path.with_name("rectifier.ckpt")
    trainer.save_checkpoint(ckpt)
    return data, module, ckpt


def test_the_paper_network_learns_a_systematic_gap_on_unseen_fluids(trained):
    data, module, _ = trained
    errors = evaluate(module.rectifier, data.test)
    # the gap is a factor 0.6-2; the noise per reading is 5 %: refined errors must fall to near the noise
    assert errors["preliminary"]["median_relative"] > 0.3
    assert errors["refined"]["median_relative"] < 0.12


def test_a_checkpoint_refines_and_refuses_to_extrapolate(trained):
    data, module, ckpt = trained
    rectifier, metadata = load_rectifier(ckpt)
    assert rectifier.residual == module.rectifier.residual
    estimator = {"name": "newtonian_ladder", "dim": 2, "dx": 0.005, "sound_speed": 1.0}
    preliminary = {"viscosity": 0.6 * 0.5**1.1, "mean_stirring_speed": 0.05, "resolves": True,
                   "estimator": estimator}
    out = refine(rectifier, metadata, preliminary, 1000.0, str(ckpt))
    assert out["value"] == pytest.approx(0.5, rel=0.15) and out["preliminary"] == preliminary["viscosity"]
    fast = refine(rectifier, metadata, dict(preliminary, mean_stirring_speed=0.5), 1000.0, str(ckpt))
    assert fast["value"] is None and "mean_stirring_speed = 0.5 m/s is outside the training range" in fast["note"]
    other = refine(rectifier, metadata, dict(preliminary, estimator=dict(estimator, dx=0.01)), 1000.0, str(ckpt))
    assert other["value"] is None and "dx=0.01" in other["note"]
    thin = refine(rectifier, metadata, dict(preliminary, resolves=False), 1000.0, str(ckpt))
    assert thin["value"] is None and "not identifiable" in thin["note"]


def test_the_held_out_verdict_applies_a_rectifier_only_where_it_lowers_the_error(trained):
    """On unseen fluids with the gap it learned the rectifier lowers the error and is applied (its checkpoint says
    so); on fluids without that gap (the preliminary estimate is the reference) it can only add one: not applied,
    and why, in the verdict and in the refinement's note."""
    data, module, ckpt = trained
    rectifier, metadata = load_rectifier(ckpt)
    assert metadata["held_out"]["applies"] and "lowers the held-out error" in metadata["held_out"]["reason"]
    assert metadata["held_out"]["metrics"] == evaluate(rectifier, data.test)
    no_gap = [dict(p, preliminary_viscosity=p["reference_viscosity"], law="newtonian") for p in data.test]
    verdict = held_out_verdict(rectifier, no_gap)
    assert not verdict["applies"] and "does not lower the held-out MAE" in verdict["reason"]
    assert verdict["metrics"]["preliminary"]["mae_mpas"] == 0.0 and set(verdict["by_law"]) == {"newtonian"}
    estimator = {"name": "newtonian_ladder", "dim": 2, "dx": 0.005, "sound_speed": 1.0}
    preliminary = {"viscosity": 0.6 * 0.5**1.1, "mean_stirring_speed": 0.05, "resolves": True,
                   "estimator": estimator}
    refused = refine(rectifier, dict(metadata, held_out=verdict), preliminary, 1000.0, str(ckpt))
    assert refused["value"] is None and refused["note"] == "not refined: the rectifier " + verdict["reason"]
    unknown = refine(rectifier, {k: v for k, v in metadata.items() if k != "held_out"}, preliminary, 1000.0,
                     str(ckpt))
    assert unknown["value"] is None and "no held-out verdict" in unknown["note"]


def test_the_shipped_checkpoint_is_not_applied_to_an_estimate_of_other_numerics():
    """The shipped pairs' estimator ran without the shear stress's substeps (its record predates them): the fit's
    coarse stage runs with them, so its estimate is not refined, and the note names the setting."""
    shipped = Path(__file__).resolve().parents[1] / "checkpoints" / "rectifier" / "rectifier.ckpt"
    rectifier, metadata = load_rectifier(shipped)
    assert "viscous_substeps" not in metadata["estimator"]
    preliminary = {"viscosity": 0.5, "mean_stirring_speed": 0.05, "resolves": True,
                   "estimator": {"name": "newtonian_ladder", **COARSE_STAGE.numerics()}}
    out = refine(rectifier, metadata, preliminary, 1000.0, str(shipped))
    assert out["value"] is None
    assert out["note"] == ("not refined: the preliminary estimate was made with viscous_substeps=True, the rectifier "
                           "was trained on viscous_substeps=False")


def test_a_residual_rectifier_corrects_the_preliminary_viscosity():
    # ln η_refined = ln η_p + μ_y + σ_y · MLP(z): with the MLP's output zero, the refined viscosity is the
    # preliminary one times the training set's geometric-mean correction, whatever the other inputs
    rectifier = Rectifier(residual=True)
    x = torch.tensor([[0.05, 0.2], [0.1, 0.5], [0.04, 2.0]])
    rectifier.fit_scaling(x, 1.25 * x[:, 1])
    torch.nn.init.zeros_(rectifier.mlp[-1].weight)
    torch.nn.init.zeros_(rectifier.mlp[-1].bias)
    probe = torch.tensor([[0.07, 0.01], [0.12, 7.0]])
    torch.testing.assert_close(rectifier(probe), 1.25 * probe[:, 1])
    with pytest.raises(ValueError, match="lack 'preliminary_viscosity'"):
        Rectifier(inputs=("mean_stirring_speed",), residual=True)


def test_rectifier_rejects_unknown_inputs_and_non_positive_values():
    with pytest.raises(ValueError, match="expected names from"):
        Rectifier(inputs=("speed",))
    with pytest.raises(ValueError, match="positive"):
        Rectifier().fit_scaling(torch.tensor([[0.05, -1.0]]), torch.tensor([1.0]))
