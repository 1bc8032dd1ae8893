"""Reading and writing recording directories (recording.yaml + stir.csv), atomically and without overwriting."""

from __future__ import annotations

import codecs
import csv
import decimal
import difflib
import io
import math
import os
import re
import secrets
import shutil
import sys
import warnings
from pathlib import Path

import numpy as np
import yaml

from diffstir.recording.errors import RecordingError, RecordingNotFound, RecordingWarning
from diffstir.recording.format import (
    COLUMN_UNITS, CSV_NAME, FORMAT, OPTIONAL_COLUMNS, REQUIRED_COLUMNS, YAML_NAME, CupGeometry,
    DensityMeasurement, Recording, RodGeometry, SensorSpec,
)
from diffstir.recording.plausibility import check_plausibility
from diffstir.recording.validate import check_columns_shape, validate_recording

# Fields this version interprets, by their path in recording.yaml; anything else is kept in extra_meta.
_KNOWN_FIELDS = {
    (): {"format", "name", "fluid", "temperature", "complete", "partial_reason", "rig", "sensor", "density"},
    ("rig",): {"cup", "rod"},
    ("rig", "cup"): {"radius", "fill_height", "fill_volume"},
    ("rig", "rod"): {"radius", "immersion_depth"},
    ("sensor",): {"mode", "axis", "one_sided", "resolution", "sample_rate", "time_constant", "noise"},
    ("density",): {"rod_weight", "immersed_reading", "immersed_depth", "rod_cross_section"},
}


_PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__)) + os.sep


def warn(message: str) -> None:
    """Emit a RecordingWarning attributed to the first caller outside this package."""
    frame, level = sys._getframe(0), 1
    while frame is not None and frame.f_code.co_filename.startswith(_PACKAGE_DIR):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, RecordingWarning, stacklevel=level)


def fresh_dir(parent: Path, stem: str, suffix: str) -> Path:
    """Create and return a new, hidden, uniquely named directory in ``parent`` (permissions from the umask)."""
    while True:
        path = parent / f".{stem}.{os.getpid()}.{secrets.token_hex(4)}{suffix}"
        try:
            path.mkdir()
            return path
        except FileExistsError:
            continue


# ---------------------------------------------------------------------------------------------------------------
# recording.yaml
# ---------------------------------------------------------------------------------------------------------------

def _get(block: dict, path: tuple[str, ...], key: str, where: str, unit: str, *, required: bool) -> float | None:
    """The number at ``path.key`` as float; strings such as '1e-3' (which YAML 1.1 reads as text) are parsed."""
    dotted = ".".join(path + (key,))
    value = block.get(key)
    if value is None:
        if required:
            raise RecordingError(f"{where}: required field '{dotted}' is missing; expected a number in {unit}")
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise RecordingError(f"{where}: field '{dotted}' = {value!r} is not a number; expected {unit}")
    try:
        return float(value)
    except ValueError:
        raise RecordingError(f"{where}: field '{dotted}' = {value!r} is not a number; expected {unit} "
                             f"(write the bare SI value, without a unit)") from None


def _block(parent: dict, path: tuple[str, ...], where: str, *, required: bool) -> dict | None:
    value = parent.get(path[-1])
    if value is None:
        if required:
            raise RecordingError(f"{where}: required section '{'.'.join(path)}' is missing")
        return None
    if not isinstance(value, dict):
        raise RecordingError(f"{where}: '{'.'.join(path)}' = {value!r} must be a mapping of fields")
    return value


def _unknown_fields(meta: dict) -> tuple[dict, list[str]]:
    """Fields not in _KNOWN_FIELDS, as a dict nested like the yaml, and their dotted names."""
    extra: dict = {}
    names: list[str] = []

    def walk(block: dict, path: tuple[str, ...]) -> None:
        for key, value in block.items():
            key_path = path + (str(key),)
            if str(key) not in _KNOWN_FIELDS[path]:
                node = extra
                for part in path:
                    node = node.setdefault(part, {})
                node[str(key)] = value
                names.append(".".join(key_path))
            elif key_path in _KNOWN_FIELDS and isinstance(value, dict):
                walk(value, key_path)

    walk(meta, ())
    return extra, names


