"""How a recording is diagnosed: the ``diagnosis:`` settings of ``diffstir-diagnose`` (conf/diagnose.yaml) as one
checked dataclass.

``DiagnosisSettings()`` holds the command's defaults, those of ``diagnose()``. The apps register it with Hydra's
ConfigStore as the schema of the ``diagnosis`` node, so a misspelt key or a value of the wrong type is refused when
the command line is composed, and a value outside its range or choices when the settings are built, before any
simulation: one line that names the setting and lists the valid values.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import ConfigError, check_choices, is_number, is_whole
from .candidates import CANDIDATES

#: The shortest comparison window [s].
MIN_WINDOW = 1e-3


@dataclass
class DiagnosisSettings:
    """The diagnosis's settings (docs/diagnosis.md).

    Attributes:
        candidates: the extensions to test, of ``CANDIDATES`` (``none``, the base law alone, is always added).
        max_iterations: Gauss-Newton evaluations per physics candidate after its finite-difference Jacobian.
        rebuild_time: the thixotropy candidate's starting structure rebuild time t_r [s] (fitted).
        identify_iterations: Gauss-Newton evaluations of the Newtonian fit made when no identification is given.
        window: compare the first ``window`` seconds of the recording [s], at least 1 ms (None: all of it).
    """

    candidates: list[str] = field(default_factory=lambda: list(CANDIDATES))
    max_iterations: int = 3
    rebuild_time: float = 1.0
    identify_iterations: int = 4
    window: float | None = None

    def __post_init__(self) -> None:
        self.candidates = list(self.candidates)
        check_choices("diagnosis.candidates", self.candidates, CANDIDATES)
        for name in ("max_iterations", "identify_iterations"):
            value = getattr(self, name)
            if not is_whole(value, 1):
                raise ConfigError(f"diagnosis.{name} = {value!r}; expected a whole number of at least 1")
        if not (is_number(self.rebuild_time) and self.rebuild_time > 0):
            raise ConfigError(f"diagnosis.rebuild_time = {self.rebuild_time!r} s; expected a positive time in s")
        if self.window is not None and not (is_number(self.window) and self.window >= MIN_WINDOW):
            raise ConfigError(f"diagnosis.window = {self.window!r} s; expected at least {MIN_WINDOW:g} s, or null "
                              "(all of the recording)")
