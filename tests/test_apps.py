"""The command-line apps as their users run them, through their console scripts: a refused setting, recording or
output folder in one line with exit status 2 and nothing written; help pages; what is never overwritten."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "diffstir" / "data" / "examples" / "carreau_example"
APPS = ["diffstir-fit", "diffstir-diagnose", "diffstir-simulate", "diffstir-synth", "diffstir-record",
        "diffstir-pairs", "diffstir-train-rectifier"]


def run(app: str, *args: str, cwd: Path, env: dict | None = None, timeout: float = 120.0):
    """``app args`` run in ``cwd`` as a user runs it; the finished process."""
    return subprocess.run([shutil.which(app), *args], cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})


def assert_refused(done, app: str, message: str) -> None:
    """Exit status 2 and one line on stderr, ``<app>: error: <message...>``, no traceback."""
    assert done.returncode == 2, done.stderr[-3000:]
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{app}: error: {message}"), done.stderr[-3000:]


@pytest.mark.parametrize("args, message", [
    (["fit.optimizer=sgd"], "fit.optimizer = 'sgd'; choose from lm, adam"),
    (["fit.selection=aic"], "fit.selection = 'aic'; choose from bic, holdout, loss"),
    (["model=[newtonian,casson]"], "model: unknown casson; choose from"),
    (["fit.sensor_nuisance=[drift]"], "fit.sensor_nuisance: unknown drift; choose from offset, lag"),
    (["fit.sensor_nuisance=[lag]", "fit.optimizer=adam"], "fit.sensor_nuisance = ['lag'] needs fit.optimizer = lm"),
    (["fit.selection=holdout", "fit.holdout_fraction=0"], "fit.selection = 'holdout' needs held-out samples"),
    (["rectifier.checkpoint=missing.ckpt"], "rectifier.checkpoint = missing.ckpt: no such file"),
    (["fit.model_error=-0.1"], "fit.model_error = -0.1; expected a relative force error in [0, 1)"),
    (["fit.inertial_error=1.5"], "fit.inertial_error = 1.5; expected a relative force error in [0, 1)"),
    (["fit.max_iterations=0"], "fit.max_iterations = 0; expected a whole number of at least 1"),
    (["fit.max_iterations=abc"], "Error merging override fit.max_iterations=abc: Value 'abc' of type 'str' could not "
                                 "be converted to Integer"),  # the schema's type
    (["fit.slice_correction=maybe"], "Error merging override fit.slice_correction=maybe: Value 'maybe' is not a "
                                     "valid bool"),
    (["threads=0"], "threads = 0; expected at least 1"),
    (["fit.windw=3"], "Could not override 'fit.windw'."),  # misspelt
    (["sim=slice3d"], "In 'fit': Could not find 'sim/slice3d' Available options in 'sim': coarse2d, fine3d"),
])
def test_a_wrong_fit_setting_is_refused_in_one_line_before_any_simulation_and_writes_nothing(tmp_path, args,
                                                                                               message):
    done = run("diffstir-fit", f"recording={EXAMPLE}", *args, cwd=tmp_path)
    assert_refused(done, "diffstir-fit", message)
    assert not any(tmp_path.iterdir())  # no outputs/ folder, no Hydra run folder, no log


def test_a_refused_run_makes_no_output_folder_where_out_is_given(tmp_path):
    done = run("diffstir-fit", f"recording={EXAMPLE}", f"out={tmp_path / 'a' / 'b'}", "fit.optimizer=sgd",
               cwd=tmp_path)
    assert_refused(done, "diffstir-fit", "fit.optimizer")
    assert not any(tmp_path.iterdir())


def test_experiment_settings_missing_values_and_other_apps_are_refused_in_one_line(tmp_path):
    assert_refused(run("diffstir-fit", "experiment=mixing", f"recordings=[{EXAMPLE},{EXAMPLE}]",
                       "mixing.viscosities=[1.0,0.1]", "mixing.fraction=0.5", cwd=tmp_path),
                   "diffstir-fit", "recordings = [")
    assert_refused(run("diffstir-fit", "experiment=mixing", f"recordings=[{EXAMPLE}]", "mixing.viscosities=[0.1,1.0]",
                       "mixing.fraction=0.5", cwd=tmp_path), "diffstir-fit",
                   "mixing.viscosities = [0.1, 1.0]; expected [eta1, eta2] in Pa·s, both positive, the more viscous "
                   "first")
    assert_refused(run("diffstir-fit", "experiment=behaviour", f"recordings=[{EXAMPLE}]", "behaviour.slope_test=t",
                       cwd=tmp_path), "diffstir-fit", "behaviour.slope_test = 't'; choose from combined")
    assert_refused(run("diffstir-fit", "experiment=behaviour", f"recordings=[{EXAMPLE}]",
                       "behaviour.inertial_error=-1", cwd=tmp_path), "diffstir-fit",
                   "behaviour.inertial_error = -1.0; expected a relative force error in [0, 1)")
    assert_refused(run("diffstir-fit", cwd=tmp_path), "diffstir-fit", "Missing mandatory value: recording")
    assert_refused(run("diffstir-diagnose", f"recording={EXAMPLE}", "diagnosis.candidates=[sensor_lag,gremlins]",
                       cwd=tmp_path), "diffstir-diagnose",
                   "diagnosis.candidates: unknown gremlins; choose from sensor_lag")
    assert_refused(run("diffstir-simulate", "stir.radius=-0.01", f"out={tmp_path / 'sim'}", cwd=tmp_path),
                   "diffstir-simulate", "stir: circle: radius = -0.01 m")
    assert not any(tmp_path.iterdir())


def test_a_simulation_that_blows_up_is_one_line_naming_the_setting_and_leaves_no_empty_output_folder(tmp_path):
    # an acoustic Courant number of 4: the explicit step is unstable from its first steps (stable below 1)
    done = run("diffstir-simulate", "sim.cfl=4", "stir.duration=0.3", f"out={tmp_path / 'sim'}", cwd=tmp_path)
    assert_refused(done, "diffstir-simulate", "the fluid became non-finite while settling")
    assert "try a smaller sim.cfl" in done.stderr
    assert not any(tmp_path.iterdir())


RECORD = ["hardware/adc=emulated", "hardware/arm=replay", "hardware/gripper=emulated", "density.skip=true"]


@pytest.mark.parametrize("app, args, message", [
    ("diffstir-diagnose", [f"recording={EXAMPLE}", "diagnosis.candidates=[nonsense]"],
     "diagnosis.candidates: unknown nonsense; choose from sensor_lag, sensor_deadband, sensor_drift, thixotropy"),
    ("diffstir-diagnose", [f"recording={EXAMPLE}", "diagnosis.window=0"], "diagnosis.window = 0.0 s; expected at "
                                                                           "least 0.001 s, or null"),
    ("diffstir-diagnose", [f"recording={EXAMPLE}", "diagnosis.max_iterations=0"],
     "diagnosis.max_iterations = 0; expected a whole number of at least 1"),
    ("diffstir-diagnose", [f"recording={EXAMPLE}", "candidates=[sensor_lag]"], "Could not override 'candidates'."),
    ("diffstir-train-rectifier", ["model.activation=nonsense"], "model.activation = 'nonsense'; choose from tanh, "
                                                                "relu, silu"),
    ("diffstir-train-rectifier", ["model.inputs=[speed]"], "model.inputs: unknown speed; choose from "
                                                           "mean_stirring_speed, preliminary_viscosity"),
    ("diffstir-train-rectifier", ["split.test_fraction=0.95"], "split.val_fraction + split.test_fraction = 1.05; "
                                                               "expected less than 1"),
    ("diffstir-train-rectifier", ["train.epochs=0"], "train.epochs = 0; expected a whole number of at least 1"),
    ("diffstir-train-rectifier", ["device=tpu"], "device = 'tpu'; choose from cpu, gpu, auto"),
    ("diffstir-record", [*RECORD, "grip.force_percent=5"], "grip.force_percent = 5.0 %; expected 20 to 100 %"),
    ("diffstir-record", [*RECORD, "dry_run.mode=wet"], "dry_run.mode = 'wet'; choose from mean, profile"),
    ("diffstir-record", [*RECORD, "sensor.mode=nonsense"], "sensor.mode = 'nonsense'; choose from component, "
                                                           "tangential, magnitude"),
    ("diffstir-record", [*RECORD, "stir.duration=-1"], "stir.duration = -1.0 s; expected a positive number in s"),
    ("diffstir-pairs", ["+pairs.design.laws.bingham=0.1"], "pairs.design.laws: unknown bingham; choose from carreau"),
    ("diffstir-pairs", ["pairs.design.fluids_per_shard=0"], "pairs.design.fluids_per_shard = 0; expected a whole "
                                                            "number of at least 1"),
    ("diffstir-pairs", ["shard=25"], "shard = 25; expected 0 <= shard < 25"),
    ("diffstir-pairs", ["retries=-1"], "retries = -1; expected at least 0"),
    ("diffstir-synth", ["lab.sensor.mode=nonsense"], "lab/sensor: sensor.mode = 'nonsense'; expected one of "
                                                     "component, tangential, magnitude"),
], ids=lambda value: " ".join(value) if isinstance(value, list) else None)
def test_a_wrong_setting_of_the_other_apps_is_refused_in_one_line_before_anything_runs(tmp_path, app, args, message):
    done = run(app, *args, "out=out", cwd=tmp_path)
    assert_refused(done, app, message)
    assert not any(tmp_path.iterdir())


def test_a_blend_recording_too_short_for_the_mixing_time_course_is_refused_before_simulating(tmp_path):
    short = ROOT / "diffstir" / "data" / "examples" / "rig_behaviour_mid"  # 0.8 s: one 0.5 s window after the ramp
    done = run("diffstir-fit", "experiment=mixing", f"recordings=[{short}]", "mixing.viscosities=[1.0,0.1]",
               "mixing.fraction=0.5", "out=mixing", cwd=tmp_path, timeout=60)
    assert_refused(done, "diffstir-fit", f"{short / 'stir.csv'}: 1 window of mixing.window = 0.5 s")
    assert "at least 4" in done.stderr and not any(tmp_path.iterdir())


def test_hydra_full_error_shows_the_traceback(tmp_path):
    done = run("diffstir-fit", f"recording={EXAMPLE}", "fit.optimizer=sgd", cwd=tmp_path,
               env={"HYDRA_FULL_ERROR": "1"})
    assert done.returncode != 0 and "Traceback" in done.stderr and "ConfigError" in done.stderr


def test_the_fits_default_output_folder_is_keyed_by_the_recording(tmp_path):
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from diffstir.apps import CONF_DIR, run_folder
    from diffstir.recording import load_recording, save_recording
    from diffstir.recording.digest import recording_digest

    copy = shutil.copytree(EXAMPLE, tmp_path / "carreau_example")
    if not OmegaConf.has_resolver("run_folder"):
        OmegaConf.register_new_resolver("run_folder", run_folder)
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        a, b = (compose("fit", overrides=[f"recording={path}"]) for path in (EXAMPLE, copy))
    digest = recording_digest(load_recording(EXAMPLE))[:8]
    assert a.out == b.out == f"outputs/fit/carreau_example-{digest}"  # the same content, the same folder
    rec = load_recording(EXAMPLE)  # another recording of the same name: twice the force
    other = save_recording(dataclasses.replace(rec, force=2 * rec.force), tmp_path / "other" / "carreau_example")
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        changed = compose("fit", overrides=[f"recording={other}"])
    assert changed.out != a.out and changed.overwrite is False


@pytest.mark.parametrize("app", APPS)
def test_each_app_has_its_own_help_page(tmp_path, app):
    done = run(app, "--help", cwd=tmp_path)
    assert done.returncode == 0 and not any(tmp_path.iterdir())
    page = done.stdout
    assert page.startswith(f"usage: {app} ") and "is powered by Hydra" not in page
    assert "Exit status: 0 done; 2 " in page
    groups = page.split("Config groups (group=option):")[-1]
    own = {"diffstir-fit": ["optimizer: lm", "# lm | adam", "diffstir-fit experiment=behaviour"],
           "diffstir-diagnose": ["candidates:", "identify_iterations:"],
           "diffstir-simulate": ["stir:", "law"], "diffstir-synth": ["overwrite: false", "  lab/fluid  "],
           "diffstir-record": ["  hardware/adc  ", "emulated, serial", "flush_interval:"],
           "diffstir-pairs": ["collect: false", "shard:"],
           "diffstir-train-rectifier": ["overwrite: false", "out: outputs/rectifier/"]}[app]
    assert all(text in page for text in own), page
    if app == "diffstir-fit":
        assert "  coarse (sim options)  " in groups and "  experiment  " in groups
    if app != "diffstir-record":
        assert "hardware" not in groups and "arm:" not in groups
    if app not in ("diffstir-synth", "diffstir-pairs"):
        assert "lab/" not in groups


def test_the_trainer_writes_under_outputs_by_default_and_never_over_a_rectifier_unless_told(tmp_path):
    from omegaconf import OmegaConf

    assert OmegaConf.load(ROOT / "conf" / "rectifier.yaml").out.startswith("outputs/rectifier/")
    out = tmp_path / "rectifier"
    out.mkdir()
    (out / "card.json").write_text('{"shipped": true}\n')
    done = run("diffstir-train-rectifier", f"out={out}", f"data={ROOT / 'checkpoints/rectifier/pairs.jsonl.gz'}",
               cwd=tmp_path)
    assert_refused(done, "diffstir-train-rectifier", f"{out / 'card.json'}: a trained rectifier is already there")
    assert json.loads((out / "card.json").read_text()) == {"shipped": True} and not (out / "tensorboard").exists()


def test_synth_refuses_an_existing_recording_before_simulating(tmp_path):
    existing = tmp_path / "lab" / "carreau_example"
    existing.mkdir(parents=True)
    (existing / "recording.yaml").write_text("kept: true\n")
    # a fine truth simulation would take minutes: a refusal within the timeout comes before it
    done = run("diffstir-synth", f"out={tmp_path / 'lab'}", "lab.sim.dx=0.002", cwd=tmp_path, timeout=60.0)
    assert_refused(done, "diffstir-synth", f"{existing}: already exists")
    assert (existing / "recording.yaml").read_text() == "kept: true\n"
    assert sorted(p.name for p in (tmp_path / "lab").iterdir()) == ["carreau_example"]


def test_collect_replaces_the_pairs_file_in_one_step(tmp_path, monkeypatch):
    from omegaconf import OmegaConf

    from diffstir.rectifier import pairs

    design = pairs.design_from_mapping(OmegaConf.to_container(OmegaConf.load(ROOT / "conf/pairs/design/paper.yaml")))
    (tmp_path / "pairs.jsonl").write_text("old\n")

    def disk_full(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", disk_full)
    with pytest.raises(OSError, match="No space left"):
        pairs.collect(design, tmp_path)
    assert (tmp_path / "pairs.jsonl").read_text() == "old\n"  # the old file whole, no temporary file left
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pairs.jsonl"]
    monkeypatch.undo()
    manifest = pairs.collect(design, tmp_path)
    assert (tmp_path / "pairs.jsonl").read_text() == "" and manifest["pairs"] == 0


def test_a_checkpoint_of_another_recording_in_out_is_refused_in_one_line(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    other = json.dumps({"settings": {"recording": "0" * 64}, "recording": "another", "done": {}, "running": {}})
    (out / "checkpoint.json").write_text(other)
    done = run("diffstir-fit", f"recording={EXAMPLE}", f"out={out}", cwd=tmp_path)
    assert_refused(done, "diffstir-fit", f"{out / 'checkpoint.json'} holds a fit of recording another")
    assert (out / "checkpoint.json").read_text() == other and sorted(p.name for p in out.iterdir()) == [
        "checkpoint.json"]


def test_a_recordings_warning_is_one_line_naming_the_app(tmp_path):
    recording = tmp_path / "rec"
    shutil.copytree(EXAMPLE, recording)
    yaml_path = recording / "recording.yaml"
    yaml_path.write_text(yaml_path.read_text() + "operator: ada\n")  # an unknown field: read, warned of, kept
    done = run("diffstir-fit", f"recording={recording}", "rectifier.checkpoint=missing.ckpt", cwd=tmp_path)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 2, done.stderr[-3000:]
    assert lines[0].startswith("diffstir-fit: warning: ") and "operator" in lines[0]
    assert lines[1].startswith("diffstir-fit: error: ")


def test_synth_refuses_hidden_physics_in_the_3d_truth_in_one_line_before_simulating(tmp_path):
    done = run("diffstir-synth", "lab/sim=fe3d", "lab/physics=thixotropic", "out=lab", cwd=tmp_path, timeout=60.0)
    assert_refused(done, "diffstir-synth", "lab/physics: hidden physics needs an MPM truth")
    assert not (tmp_path / "lab").exists()


def test_synth_refuses_a_programme_too_short_to_fit_before_simulating(tmp_path):
    """A 0.8 s stir at 0.05 m/s on the 15 mm circle spans less than one stirring period: refused in one line before
    the truth simulation (a 2 mm truth would take minutes), nothing written."""
    done = run("diffstir-synth", "lab.programme.segments=[{speed:0.05,duration:0.8}]", "out=lab", cwd=tmp_path,
               timeout=60.0)
    assert_refused(done, "diffstir-synth", "lab/programme, lab/sensor: the recording they make would be invalid: "
                                            "column 't' spans 0.8 s")
    assert not (tmp_path / "lab").exists()
