"""Import the DiffStir authors' recordings (Xu, Zheng et al., the paper diffstir follows) into the recording format.

Their repository holds one stir as three files (docs/recording-format.md, Importing the DiffStir authors'
recordings):

    data/traj.npy            N x 3 float64 rod positions [m], one row per sample at 1 kHz, the rod circling the
                             cup's axis in a frame the files do not describe
    data/force.npy           N float64 readings of a one-sided thin-film sensor [N], zero until the sensor wakes
    config/arguments.json    scene_information: container_diameter, liquid_height, operator_bottom_height,
                             operator_radius [m]; liquid_density [kg/m³]

The mapping: cup radius = container_diameter / 2, fill height = liquid_height, immersion depth = liquid_height −
operator_bottom_height, rod radius = operator_radius, t_i = i / f_s. The vertical column of traj.npy is the one
that varies least (it must vary less than a quarter of each other one); the other two, in cyclic order after it,
are x and y. The cup's axis is the centre of the least-squares circle through the (x, y) path (Kåsa's fit:
x² + y² = 2 a x + 2 b y + c, linear in a, b, c), and the positions are written relative to it. The files state no
density measurement (only a density value, kept as the recording's ``density_stated`` [kg/m³]) and neither the
sensor's mode nor its axis: they are settings.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from diffstir.errors import ConfigError, OutputError, is_number
from diffstir.recording.errors import RecordingError
from diffstir.recording.files import save_recording
from diffstir.recording.format import SENSOR_MODES, CupGeometry, Recording, RodGeometry, SensorSpec
from diffstir.recording.validate import validate_recording

TRAJ = Path("data") / "traj.npy"
FORCE = Path("data") / "force.npy"
ARGUMENTS = Path("config") / "arguments.json"
SCENE_LENGTHS = ("container_diameter", "liquid_height", "operator_bottom_height", "operator_radius")
DENSITY_RANGE = (400.0, 3000.0)  # kg/m³: liquids a stirring rig meets
MAX_LENGTH = 1.0  # m: a length above this is taken for millimetres
MAX_FORCE = 50.0  # N: a thin-film reading above this is taken for mN or grams
VERTICAL_SHARE = 0.25  # the vertical column's range, at most this share of each horizontal column's range
WAKE_LEVEL = 1e-9  # N: a reading above this is the sensor awake


@dataclass(frozen=True)
class ImportSettings:
    """What the authors' files do not state: ``sample_rate`` f_s [Hz] of traj.npy and force.npy, the sensor's
    ``mode`` (component | tangential | magnitude), its ``axis`` (horizontal unit vector in the imported frame,
    component mode only) and whether it is ``one_sided``."""

    sample_rate: float = 1000.0
    mode: str = "tangential"
    axis: tuple[float, float] | None = None
    one_sided: bool = True

    def __post_init__(self) -> None:
        if not (is_number(self.sample_rate) and self.sample_rate > 0):
            raise ConfigError(f"sample_rate = {self.sample_rate!r}; expected a positive rate in Hz")
        if self.mode not in SENSOR_MODES:
            raise ConfigError(f"sensor.mode = {self.mode!r}; expected one of {', '.join(SENSOR_MODES)}")
        if self.mode == "component" and self.axis is None:
            raise ConfigError("sensor.axis is null; mode component needs a horizontal unit vector [1, 1]")


@dataclass
class Imported:
    """An imported recording and what the import inferred: the ``vertical_column`` of traj.npy (0, 1 or 2), the
    cup axis' ``centre`` [m] in traj.npy's horizontal columns, the fitted circle's ``radius`` [m] and the rms
    distance of the path from it, ``circle_rms`` [m], the stated ``density`` [kg/m³] and ``dead_start`` [s], how
    long the sensor reads 0 from the first sample."""

    recording: Recording
    vertical_column: int
    centre: tuple[float, float]
    radius: float
    circle_rms: float
    density: float
    dead_start: float


def fit_circle(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float, float]:
    """The least-squares circle through the points (``x``, ``y``) [m] (Kåsa): its centre (a, b) [m], radius [m]
    and the rms distance of the points from it [m]."""
    design = np.stack([2.0 * x, 2.0 * y, np.ones_like(x)], axis=1)
    (a, b, c), *_ = np.linalg.lstsq(design, x * x + y * y, rcond=None)
    radius = math.sqrt(max(c + a * a + b * b, 0.0))
    rms = float(np.sqrt(np.mean((np.hypot(x - a, y - b) - radius) ** 2)))
    return float(a), float(b), radius, rms


def _load_array(path: Path) -> np.ndarray:
    if not path.is_file():
        raise RecordingError(f"{path}: not found; expected the DiffStir authors' layout (data/traj.npy, "
                             f"data/force.npy, config/arguments.json)")
    try:
        array = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as error:
        raise RecordingError(f"{path}: not a numpy array file ({error})") from None
    if not np.issubdtype(array.dtype, np.number):
        raise RecordingError(f"{path}: holds {array.dtype} values; expected float64 (m or N)")
    return np.asarray(array, dtype=np.float64)


def _check_finite(path: Path, array: np.ndarray, unit: str) -> None:
    bad = np.flatnonzero(~np.isfinite(array.reshape(array.shape[0], -1)).all(axis=1))
    if bad.size:
        raise RecordingError(f"{path}: row {bad[0]} (of {array.shape[0]}, counted from 0) holds a non-finite "
                             f"value ({bad.size} such rows); expected finite numbers in {unit}")


def _scene(path: Path) -> tuple[dict[str, float], float]:
    """The scene's lengths [m] and the stated liquid density [kg/m³] from config/arguments.json."""
    if not path.is_file():
        raise RecordingError(f"{path}: not found; expected the scene's geometry in scene_information")
    try:
        args = json.loads(path.read_text(encoding="utf-8-sig"))
    except (ValueError, UnicodeDecodeError) as error:
        raise RecordingError(f"{path}: not JSON ({error})") from None
    scene = args.get("scene_information") if isinstance(args, dict) else None
    if not isinstance(scene, dict):
        raise RecordingError(f"{path}: no scene_information object; expected container_diameter, liquid_height, "
                             f"operator_bottom_height, operator_radius [m] and liquid_density [kg/m^3]")
    values = {}
    for field, unit in [(f, "m") for f in SCENE_LENGTHS] + [("liquid_density", "kg/m^3")]:
        value = scene.get(field)
        if not is_number(value):
            raise RecordingError(f"{path}: scene_information.{field} = {value!r}; expected a finite number in "
                                 f"{unit}")
        values[field] = float(value)
    for field in SCENE_LENGTHS:
        value = values[field]
        if field != "operator_bottom_height" and value <= 0:
            raise RecordingError(f"{path}: scene_information.{field} = {value!r}; expected a length > 0 in m")
        if value > MAX_LENGTH:
            raise RecordingError(f"{path}: scene_information.{field} = {value!r}; expected m (in mm? "
                                 f"{value / 1000:g} m)")
    density = values.pop("liquid_density")
    if not DENSITY_RANGE[0] <= density <= DENSITY_RANGE[1]:
        hint = " (in g/cm^3?)" if 0 < density < 10 else ""
        raise RecordingError(f"{path}: scene_information.liquid_density = {density!r}; expected kg/m^3 within "
                             f"{DENSITY_RANGE[0]:g}-{DENSITY_RANGE[1]:g}{hint}")
    if values["operator_bottom_height"] >= values["liquid_height"]:
        raise RecordingError(f"{path}: scene_information.operator_bottom_height = "
                             f"{values['operator_bottom_height']!r} m is not below liquid_height = "
                             f"{values['liquid_height']!r} m; the rod's tip must be immersed")
    return values, density