def parse_metadata(meta: object, where: str) -> dict:
    """Keyword arguments of Recording (all but the columns and path) from the parsed recording.yaml."""
    if not isinstance(meta, dict):
        raise RecordingError(f"{where}: expected a mapping of fields at the top level, got {type(meta).__name__}")
    fmt = meta.get("format")
    if fmt is None:
        raise RecordingError(f"{where}: required field 'format' is missing; expected format: {FORMAT}")
    if fmt != FORMAT:
        raise RecordingError(f"{where}: field 'format' = {fmt!r}; this reader understands exactly {FORMAT!r}")

    rig = _block(meta, ("rig",), where, required=True)
    cup_d = _block(rig, ("rig", "cup"), where, required=True)
    rod_d = _block(rig, ("rig", "rod"), where, required=True)
    cup = CupGeometry(
        radius=_get(cup_d, ("rig", "cup"), "radius", where, "m", required=True),
        fill_height=_get(cup_d, ("rig", "cup"), "fill_height", where, "m", required=False),
        fill_volume=_get(cup_d, ("rig", "cup"), "fill_volume", where, "m^3", required=False),
    )
    if cup.fill_height is None and cup.fill_volume is None:
        raise RecordingError(f"{where}: required field 'rig.cup.fill_height' (m) or 'rig.cup.fill_volume' (m^3) "
                             f"is missing; give one of them")
    rod = RodGeometry(
        radius=_get(rod_d, ("rig", "rod"), "radius", where, "m", required=True),
        immersion_depth=_get(rod_d, ("rig", "rod"), "immersion_depth", where, "m", required=True),
    )

    sensor_d = _block(meta, ("sensor",), where, required=True)
    if "mode" not in sensor_d:
        raise RecordingError(f"{where}: required field 'sensor.mode' is missing; expected component, tangential "
                             f"or magnitude")
    axis = sensor_d.get("axis")
    if axis is not None:
        if not isinstance(axis, (list, tuple)) or len(axis) != 2:
            raise RecordingError(f"{where}: field 'sensor.axis' = {axis!r}; expected two numbers [ax, ay], "
                                 f"a horizontal unit vector (dimensionless)")
        axis = tuple(_get({"axis": a}, ("sensor",), "axis", where, "a dimensionless unit-vector component",
                          required=True) for a in axis)
    one_sided = sensor_d.get("one_sided", False)
    if not isinstance(one_sided, bool):
        raise RecordingError(f"{where}: field 'sensor.one_sided' = {one_sided!r}; expected true or false")
    sensor = SensorSpec(
        mode=str(sensor_d["mode"]), axis=axis, one_sided=one_sided,
        resolution=_get(sensor_d, ("sensor",), "resolution", where, "N", required=False),
        sample_rate=_get(sensor_d, ("sensor",), "sample_rate", where, "Hz", required=False),
        time_constant=_get(sensor_d, ("sensor",), "time_constant", where, "s", required=False),
        noise=_get(sensor_d, ("sensor",), "noise", where, "N (1 sigma)", required=False),
    )

    density = None
    density_d = _block(meta, ("density",), where, required=False)
    if density_d is not None:
        def readings(key: str) -> float | list[float]:  # one reading, or a list of repeated readings [N]
            value = density_d.get(key)
            if not isinstance(value, list):
                return _get(density_d, ("density",), key, where, "N", required=True)
            if not value:
                raise RecordingError(f"{where}: field 'density.{key}' = []; expected a force in N or a list of "
                                     f"repeated readings in N")
            return [_get({key: v}, ("density",), key, where, "N (each repeated reading)", required=True)
                    for v in value]

        density = DensityMeasurement.of_readings(
            rod_weight=readings("rod_weight"), immersed_reading=readings("immersed_reading"),
            immersed_depth=_get(density_d, ("density",), "immersed_depth", where, "m", required=True),
            rod_cross_section=_get(density_d, ("density",), "rod_cross_section", where, "m^2", required=False),
        )

    complete = meta.get("complete", True)
    if not isinstance(complete, bool):
        raise RecordingError(f"{where}: field 'complete' = {complete!r}; expected true or false")
    partial_reason = meta.get("partial_reason")
    extra_meta, unknown = _unknown_fields(meta)
    if unknown:
        warn(f"{where}: unknown fields kept in extra_meta but not interpreted: {', '.join(unknown)}")
    return dict(
        cup=cup, rod=rod, sensor=sensor, density=density,
        name=None if meta.get("name") is None else str(meta["name"]),
        fluid=None if meta.get("fluid") is None else str(meta["fluid"]),
        temperature=_get(meta, (), "temperature", where, "degrees Celsius", required=False),
        complete=complete, partial_reason=None if partial_reason is None else str(partial_reason),
        extra_meta=extra_meta,
    )


