"""A campaign of malformed recordings, each refused on loading in one line that names the file, the field or column
and the expected unit, within 5 s and before any simulation; and the recordings real rigs write (a byte-order
mark, CRLF, 1 kHz, a clock's time origin, rounded or jittery positions, a sensor's dead start), accepted and read
right."""

from __future__ import annotations

import codecs
import math
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import yaml

from diffstir.recording import RecordingError, RecordingWarning, load_recording
from diffstir.recording import plausibility

RATE = 200.0  # Hz
DURATION = 2.0  # s


def meta() -> dict:
    """recording.yaml of the base recording: the paper's rig, a tangential sensor at 200 Hz."""
    return {"format": "diffstir-recording/1", "name": "base",
            "rig": {"cup": {"radius": 0.0425, "fill_height": 0.13}, "rod": {"radius": 0.0125, "immersion_depth": 0.08}},
            "sensor": {"mode": "tangential", "resolution": 0.001, "sample_rate": RATE},
            "density": {"rod_weight": 0.6, "immersed_reading": 0.2, "immersed_depth": 0.08}}


def columns(rate: float = RATE, duration: float = DURATION, radius: float = 0.015, freq: float = 1.0) -> dict:
    """A rod circling ``radius`` [m] off the cup axis at ``freq`` [Hz]; a force of 20-40 mN."""
    t = np.arange(round(duration * rate) + 1) / rate
    phase = 2 * math.pi * freq * t
    return {"t": t, "x": radius * np.cos(phase), "y": radius * np.sin(phase), "force": 0.03 + 0.01 * np.sin(phase)}


@dataclass
class Case:
    """A recording's text: ``meta`` and ``cols`` as the base has them, changed by ``change`` (on the dicts) and
    ``text`` (on the final csv text); ``yaml_bytes``/``csv_bytes`` replace the files' bytes."""

    change: Callable[[dict, dict], None] = lambda m, c: None
    text: Callable[[str], str] = lambda s: s
    yaml_text: Callable[[str], str] = lambda s: s
    yaml_bytes: Callable[[str], bytes] = lambda s: s.encode("utf-8")
    csv_bytes: Callable[[str], bytes] = lambda s: s.encode("utf-8")
    cols: Callable[[], dict] = columns
    omit: tuple[str, ...] = ()
    path: Callable[[Path], Path] = lambda p: p


def csv_text(cols: dict) -> str:
    names = list(cols)
    rows = [",".join(repr(float(v)) if isinstance(v, (float, np.floating)) else str(v) for v in row)
            for row in zip(*cols.values())]
    return "# diffstir-recording/1 stir.csv; units: t [s], x [m], y [m], force [N]\n" + ",".join(names) + "\n" + \
        "\n".join(rows) + "\n"


def write_case(tmp_path: Path, case: Case) -> Path:
    m, c = meta(), case.cols()
    case.change(m, c)
    path = tmp_path / "rec"
    path.mkdir()
    if "recording.yaml" not in case.omit:
        (path / "recording.yaml").write_bytes(case.yaml_bytes(case.yaml_text(yaml.safe_dump(m, sort_keys=False,
                                                                                          allow_unicode=True))))
    if "stir.csv" not in case.omit:
        (path / "stir.csv").write_bytes(case.csv_bytes(case.text(csv_text(c))))
    return case.path(path)


def scale(column: str, factor: float):
    return lambda m, c: c.__setitem__(column, c[column] * factor)


def setcell(column: str, row: int, value: float):
    def change(m, c):
        c[column] = c[column].copy()
        c[column][row] = value
    return change


def setfield(dotted: str, value):
    def change(m, c):
        *parents, key = dotted.split(".")
        for p in parents:
            m = m[p]
        if value is None:
            del m[key]
        else:
            m[key] = value
    return change


def both(*changes):
    def change(m, c):
        for ch in changes:
            ch(m, c)
    return change


def slow_stir():
    return columns(radius=0.002)  # 12.6 mm/s on a 2 mm circle


def with_column(name: str, values):
    return lambda m, c: c.__setitem__(name, np.broadcast_to(values, c["t"].shape).astype(float))


