"""The errors a user's input can cause, and the checks of a setting that raise them. Each message is one line that
names the file or setting, the field and the expected unit or the valid choices; the command-line apps print it
without a traceback and exit with status 2."""

from __future__ import annotations

import math


class DiffstirError(Exception):
    """An input the user can correct: a recording, a setting, an output folder."""


class ConfigError(DiffstirError, ValueError):
    """A setting outside its range or its choices; the message lists the valid ones."""


class OutputError(DiffstirError):
    """An output that would overwrite something recorded or shipped, or belongs to another input."""


class SimulationError(DiffstirError, FloatingPointError):
    """A simulation that became non-finite at the settings given; the message names the settings that would let it
    run. A fit rejects such a trial step (it is a ``FloatingPointError``); where nothing simulates, the apps print
    it as a user's error."""


def is_number(value) -> bool:
    """Whether ``value`` is a finite int or float (a bool is not a number here)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def is_whole(value, low: int) -> bool:
    """Whether ``value`` is an int (not a bool) of at least ``low``."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= low


def check_choice(setting: str, value, choices) -> None:
    """Raise ConfigError unless ``value`` is one of ``choices``; ``setting`` is its name on the command line."""
    if value not in choices:
        raise ConfigError(f"{setting} = {value!r}; choose from {', '.join(map(str, choices))}")


def check_choices(setting: str, values, choices) -> None:
    """Raise ConfigError unless every one of ``values`` is one of ``choices``."""
    unknown = [v for v in values if v not in choices]
    if unknown:
        raise ConfigError(f"{setting}: unknown {', '.join(map(str, unknown))}; choose from "
                          f"{', '.join(map(str, choices))}")


def check_at_least(setting: str, value, low: float, unit: str = "") -> None:
    """Raise ConfigError unless ``value`` (null allowed) is a number of at least ``low`` [``unit``]."""
    if value is not None and not (is_number(value) and value >= low):
        raise ConfigError(f"{setting} = {value!r}{' ' + unit if unit else ''}; expected at least {low}"
                          f"{' ' + unit if unit else ''}")