def metadata_dict(*, cup: CupGeometry, rod: RodGeometry, sensor: SensorSpec, density: DensityMeasurement | None,
                  name: str | None, fluid: str | None, temperature: float | None, complete: bool,
                  partial_reason: str | None, extra_meta: dict, where: str) -> dict:
    """recording.yaml as a dict, in the spec's order, with ``extra_meta`` merged back in."""
    def numbers(**kv) -> dict:
        return {k: float(v) for k, v in kv.items() if v is not None}

    meta: dict = {"format": FORMAT}
    meta.update({k: v for k, v in (("name", name), ("fluid", fluid)) if v is not None})
    meta.update(numbers(temperature=temperature))
    meta["complete"] = bool(complete)
    if partial_reason is not None:
        meta["partial_reason"] = str(partial_reason)
    meta["rig"] = {
        "cup": numbers(radius=cup.radius, fill_height=cup.fill_height, fill_volume=cup.fill_volume),
        "rod": numbers(radius=rod.radius, immersion_depth=rod.immersion_depth),
    }
    meta["sensor"] = {"mode": sensor.mode}
    if sensor.axis is not None:
        meta["sensor"]["axis"] = [float(a) for a in sensor.axis]
    meta["sensor"]["one_sided"] = bool(sensor.one_sided)
    meta["sensor"].update(numbers(resolution=sensor.resolution, sample_rate=sensor.sample_rate,
                                  time_constant=sensor.time_constant, noise=sensor.noise))
    if density is not None:
        meta["density"] = numbers(
            rod_weight=density.rod_weight, immersed_reading=density.immersed_reading,
            immersed_depth=density.immersed_depth, rod_cross_section=density.rod_cross_section)
        for key, repeated in (("rod_weight", density.rod_weight_readings),
                              ("immersed_reading", density.immersed_readings)):
            if repeated is not None:
                meta["density"][key] = [float(v) for v in repeated]
    _merge(meta, extra_meta, (), where)
    return meta


def _merge(meta: dict, extra: dict, path: tuple[str, ...], where: str) -> None:
    for key, value in extra.items():
        key_path = path + (key,)
        if key_path in _KNOWN_FIELDS and key not in meta:
            raise RecordingError(f"{where}: extra_meta holds fields under '{'.'.join(key_path)}', a section this "
                                 f"recording does not have; they would make an invalid section")
        if key in meta:
            if isinstance(meta[key], dict) and isinstance(value, dict) and key_path in _KNOWN_FIELDS:
                _merge(meta[key], value, key_path, where)
                continue
            raise RecordingError(f"{where}: extra_meta field '{'.'.join(key_path)}' collides with a field of the "
                                 f"format; set it through the Recording's own attribute")
        meta[key] = value


def write_metadata(directory: Path, meta: dict) -> None:
    """Write recording.yaml atomically: temp file, fsync, os.replace, fsync of the directory."""
    tmp = directory / f".{YAML_NAME}.tmp"
    with open(tmp, "w", encoding="utf-8") as f:
        yaml.safe_dump(meta, f, sort_keys=False, default_flow_style=None, allow_unicode=True)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, directory / YAML_NAME)
    fsync_dir(directory)