def replace_header(old: str, new: str):
    def text(s: str) -> str:
        lines = s.split("\n")
        lines[1] = lines[1].replace(old, new)
        return "\n".join(lines)
    return text


def reorder_rows(order: str):
    def change(m, c):
        n = c["t"].size
        index = np.arange(n)
        if order == "reversed":
            index = index[::-1]
        elif order == "shuffled":
            index = np.random.default_rng(0).permutation(n)
        for k in c:
            c[k] = c[k][index]
    return change


def still(jitter: float):
    def change(m, c):
        rng = np.random.default_rng(3)
        c["x"] = 0.01 + jitter * rng.standard_normal(c["t"].size)
        c["y"] = jitter * rng.standard_normal(c["t"].size)
    return change


# id: (case, file, fragments the one-line message holds: the field or column, and the expected unit)
REFUSED = {
    # units
    "positions in mm": (Case(both(scale("x", 1e3), scale("y", 1e3))), "stir.csv", ["column 'x'", "millimetres", "(m)"]),
    "z in mm": (Case(with_column("z", -20.0)), "stir.csv", ["column 'z'", "millimetres", "(m)"]),
    "force in mN, slow stir": (Case(scale("force", 5e4), cols=slow_stir), "stir.csv",
                               ["column 'force'", "is the force in mN", "N"]),
    "force x1e30": (Case(scale("force", 1e30)), "stir.csv", ["column 'force'", "peaks at", "expected N"]),
    "force in nN": (Case(scale("force", 1e9)), "stir.csv", ["column 'force'", "cannot exceed", "expected N"]),
    "rod radius in mm": (Case(setfield("rig.rod.radius", 12.5)), "recording.yaml", ["'rig.rod.radius'", "(m)"]),
    "cup radius in mm": (Case(setfield("rig.cup.radius", 42.5)), "recording.yaml", ["'rig.cup.radius'", "(m)"]),
    "fill in cm": (Case(setfield("rig.cup.fill_height", 13.0)), "recording.yaml",
                   ["'rig.cup.fill_height'", "centimetres", "(m)"]),
    "immersion in mm": (Case(setfield("rig.rod.immersion_depth", 80.0)), "recording.yaml",
                        ["'rig.rod.immersion_depth'", "(m)"]),
    "fill volume in ml": (Case(both(setfield("rig.cup.fill_height", None), setfield("rig.cup.fill_volume", 738.0))),
                          "recording.yaml", ["'rig.cup.fill_volume'", "m^3"]),
    "t in ms": (Case(scale("t", 1e3)), "recording.yaml", ["'sensor.sample_rate'", "column 't'", "in s"]),
    "t in us": (Case(scale("t", 1e6)), "recording.yaml", ["'sensor.sample_rate'", "column 't'", "in s"]),
    "sample rate in kHz": (Case(setfield("sensor.sample_rate", 0.2)), "recording.yaml",
                           ["'sensor.sample_rate'", "in Hz"]),
    "time constant in ms": (Case(setfield("sensor.time_constant", 20.0)), "recording.yaml",
                            ["'sensor.time_constant'", "in s"]),
    "density depth in mm": (Case(setfield("density.immersed_depth", 80.0)), "recording.yaml",
                            ["'density.immersed_depth'", "(m)"]),
    "rod cross-section in mm2": (Case(setfield("density.rod_cross_section", 490.9)), "recording.yaml",
                                 ["'density.rod_cross_section'", "m^2"]),
    "field with a unit": (Case(setfield("rig.rod.radius", "12.5 mm")), "recording.yaml", ["'rig.rod.radius'", " m"]),
    # non-finite values, in every column
    **{f"{v} in {col}": (Case(setcell(col, 7, float(v))), "stir.csv", [f"column '{col}'", f"in {unit}"])
       for v in ("nan", "inf") for col, unit in (("t", "s"), ("x", "m"), ("y", "m"), ("force", "N"))},
    "nan in z": (Case(both(with_column("z", 0.0), setcell("z", 3, math.nan))), "stir.csv", ["column 'z'", "in m"]),
    "-inf in force_x": (Case(both(with_column("force_x", 0.0), setcell("force_x", 3, -math.inf))), "stir.csv",
                        ["column 'force_x'", "in N"]),
    # time order and resolution
    "time steps back": (Case(setcell("t", 50, 0.1)), "stir.csv", ["column 't'", "strictly increasing", "in s"]),
    "time duplicated": (Case(setcell("t", 50, 49 / RATE)), "stir.csv", ["column 't'", "strictly increasing"]),
    "rows shuffled": (Case(reorder_rows("shuffled")), "stir.csv", ["column 't'", "strictly increasing"]),
    "rows reversed": (Case(reorder_rows("reversed")), "stir.csv", ["column 't'", "strictly increasing"]),
    "clock at 1e12 s": (Case(lambda m, c: c.__setitem__("t", c["t"] + 1e12)), "stir.csv",
                        ["column 't'", "float64", "in s"]),
    # columns
    **{f"missing {col}": (Case(lambda m, c, col=col: c.pop(col)), "stir.csv", [f"'{col}'", "missing", "[N]"])
       for col in ("t", "x", "y", "force")},
    "duplicated column": (Case(text=replace_header("y", "x")), "stir.csv", ["'x'", "repeated"]),
    "misspelt column": (Case(text=replace_header("force", "forse")), "stir.csv", ["'forse' for 'force'", "[N]"]),
    "capitalised column": (Case(text=replace_header("t,", "T,")), "stir.csv", ["'T' for 't'", "[s]"]),
    "header in mN": (Case(text=replace_header("force", "force [mN]")), "stir.csv", ["'force [mN]'", "in N"]),
    "header in mm": (Case(text=replace_header("x,", "x (mm),")), "stir.csv", ["'x (mm)'", "in m"]),
    "extra value in a row": (Case(text=lambda s: s.replace("\n0.5,", "\n0.5,1.0,")), "stir.csv",
                             ["line", "5 values for the 4 columns", "[s]"]),
    "missing value in a row": (Case(text=lambda s: s.replace("\n0.5,", "\n")), "stir.csv",
                               ["3 values for the 4 columns", "[N]"]),
    "text in a cell": (Case(setcell("force", 9, 0.0), text=lambda s: s.replace(",0.03\n", ",0.03 N\n", 1)),
                       "stir.csv", ["column 'force'", "'0.03 N'", "N"]),
    "empty cell": (Case(text=lambda s: s.replace(",0.03\n", ",\n", 1)), "stir.csv", ["column 'force'", "N"]),
    "truncated line": (Case(text=lambda s: s.replace("\n0.5,", "\n0.5\n0.505,", 1)), "stir.csv",
                       ["1 values for the 4 columns", "[s]"]),
    # separators
    "semicolons": (Case(text=lambda s: s.replace(",", ";")), "stir.csv", ["semicolons", "commas", "s, m, m, N"]),
    "tabs": (Case(text=lambda s: s.replace(",", "\t")), "stir.csv", ["tabs", "commas", "s, m, m, N"]),
    "decimal comma, semicolons": (Case(text=lambda s: s.replace(",", ";").replace(".", ",")), "stir.csv",
                                  ["semicolons", "decimal point"]),
    "decimal comma": (Case(text=lambda s: s.split("\n", 2)[0] + "\n" + s.split("\n", 2)[1] + "\n"
                           + s.split("\n", 2)[2].replace(".", ",")), "stir.csv",
                      ["decimal comma", "[s]"]),
    # encodings
    "csv in UTF-16": (Case(csv_bytes=lambda s: s.encode("utf-16")), "stir.csv", ["UTF-16", "UTF-8"]),
    "yaml in UTF-16": (Case(yaml_bytes=lambda s: s.encode("utf-16")), "recording.yaml", ["UTF-16", "UTF-8"]),
    "yaml in Latin-1": (Case(setfield("name", "crème brûlée"), yaml_bytes=lambda s: s.encode("latin-1")),
                        "recording.yaml", ["line 2", "not UTF-8", "UTF-8"]),
    "csv comment in Latin-1": (Case(text=lambda s: "# sensor: 5 µN resolution\n" + s,
                                    csv_bytes=lambda s: s.encode("latin-1")), "stir.csv", ["line 1", "UTF-8"]),
    "binary csv": (Case(csv_bytes=lambda s: bytes(range(256)) * 4), "stir.csv", ["binary", "UTF-8"]),
    # geometry
    "rod outside the cup": (Case(cols=lambda: columns(radius=0.035)), "stir.csv",
                            ["columns 'x', 'y'", "cup wall", " m"]),
    "rod wider than cup": (Case(setfield("rig.rod.radius", 0.05)), "recording.yaml", ["'rig.rod.radius'", "(m)"]),
    "immersion deeper than the fill": (Case(setfield("rig.rod.immersion_depth", 0.14)), "recording.yaml",
                                       ["'rig.rod.immersion_depth'", "(expected m)"]),
    "negative rod radius": (Case(setfield("rig.rod.radius", -0.0125)), "recording.yaml",
                            ["'rig.rod.radius'", "in m"]),
    "negative cup radius": (Case(setfield("rig.cup.radius", -0.0425)), "recording.yaml",
                            ["'rig.cup.radius'", "in m"]),
    "zero fill": (Case(setfield("rig.cup.fill_height", 0.0)), "recording.yaml", ["'rig.cup.fill_height'", "in m"]),
    "z reaching the bottom": (Case(with_column("z", -0.06)), "stir.csv", ["column 'z'", "bottom", "m)"]),
    # motion and sensor
    "rod never moves": (Case(still(0.0)), "stir.csv", ["columns 'x', 'y'", "does not stir", "(in m)"]),
    "still rod, 50 um jitter": (Case(still(50e-6)), "stir.csv", ["columns 'x', 'y'", "does not stir", "(in m)"]),
    "all-zero force": (Case(scale("force", 0.0)), "stir.csv", ["column 'force'", "silent", "in N"]),
    "constant force": (Case(lambda m, c: c.__setitem__("force", np.full_like(c["t"], 0.02))), "stir.csv",
                       ["column 'force'", "silent", "in N"]),
    "component without axis": (Case(setfield("sensor.mode", "component")), "recording.yaml",
                               ["'sensor.axis'", "unit vector"]),
    "axis not unit": (Case(both(setfield("sensor.mode", "component"), setfield("sensor.axis", [1.0, 1.0]))),
                      "recording.yaml", ["'sensor.axis'", "dimensionless"]),
    "unknown sensor mode": (Case(setfield("sensor.mode", "force")), "recording.yaml", ["'sensor.mode'", "tangential"]),
    "negative resolution": (Case(setfield("sensor.resolution", -0.001)), "recording.yaml",
                            ["'sensor.resolution'", "in N"]),
    "density reading above weight": (Case(setfield("density.immersed_reading", 0.7)), "recording.yaml",
                                     ["'density.immersed_reading'", "(N)"]),
    # files and format
    "empty csv": (Case(text=lambda s: ""), "stir.csv", ["no header line", "t, x, y, force"]),
    "comments only": (Case(text=lambda s: s.split("\n")[0] + "\n"), "stir.csv", ["no header line"]),
    "header only": (Case(text=lambda s: "\n".join(s.split("\n")[:2]) + "\n"), "stir.csv",
                    ["0 data rows", "0.5 s"]),
    "wrong format string": (Case(setfield("format", "diffstir-recording/2")), "recording.yaml",
                            ["'format'", "diffstir-recording/1"]),
    "format missing": (Case(setfield("format", None)), "recording.yaml", ["'format'", "diffstir-recording/1"]),
    "no stir.csv": (Case(omit=("stir.csv",)), "stir.csv", ["missing", "stir.csv"]),
    "no recording.yaml": (Case(omit=("recording.yaml",)), "recording.yaml", ["missing"]),
    "yaml not a mapping": (Case(yaml_text=lambda s: "- a list\n- of things\n"), "recording.yaml", ["mapping"]),
    "yaml syntax error": (Case(yaml_text=lambda s: s + "rig: [unclosed\n"), "recording.yaml", ["not valid YAML"]),
    "rig section missing": (Case(setfield("rig", None)), "recording.yaml", ["'rig'", "missing"]),
    "path does not exist": (Case(path=lambda p: p / "nothing-here"), "nothing-here", ["no such recording"]),
    # sampling
    "too few samples per period": (Case(cols=lambda: columns(rate=RATE, freq=25.0, duration=1.0)), "stir.csv",
                                   ["column 't'", "samples per stirring period", "Hz"]),
    "too short": (Case(cols=lambda: columns(duration=0.3)), "stir.csv", ["column 't'", "too short", "s"]),
}


