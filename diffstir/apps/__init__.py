"""Command-line applications; the only modules that import Hydra.

Every app runs through ``command``: it prints its own help page for ``-h``/``--help``, turns the project's errors
(``DiffstirError``: a recording, a setting, an output folder, a simulation those settings cannot run) into one line
on stderr and exit status 2, removing an output folder it made and left empty (``HYDRA_FULL_ERROR=1`` re-raises
them with the full traceback), and turns SIGINT and SIGTERM into one line and exit status 128 + the signal's number
(130, 143), keeping what the run has written. Exit status 0: done.
"""

from __future__ import annotations

import functools
import os
import re
import signal
import sys
import warnings
from pathlib import Path
from typing import Callable

import hydra
from hydra.core.config_store import ConfigStore
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from hydra.errors import InstantiationException
from hydra.utils import to_absolute_path
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import MissingMandatoryValue, OmegaConfBaseException

from diffstir.behaviour import BehaviourSettings
from diffstir.diagnosis import DiagnosisSettings
from diffstir.errors import DiffstirError, check_at_least
from diffstir.fitting import FitSettings
from diffstir.hardware import DensitySettings, DryRunSettings, GripSettings, SensorSettings, StirSettings
from diffstir.mixing import MixingSettings
from diffstir.parallel import default_workers
from diffstir.recording import load_recording
from diffstir.recording.digest import recording_digest
from diffstir.rectifier.settings import DesignSettings, ModelSettings, SplitSettings, TrainSettings

#: The project's Hydra configs (the repository's top-level conf/), as an absolute path so that the apps find them
#: whether started as console scripts, with python -m, or from another working directory.
CONF_DIR = str(Path(__file__).resolve().parents[2] / "conf")

#: The schemas of the config nodes that have one, by name: a defaults entry ``- <name>@<node>`` composes the node on
#: it, so that an unknown key or a value of the wrong type is refused when the command line is composed.
SCHEMAS = {"fit_settings": FitSettings, "behaviour_settings": BehaviourSettings, "mixing_settings": MixingSettings,
           "diagnosis_settings": DiagnosisSettings,
           "rectifier_model_settings": ModelSettings, "rectifier_train_settings": TrainSettings,
           "rectifier_split_settings": SplitSettings, "pair_design_settings": DesignSettings,
           "record_sensor_settings": SensorSettings, "record_grip_settings": GripSettings,
           "record_dry_run_settings": DryRunSettings, "record_density_settings": DensitySettings,
           "record_stir_settings": StirSettings}
for _name, _schema in SCHEMAS.items():
    ConfigStore.instance().store(name=_name, node=_schema)


def config_workers(cfg: DictConfig) -> int:
    """The config's ``workers``: processes for fits side by side (null: one per CPU, one on a GPU)."""
    return default_workers(cfg.sim.device) if cfg.workers is None else int(cfg.workers)


def check_processes(cfg: DictConfig) -> None:
    """Raise ConfigError unless ``threads`` (torch threads per process) and ``workers`` (null: one per CPU) are at
    least 1."""
    check_at_least("threads", cfg.threads, 1)
    if "workers" in cfg:
        check_at_least("workers", cfg.workers, 1)


def recording_key(root: DictConfig) -> str:
    """``<name>-<first 8 hex digits of its content digest>`` of each recording (``recording``, else
    ``recordings``) of the config ``root``, joined by ``+``."""
    node = root._get_node("recording")
    paths = [root.recording] if node is not None and not node._is_missing() else list(root.get("recordings", []))
    keys = []
    for p in paths:
        path = Path(to_absolute_path(str(p))).resolve()
        stamps = tuple((f.name, f.stat().st_mtime_ns, f.stat().st_size) for f in sorted(path.glob("*"))
                       if f.is_file()) if path.is_dir() else ()
        keys.append(f"{path.name}-{_digest_prefix(path, stamps)}")
    return "+".join(keys)


@functools.lru_cache(maxsize=None)
def _digest_prefix(path: Path, stamps: tuple) -> str:
    """The first 8 hex digits of the recording's content digest at ``path``, loaded once per state of its files
    (``stamps``: name, modification time and size of each): the config resolves ``out`` more than once."""
    return recording_digest(load_recording(path))[:8]