def fsync_dir(directory: Path) -> None:
    """Make a rename or a new file in ``directory`` durable."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


# ---------------------------------------------------------------------------------------------------------------
# stir.csv
# ---------------------------------------------------------------------------------------------------------------

def format_value(value) -> str:
    """Shortest text that reads back to the same float64 ('0.03', '1e-05', '123'); strings pass through."""
    if isinstance(value, str):
        return value
    text = repr(float(value))
    return text[:-2] if text.endswith(".0") else text


def csv_header(names: list[str]) -> str:
    """A units comment and the header line of stir.csv."""
    units = ", ".join(f"{n} [{COLUMN_UNITS[n]}]" for n in names if n in COLUMN_UNITS)
    return f"# {FORMAT} stir.csv; units: {units}\n{','.join(names)}\n"


def read_text(path: Path) -> str:
    """The text of ``path`` as UTF-8, without a byte-order mark (Excel's "CSV UTF-8" writes one), with CRLF and
    CR line ends read as LF. Raises FileNotFoundError, and RecordingError naming the file for any other encoding."""
    data = path.read_bytes()
    if data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)) or b"\x00" in data[:4096]:
        raise RecordingError(f"{path}: UTF-16 or binary text (NUL bytes); expected UTF-8 text (in Excel: "
                             f"save as 'CSV UTF-8')")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise RecordingError(f"{path} line {line}: byte 0x{data[exc.start]:02x} is not UTF-8 (Latin-1 or another "
                             f"code page?); expected UTF-8 text (save the file as UTF-8)") from None
    return text.replace("\r\n", "\n").replace("\r", "\n")


def relative_times(values: list[str], lines: list[int], where: str) -> tuple[np.ndarray, float]:
    """Times [s] counted from the first, t_i - t_0 in float64, and the origin t_0 [s], from their text.

    The difference is taken in decimal arithmetic on the text, so a clock that reads 1.7e9 s keeps the
    resolution its text carries (float64 holds 1.7e9 only to 2.4e-7 s). Non-finite text gives nan or inf at
    its row (``validate_recording`` names it)."""
    times = _to_float(values, "t", lines, where)
    if not times.size or not np.isfinite(times[0]):
        return times, 0.0
    with decimal.localcontext(decimal.Context(prec=60)):
        first = decimal.Decimal(values[0])
        relative = np.array([float(decimal.Decimal(v) - first) if math.isfinite(t) else t
                             for v, t in zip(values, times)], dtype=np.float64)
    return relative, float(times[0])


def absolute_times(t: np.ndarray, origin: float) -> list[str] | np.ndarray:
    """The text of origin + t [s], summed in decimal arithmetic on each value's shortest text: the inverse of
    ``relative_times`` (``t`` unchanged when ``origin`` is 0)."""
    if origin == 0.0:
        return t
    with decimal.localcontext(decimal.Context(prec=60)):
        base = decimal.Decimal(repr(float(origin)))
        return [format_value(str(base + decimal.Decimal(repr(float(v))))) if math.isfinite(v) else repr(float(v))
                for v in t]


def _to_float(values: list[str], column: str, lines: list[int], where: str) -> np.ndarray:
    try:
        return np.array([float(v) for v in values], dtype=np.float64)
    except ValueError:
        for value, line in zip(values, lines):
            try:
                float(value)
            except ValueError:
                raise RecordingError(
                    f"{where} line {line}: column '{column}' = {value!r} is not a number; "
                    f"expected {COLUMN_UNITS.get(column, 'a number')}") from None
        raise


def read_csv(path: Path, *, partial: bool) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], float]:
    """Known and unknown columns of stir.csv, each in file order, and the time origin [s]: column ``t`` counts
    from its first value (``relative_times``), which is returned as the origin.

    The text is UTF-8, with or without a byte-order mark, with LF, CRLF or CR line ends (``read_text``).
    Lines whose first non-blank character is '#' are comments; blank lines are skipped. The last line is
    dropped, with a warning, when it has no final newline and either the recording is partial or the line
    does not parse (a write cut short by a crash).
    """
    where = str(path)
    try:
        text = read_text(path)
    except FileNotFoundError:
        raise RecordingError(f"{where}: missing; a recording directory needs {YAML_NAME} and {CSV_NAME}") from None
    lines = [(n + 1, line) for n, line in enumerate(text.split("\n"))
             if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        raise RecordingError(f"{where}: no header line; expected the columns {', '.join(REQUIRED_COLUMNS)}")
    unterminated = not text.endswith("\n")
    (header_line, header_text), data = lines[0], lines[1:]
    header = [_column_name(h.strip(), where, header_line) for h in next(csv.reader([header_text]))]
    for column in header:
        if not column or header.count(column) > 1:
            raise RecordingError(f"{where} line {header_line}: column name {column!r} is empty or repeated in "
                                 f"the header {header_text!r}")
    for separator, name in ((";", "semicolons"), ("\t", "tabs")):
        if len(header) == 1 and separator in header_text:
            raise RecordingError(f"{where} line {header_line}: the header {header_text!r} is separated by {name}; "
                                 f"expected commas: t,x,y,force (s, m, m, N) with '.' as the decimal point")
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        unknown_names = {h.lower(): h for h in header if h not in REQUIRED_COLUMNS and h not in OPTIONAL_COLUMNS}
        hints = [f"{unknown_names[close[0]]!r} for {c!r}?" for c in missing
                 for close in [difflib.get_close_matches(c, list(unknown_names), n=1, cutoff=0.5)] if close]
        hint = f" (misspelt: {', '.join(hints)})" if hints else ""
        raise RecordingError(f"{where}: required column(s) {', '.join(repr(c) for c in missing)} missing from the "
                             f"header {header_text!r}{hint}; expected t [s], x [m], y [m], force [N] in any order")

    rows = [[v.strip() for v in row] for row in csv.reader([line for _, line in data])]
    numbers = [line for line, _ in data]
    if rows and unterminated and (partial or not _parses(rows[-1], header)):
        warn(f"{where} line {numbers[-1]}: dropped the last line {data[-1][1]!r}, cut short by an interrupted "
             f"write (no final newline)")
        rows, numbers = rows[:-1], numbers[:-1]
    for row, line in zip(rows, numbers):
        if len(row) != len(header):
            comma = " (a decimal comma? expected '.' as the decimal point)" if len(row) > len(header) else ""
            raise RecordingError(f"{where} line {line}: {len(row)} values for the {len(header)} columns "
                                 f"{', '.join(header)}{comma}; expected numbers in "
                                 f"{', '.join(f'{h} [{COLUMN_UNITS[h]}]' for h in header if h in COLUMN_UNITS)}")

    values = list(zip(*rows)) if rows else [()] * len(header)
    known, unknown, origin = {}, {}, 0.0
    for column, column_values in zip(header, values):
        if column == "t":
            known[column], origin = relative_times(list(column_values), numbers, where)
        elif column in REQUIRED_COLUMNS or column in OPTIONAL_COLUMNS:
            known[column] = _to_float(list(column_values), column, numbers, where)
        else:
            try:
                unknown[column] = np.array([float(v) for v in column_values], dtype=np.float64)
            except ValueError:
                unknown[column] = np.array(column_values, dtype=str)
    if unknown:
        warn(f"{where}: unknown columns kept in extra_columns but not interpreted: {', '.join(unknown)}")
    return known, unknown, origin


_NAME_WITH_UNIT = re.compile(r"^(\w+)\s*[\[(]\s*([^\])]*?)\s*[\])]$")


def _column_name(text: str, where: str, line: int) -> str:
    """A header cell's column name: 'force [N]' or 'force (N)' is 'force' when the unit is the column's SI unit;
    another unit for a known column is refused."""
    match = _NAME_WITH_UNIT.match(text)
    if match is None or match[1] not in COLUMN_UNITS:
        return text
    name, unit = match[1], match[2]
    if unit != COLUMN_UNITS[name]:
        raise RecordingError(f"{where} line {line}: column {text!r} is in {unit!r}; expected {name} in "
                             f"{COLUMN_UNITS[name]} (convert the values, or name the column {name})")
    return name


def _parses(row: list[str], header: list[str]) -> bool:
    if len(row) != len(header):
        return False
    try:
        [float(v) for v, h in zip(row, header) if h in REQUIRED_COLUMNS or h in OPTIONAL_COLUMNS]
    except ValueError:
        return False
    return True


# ---------------------------------------------------------------------------------------------------------------
# Recording directories
# ---------------------------------------------------------------------------------------------------------------

def _recording_dir(path: str | Path) -> Path:
    path = Path(path)
    if path.name in (YAML_NAME, CSV_NAME) and path.is_file():
        path = path.parent
    if not path.is_dir():
        raise RecordingNotFound(f"{path}: no such recording directory; expected a directory with {YAML_NAME} and "
                                f"{CSV_NAME}")
    return path


def load_recording(path: str | Path, *, validate: bool = True) -> Recording:
    """Read the recording directory ``path`` (or its recording.yaml / stir.csv).

    Column ``t`` counts from the first sample (t[0] = 0); the clock's reading there is ``Recording.time_origin``.
    Raises RecordingError if the files break the format and, with ``validate``, if validate_recording or
    check_plausibility (the force and motion the rig can make) finds an error, before any simulation; their
    warnings, unknown fields/columns and partial recordings are reported as RecordingWarning.
    """
    directory = _recording_dir(path)
    yaml_path = directory / YAML_NAME
    try:
        text = read_text(yaml_path)
    except FileNotFoundError:
        raise RecordingError(f"{yaml_path}: missing; {directory} is not a diffstir recording") from None
    try:
        meta = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise RecordingError(f"{yaml_path}: not valid YAML: {' '.join(str(exc).split())}") from None
    fields = parse_metadata(meta, str(yaml_path))
    known, unknown, origin = read_csv(directory / CSV_NAME, partial=not fields["complete"])
    rec = Recording(**fields, **known, extra_columns=unknown, time_origin=origin, path=directory)
    if not rec.complete:
        warn(f"{yaml_path}: PARTIAL recording (complete: false, reason: {rec.partial_reason!r}); it holds "
             f"{rec.t.size} rows up to t = {rec.t[-1] if rec.t.size else math.nan} s and may end early")
    if validate:
        for message in validate_recording(rec) + check_plausibility(rec):
            warn(message)
    return rec


def write_csv(f: io.TextIOBase, columns: dict[str, np.ndarray]) -> None:
    """Write the header and all rows of ``columns`` (name -> 1-D array) to the open text file ``f``."""
    names = list(columns)
    f.write(csv_header(names))
    writer = csv.writer(f, lineterminator="\n")
    for row in zip(*columns.values()):
        writer.writerow([format_value(v) for v in row])


def save_recording(rec: Recording, path: str | Path, *, overwrite: bool = False) -> Path:
    """Write ``rec`` as the recording directory ``path`` and return it.

    The files are written into a temporary directory beside ``path`` and renamed into place, so ``path`` is
    either untouched or complete. An existing ``path`` raises FileExistsError unless ``overwrite`` is True, and
    even then only an existing recording (a directory with recording.yaml) is replaced.
    """
    path = Path(path)
    check_columns_shape(rec)
    meta = metadata_dict(cup=rec.cup, rod=rec.rod, sensor=rec.sensor, density=rec.density, name=rec.name,
                         fluid=rec.fluid, temperature=rec.temperature, complete=rec.complete,
                         partial_reason=rec.partial_reason, extra_meta=rec.extra_meta, where=rec.source("yaml"))
    exists = path.exists() or path.is_symlink()
    if exists and not overwrite:
        raise FileExistsError(f"{path}: already exists; a recording is never overwritten unless overwrite=True")
    if exists and not (path.is_dir() and not path.is_symlink() and (path / YAML_NAME).is_file()):
        raise FileExistsError(f"{path}: exists and is not a recording directory (no {YAML_NAME}); refusing to "
                              f"replace it")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = fresh_dir(path.parent, path.name, ".tmp")
    try:
        with open(tmp / CSV_NAME, "w", encoding="utf-8", newline="") as f:
            write_csv(f, {**rec.columns(), "t": absolute_times(rec.t, rec.time_origin)})
            f.flush()
            os.fsync(f.fileno())
        write_metadata(tmp, meta)
        if exists:
            old = fresh_dir(path.parent, path.name, ".old")
            os.replace(path, old / path.name)
            try:
                os.replace(tmp, path)
            except OSError:
                os.replace(old / path.name, path)  # put the old recording back
                raise
            shutil.rmtree(old)
        else:
            os.rename(tmp, path)
        fsync_dir(path.parent)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return path
