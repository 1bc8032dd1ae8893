"""An identification's checkpoint: the state of its fits saved as JSON after every change, resumed only for the
same recording (its content digest) and the same settings (``fingerprint``)."""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import OutputError
from ..fitting import PROBE_INDEX_STEP, FitSettings, SensorNuisance, StirProblem
from ..mpm import SimConfig
from ..recording import Recording
from ..recording.digest import recording_digest
from ..report_files import write_text_atomically
from ..slice_correction import slice_correction_table


def fingerprint(problem: StirProblem, names: list[str], settings: FitSettings, sensor: SensorNuisance,
                coarse: SimConfig | None) -> dict:
    """What a checkpoint's fits depend on: the recording's content digest, the models and every setting that
    changes a fit; a checkpoint of another fingerprint is not resumed (``Checkpoint.open``)."""
    config = problem.config
    return {"recording": recording_digest(problem.recording), "sensor_nuisance": list(sensor.fitted),
            "models": names, "window": settings.window, "holdout_fraction": settings.holdout_fraction,
            "optimizer": settings.optimizer, "max_iterations": settings.max_iterations,
            **config.force_settings(), "density": problem.density,
            "slice_correction": (slice_correction_table()["coefficients"]
                                 if config.dim == 2 and settings.slice_correction else None),
            "shear_rate_probes": PROBE_INDEX_STEP,
            "coarse": (None if coarse is None
                       else {**coarse.force_settings(), "fine_iterations": settings.fine_iterations})}


class Checkpoint:
    """An identification's state (``state``: the settings' fingerprint, the ladder, γ̇_eff, the stages' time
    steps, the finished fits and each running fit's last iterate), saved to ``path`` as JSON after every change
    (never when ``path`` is None)."""

    def __init__(self, path: str | Path | None, state: dict):
        self.path, self.state = path, state

    @classmethod
    def open(cls, path: str | Path | None, settings: dict, label: str, overwrite: bool) -> "Checkpoint":
        """The state saved in the checkpoint ``path`` when it holds a fit of the same recording
        (``settings["recording"]``, its digest) with the same ``settings``; a fresh state when there is none or with
        ``overwrite``. Otherwise an ``OutputError`` in one line."""
        fresh = {"settings": settings, "recording": label, "done": {}, "running": {}, "dt": {}}
        if path is None or overwrite or not Path(path).exists():
            return cls(path, fresh)
        try:
            state = json.loads(Path(path).read_text())
        except json.JSONDecodeError as exc:
            raise OutputError(f"{path}: the checkpoint is not valid JSON ({exc}); use another out= or "
                              "overwrite=true") from None
        saved = state.get("settings", {}) if isinstance(state, dict) else {}
        if saved.get("recording") != settings["recording"]:
            digest = saved.get("recording") or "none"
            raise OutputError(f"{path} holds a fit of recording {state.get('recording', '(unknown)')} (sha256 "
                              f"{digest[:12]}…), not of {label} (sha256 {settings['recording'][:12]}…); use another "
                              "out= or overwrite=true")
        changed = sorted(k for k in settings if saved.get(k) != settings[k])
        if changed:
            raise OutputError(f"{path}: the checkpoint was written with other settings ({', '.join(changed)}); use "
                              "another out= or overwrite=true")
        state.setdefault("dt", {})
        return cls(path, state)

    def save(self) -> None:
        """Write the state to ``path`` in one step (``report_files.write_text_atomically``)."""
        if self.path is not None:
            Path(self.path).parent.mkdir(parents=True, exist_ok=True)
            write_text_atomically(self.path, json.dumps(self.state))



def recording_label(recording: Recording) -> str:
    """How a checkpoint names its recording: its directory (or name)."""
    return str(recording.path) if recording.path else (recording.name or "(unnamed)")