def test_the_campaign_holds_54_malformed_recordings():
    assert len(REFUSED) >= 54


@pytest.mark.parametrize("case_id", list(REFUSED))
def test_a_malformed_recording_is_refused_in_one_line(tmp_path, monkeypatch, case_id):
    case, file, fragments = REFUSED[case_id]
    path = write_case(tmp_path, case)
    import diffstir.mpm.simulator as simulator  # no recording reaches a simulation
    monkeypatch.setattr(simulator.StirringSimulator, "forward", lambda *a, **k: pytest.fail("simulated"))
    started = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecordingWarning)
        with pytest.raises(RecordingError) as info:
            load_recording(path)
    assert time.perf_counter() - started < 5.0
    message = str(info.value)
    assert "\n" not in message, message
    assert file in message, message
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"


def test_the_plausibility_bounds_are_the_laws_bounds():
    from diffstir.rheology.laws import LAWS
    specs = [(name, spec) for law in LAWS.values() for name, spec in law.specs.items()]
    assert max(s.bounds[1] for n, s in specs if s.unit == "Pa·s") == plausibility.VISCOSITY_MAX
    assert max(s.bounds[1] for n, s in specs if s.unit == "Pa·s^n") == plausibility.CONSISTENCY_MAX
    assert max(s.bounds[1] for n, s in specs if s.unit == "Pa") == plausibility.YIELD_STRESS_MAX
    indices = [s.bounds for n, s in specs if s.unit == "1"]
    assert (min(b[0] for b in indices), max(b[1] for b in indices)) == plausibility.FLOW_INDEX_RANGE