def run_folder(parent: str, *, _root_: DictConfig) -> str:
    """A run's default output folder (``${run_folder:outputs/fit}`` in conf/fit.yaml): ``parent/<recording_key>``,
    so that the same command on the same recording resumes its run and another recording of the same name does
    not; in a sweep (``-m``), the job's own folder in the sweep's."""
    if HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN:
        return str(HydraConfig.get().runtime.output_dir)
    return f"{parent}/{recording_key(_root_)}"


class Run:
    """What the app running in this process has written, for the line an interruption prints."""

    out: Path | None = None
    kept: tuple[str, ...] = ()
    made: bool = False

    @classmethod
    def writes(cls, out: Path, *kept: str) -> Path:
        """Make the output folder ``out`` (after the run's inputs passed their checks) and name the files in it
        that an interrupted run keeps; returns ``out``."""
        cls.made = not out.exists()
        out.mkdir(parents=True, exist_ok=True)
        cls.out, cls.kept = out, kept
        return out

    @classmethod
    def discard_empty(cls) -> None:
        """Remove the output folder this run made if nothing was written into it (a run refused midway)."""
        if cls.made and cls.out is not None and cls.out.is_dir() and not any(cls.out.iterdir()):
            cls.out.rmdir()

    @classmethod
    def kept_line(cls) -> str:
        if cls.out is None or not cls.out.exists():
            return "nothing written"
        files = [cls.out / name for name in cls.kept if (cls.out / name).exists()]
        return "kept " + ", ".join(map(str, files or [cls.out]))


def one_line(error: BaseException) -> str:
    """The message of a user's error in one line: a DiffstirError's own; a setting's error (OmegaConf, a config's
    instantiation) as its first line, with the setting's key."""
    if isinstance(error, InstantiationException) and error.__cause__ is not None:
        key = getattr(error, "full_key", None)
        return (f"{key}: " if key else "") + str(error.__cause__).splitlines()[0]
    if isinstance(error, OmegaConfBaseException):
        first = str(error).splitlines()[0]
        key = getattr(error, "full_key", None)
        return f"{first} (set it on the command line: {key}=...)" if isinstance(error, MissingMandatoryValue) \
            else first
    return " ".join(str(error).split("\n"))


def _raise_interrupted(signum, frame) -> None:
    """SIGINT and SIGTERM raise KeyboardInterrupt naming the signal, so that every ``finally`` runs and whatever
    handles an interruption (a recording session marks its files unfinished) handles both."""
    raise KeyboardInterrupt(signal.Signals(signum).name)


def _signal_number(stop: KeyboardInterrupt) -> signal.Signals:
    """The signal that ``stop`` stands for: the one it names, else SIGINT."""
    name = stop.args[0] if stop.args and isinstance(stop.args[0], str) else ""
    return signal.Signals[name] if name in signal.Signals.__members__ else signal.SIGINT


def _remove_empty_run_dir() -> None:
    """Remove the run directory Hydra made for this job when the job wrote nothing into it."""
    try:
        run_dir = Path(HydraConfig.get().runtime.output_dir)
    except ValueError:  # no Hydra config: not inside a job
        return
    if run_dir.resolve() != Path.cwd().resolve() and run_dir.is_dir() and not any(run_dir.iterdir()):
        run_dir.rmdir()


def _one_line_warnings(name: str) -> Callable:
    """A ``warnings.showwarning`` that prints the project's own warnings as ``<name>: warning: <message>`` in one
    line (where in diffstir's code they were raised says nothing to a user) and others as Python does."""
    package = str(Path(__file__).resolve().parents[1])
    shown = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        if str(Path(filename).resolve()).startswith(package):
            print(f"{name}: warning: {' '.join(str(message).split())}", file=file or sys.stderr, flush=True)
        else:
            shown(message, category, filename, lineno, file, line)

    return show