def read_diffstir_authors(source: str | Path, settings: ImportSettings | None = None) -> Imported:
    """The recording in the DiffStir authors' folder ``source`` (module docstring), validated; nothing is written.
    Raises RecordingError naming the file, field and unit of the first problem."""
    settings = settings or ImportSettings()
    source = Path(source)
    if not source.is_dir():
        raise RecordingError(f"{source}: not a directory; expected the DiffStir authors' layout (data/traj.npy, "
                             f"data/force.npy, config/arguments.json)")
    traj_path, force_path = source / TRAJ, source / FORCE
    traj, force = _load_array(traj_path), _load_array(force_path)
    if traj.ndim != 2 or traj.shape[1] != 3:
        raise RecordingError(f"{traj_path}: shape {traj.shape}; expected (N, 3) rod positions in m")
    if force.ndim == 2 and force.shape[1] == 1:
        force = force[:, 0]
    if force.ndim != 1:
        raise RecordingError(f"{force_path}: shape {force.shape}; expected (N,) readings in N")
    if force.shape[0] != traj.shape[0]:
        raise RecordingError(f"{force_path}: {force.shape[0]} readings against {traj.shape[0]} rows of "
                             f"{traj_path}; expected one reading per position, both at {settings.sample_rate:g} Hz")
    _check_finite(traj_path, traj, "m")
    _check_finite(force_path, force, "N")
    if traj.shape[0] < 3:
        raise RecordingError(f"{traj_path}: {traj.shape[0]} rows; expected a stir of many samples")
    big = np.abs(traj).max()
    if big > MAX_LENGTH:
        raise RecordingError(f"{traj_path}: a position of {big:g}; expected m (in mm?)")
    if np.abs(force).max() > MAX_FORCE:
        raise RecordingError(f"{force_path}: a reading of {np.abs(force).max():g}; expected N from a thin-film "
                             f"sensor (below {MAX_FORCE:g} N; in mN or grams?)")
    scene, density = _scene(source / ARGUMENTS)

    spans = np.ptp(traj, axis=0)
    vertical = int(np.argmin(spans))
    horizontal = [(vertical + 1) % 3, (vertical + 2) % 3]
    if spans[vertical] > VERTICAL_SHARE * spans[horizontal].min():
        raise RecordingError(f"{traj_path}: no column stays level (ranges {', '.join(f'{s:.3g}' for s in spans)} "
                             f"m); expected one vertical column that varies less than {VERTICAL_SHARE:g} of the "
                             f"others (the rod circles in a horizontal plane)")
    x, y = traj[:, horizontal[0]], traj[:, horizontal[1]]
    a, b, radius, rms = fit_circle(x, y)
    t = np.arange(traj.shape[0]) / settings.sample_rate
    awake = np.flatnonzero(np.abs(force) > WAKE_LEVEL)
    dead_start = float(t[awake[0]]) if awake.size else float(t[-1])
    cup = CupGeometry(radius=scene["container_diameter"] / 2.0, fill_height=scene["liquid_height"])
    rod = RodGeometry(radius=scene["operator_radius"],
                      immersion_depth=scene["liquid_height"] - scene["operator_bottom_height"])
    sensor = SensorSpec(mode=settings.mode, axis=tuple(settings.axis) if settings.mode == "component" else None,
                        one_sided=bool(settings.one_sided), sample_rate=float(settings.sample_rate))
    recording = Recording(cup=cup, rod=rod, sensor=sensor, density=None, t=t, x=x - a, y=y - b, force=force,
                          name=source.resolve().name,
                          extra_meta={"density_stated": density,
                                      "imported_from": {"layout": "diffstir-authors", "source": str(source),
                                                        "vertical_column": vertical,
                                                        "circle_centre": [a, b], "circle_radius": radius,
                                                        "circle_rms": rms}})
    validate_recording(recording)
    return Imported(recording, vertical, (a, b), radius, rms, density, dead_start)


def import_diffstir_authors(source: str | Path, out: str | Path, settings: ImportSettings | None = None, *,
                            overwrite: bool = False) -> Imported:
    """Read the DiffStir authors' folder ``source`` and write it as the recording directory ``out``. An existing
    ``out`` raises OutputError unless ``overwrite`` (then only a recording directory is replaced); a refused
    import writes nothing."""
    out = Path(out)
    if (out.exists() or out.is_symlink()) and not overwrite:
        raise OutputError(f"{out}: already exists; pass overwrite=true to replace it")
    imported = read_diffstir_authors(source, settings)
    try:
        save_recording(imported.recording, out, overwrite=overwrite)
    except FileExistsError as error:
        raise OutputError(str(error)) from None
    imported.recording.path = out
    return imported