# -- what real rigs write: accepted, and read right ------------------------------------------------------------

def load_clean(path: Path, allowed: tuple[str, ...] = ()):
    """load_recording, failing on any warning whose message holds none of ``allowed``."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rec = load_recording(path)
    unexpected = [str(w.message) for w in caught if not any(a in str(w.message) for a in allowed)]
    assert not unexpected, unexpected
    return rec


def assert_read_right(rec, cols: dict, *, origin: float = 0.0, time_tolerance: float = 1e-12) -> None:
    assert rec.time_origin == pytest.approx(origin, rel=1e-15)
    assert rec.t[0] == 0.0
    np.testing.assert_allclose(rec.t, cols["t"] - cols["t"][0], rtol=0, atol=time_tolerance)
    for k in ("x", "y", "force"):
        np.testing.assert_array_equal(getattr(rec, k), np.asarray(cols[k], dtype=float), err_msg=k)


def test_a_utf8_byte_order_mark_is_read(tmp_path):
    """Excel's "CSV UTF-8" starts the file with EF BB BF; the header's first name is still 't'."""
    path = write_case(tmp_path, Case(csv_bytes=lambda s: codecs.BOM_UTF8 + s.encode(),
                                     yaml_bytes=lambda s: codecs.BOM_UTF8 + s.encode()))
    assert_read_right(load_clean(path), columns())


@pytest.mark.parametrize("ending", ["\r\n", "\r"])
def test_crlf_and_cr_line_ends_are_read(tmp_path, ending):
    path = write_case(tmp_path, Case(text=lambda s: s.replace("\n", ending), yaml_text=lambda s: s.replace("\n", ending)))
    assert_read_right(load_clean(path), columns())


def test_a_header_with_si_units_is_read(tmp_path):
    path = write_case(tmp_path, Case(text=replace_header("t,x,y,force", "t [s],x (m),y [m], force [N]")))
    assert_read_right(load_clean(path), columns())


def test_1khz_with_micrometre_rounding_and_comments(tmp_path):
    def cols():
        c = columns(rate=1000.0)
        c["x"], c["y"] = np.round(c["x"], 6), np.round(c["y"], 6)
        return c

    def text(s):
        lines = s.split("\n")
        return "\n".join(lines[:500] + ["# the arm paused its log here", "   # indented comment", ""] + lines[500:])

    path = write_case(tmp_path, Case(setfield("sensor.sample_rate", 1000.0), text=text, cols=cols))
    assert_read_right(load_clean(path), cols())


@pytest.mark.parametrize("rate", [100.0, 1000.0])
def test_50_micrometre_jitter_is_accepted(tmp_path, rate):
    def cols():
        c = columns(rate=rate)
        rng = np.random.default_rng(5)
        c["x"], c["y"] = (c[k] + 50e-6 * rng.standard_normal(c["t"].size) for k in ("x", "y"))
        return c

    path = write_case(tmp_path, Case(setfield("sensor.sample_rate", rate), cols=cols))
    assert_read_right(load_clean(path), cols())


@pytest.mark.parametrize("origin", [1e5, 1.7e9])
def test_a_clock_origin_keeps_the_time_resolution(tmp_path, origin):
    """Times written as a rig's uptime (1e5 s) or Unix time (1.7e9 s), at 1 kHz, to 1 µs: read from the text as
    times from the first sample, exact to float64 rounding of the differences (1e-16 s · 2 s), not to the
    clock's float64 spacing (1.5e-11 s at 1e5 s, 2.4e-7 s at 1.7e9 s)."""
    base = columns(rate=1000.0)
    micro = np.round(base["t"] * 1e6).astype(np.int64)  # µs since the start

    def text(s):
        lines = s.split("\n")
        seconds, fraction = int(origin), origin - int(origin)
        assert fraction == 0
        for k, us in enumerate(micro):
            cells = lines[2 + k].split(",")
            cells[0] = f"{seconds + us // 1_000_000}.{us % 1_000_000:06d}"
            lines[2 + k] = ",".join(cells)
        return "\n".join(lines)

    path = write_case(tmp_path, Case(setfield("sensor.sample_rate", 1000.0), text=text,
                                     cols=lambda: columns(rate=1000.0)))
    rec = load_clean(path)
    assert_read_right(rec, base, origin=origin, time_tolerance=1e-15)
    assert np.all(np.diff(rec.t) > 0.999e-3)