def command(name: str, config_name: str) -> Callable[[Callable[[DictConfig], None]], Callable[[], None]]:
    """Decorate an app's task function ``task(cfg)`` into the console entry point ``name`` (e.g. ``diffstir-fit``)
    composed from ``conf/<config_name>.yaml``; see the module docstring."""

    def decorate(task: Callable[[DictConfig], None]) -> Callable[[], None]:
        @functools.wraps(task)
        def guarded(cfg: DictConfig) -> None:
            try:
                return task(cfg)
            except (DiffstirError, OmegaConfBaseException, InstantiationException) as error:
                if os.environ.get("HYDRA_FULL_ERROR") == "1":
                    raise
                print(f"{name}: error: {one_line(error)}", file=sys.stderr, flush=True)
                Run.discard_empty()
                sys.exit(2)
            finally:
                _remove_empty_run_dir()

        hydra_main = hydra.main(config_path=CONF_DIR, config_name=config_name, version_base="1.3")(guarded)

        def main() -> None:
            if any(arg in ("-h", "--help") for arg in sys.argv[1:]):
                print(help_page(name, config_name, task.__module__))
                return
            Run.out, Run.kept, Run.made = None, (), False
            check_overrides(name, config_name, sys.argv[1:])
            if not OmegaConf.has_resolver("run_folder"):
                OmegaConf.register_new_resolver("run_folder", run_folder)
            handlers = {sig: signal.signal(sig, _raise_interrupted) for sig in (signal.SIGINT, signal.SIGTERM)}
            warnings.showwarning = _one_line_warnings(name)
            try:
                hydra_main()
            except KeyboardInterrupt as stop:
                sig = _signal_number(stop)
                print(f"{name}: interrupted ({sig.name}); {Run.kept_line()}", file=sys.stderr, flush=True)
                sys.exit(128 + sig)
            finally:
                for sig, handler in handlers.items():
                    signal.signal(sig, handler)

        return main

    return decorate


def check_overrides(name: str, config_name: str, args: list[str]) -> None:
    """Compose ``conf/<config_name>.yaml`` with the command line's overrides ``args``, so that a misspelt key, an
    unknown option of a config group or a malformed override is refused in one line with exit status 2 before Hydra
    starts (with ``-m`` or Hydra's own flags, or ``HYDRA_FULL_ERROR=1``, Hydra reports them itself)."""
    if any(arg.startswith("-") for arg in args) or os.environ.get("HYDRA_FULL_ERROR") == "1":
        return
    from hydra import compose, initialize_config_dir
    from hydra.errors import HydraException

    try:
        with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
            compose(config_name, overrides=args)
    except (HydraException, OmegaConfBaseException) as error:
        parts: list[str] = []
        for line in str(error).split("Config search path:")[0].splitlines():
            if line.startswith("\t") and parts:
                parts[-1] += (" " if parts[-1].endswith(":") else ", ") + line.strip()
            elif line.strip() and not line.strip().startswith(("full_key:", "object_type=", "See https://")):
                parts.append(line.strip())
        cause = str(error.__cause__).splitlines()[0] if error.__cause__ is not None else ""
        print(f"{name}: error: {' '.join(parts)}{': ' + cause if cause else ''}", file=sys.stderr, flush=True)
        sys.exit(2)


def help_page(name: str, config_name: str, module: str) -> str:
    """``name --help``: a usage line, the app's examples (its module docstring), its options with their comments
    (``conf/<config_name>.yaml``, and the default of a config group that it merges at its top level, ``# @package
    _global_``) and the options of the config groups it composes."""
    text = (Path(CONF_DIR) / f"{config_name}.yaml").read_text(encoding="utf-8")
    options = re.sub(r"^  - override hydra/.*\n", "", text.split("\nhydra:")[0], flags=re.M).rstrip()
    for group, option in re.findall(r"^  - (\w+): (\w+)", text, flags=re.M):
        merged = Path(CONF_DIR) / group / f"{option}.yaml"
        body = merged.read_text(encoding="utf-8") if merged.is_file() else ""
        if body.startswith("# @package _global_\n"):
            options += f"\n\n# conf/{group}/{option}.yaml:\n" + body.split("\n", 1)[1].rstrip()
    groups = []
    for line in re.findall(r"^  - (?!_self_|override )(\S+?):", text, flags=re.M):
        group, _, package = line.partition("@")
        folder = Path(CONF_DIR) / group
        if folder.is_dir():
            choices = sorted(p.stem for p in folder.glob("*.yaml"))
            label = f"{package} ({group} options)" if package else group
            groups.append(f"  {label:<26} {', '.join(choices)}")
    doc = (sys.modules[module].__doc__ or "").strip()
    parts = [f"usage: {name} [key=value ...] [group=option ...]   (Hydra overrides; -m: a sweep)", "",
             doc, "", "Options (conf/" + config_name + ".yaml; set any key on the command line, "
             "~key removes it):", "", options]
    if groups:
        parts += ["", "Config groups (group=option):", *groups]
    parts += ["", "Exit status: 0 done; 2 a recording, setting or output folder refused (one line on stderr,",
              "HYDRA_FULL_ERROR=1 for the traceback); 130 / 143 interrupted by SIGINT / SIGTERM (what was written",
              "is kept). Hydra's own options: --hydra-help."]
    return "\n".join(parts)