def test_a_thin_film_sensor_with_a_dead_start_is_accepted(tmp_path):
    """A one-sided sensor at 1 kHz that reads zero for the first 1.5 s of 8 s, then 8-11 mN (the DiffStir
    authors' recording)."""
    def cols():
        c = columns(rate=1000.0, duration=8.0, freq=0.5)
        c["force"] = np.where(c["t"] < 1.5, 0.0, 0.0095 + 0.0015 * np.sin(2 * math.pi * c["t"]))
        return c

    path = write_case(tmp_path, Case(both(setfield("sensor.sample_rate", 1000.0), setfield("sensor.mode", "magnitude"),
                                          setfield("sensor.one_sided", True)), cols=cols))
    assert_read_right(load_clean(path), cols())


def test_a_thick_fluid_in_newtons_and_a_thin_one_in_micronewtons_are_accepted(tmp_path):
    """The force bound refuses only readings beyond any law's reach: 3 N of a paste on a slow stir, and 50 µN of
    water, both read as written."""
    for name, factor, make in (("paste", 100.0, slow_stir), ("water", 1.6e-3, columns)):
        directory = tmp_path / name
        directory.mkdir()
        path = write_case(directory, Case(scale("force", factor), cols=make))
        rec = load_clean(path)
        np.testing.assert_allclose(rec.force, make()["force"] * factor, rtol=1e-15)
