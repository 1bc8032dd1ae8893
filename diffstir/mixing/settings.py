"""What a mixing analysis needs besides the recording: the ``mixing:`` settings of ``diffstir-fit experiment=mixing``
(conf/experiment/mixing.yaml) as one checked dataclass.

``MixingSettings(viscosities=[1.0, 0.1], fraction=0.5)`` names the two components; the rest holds the experiment's
defaults. The apps register it with Hydra's ConfigStore as the schema of the ``mixing`` node; a value outside its
range is refused when the settings are built, before any simulation, in one line that names the setting and unit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import ConfigError, is_number, is_whole
from ..fitting import COARSE_FORCE_ERROR, checked_model_error


@dataclass
class MixingSettings:
    """The mixing experiment's settings (docs/mixing.md).

    Attributes:
        viscosities: [η1, η2], the components' viscosities [Pa·s], the more viscous first.
        fraction: φ, the volume fraction of fluid 1 [1], in (0, 1).
        window: the length of each window of the time course [s].
        iterations: Gauss-Newton iterations of each window's Newtonian fit.
        model_error: σ_m, the relative 1-σ error of the fitting simulation's force [1], in every window's interval:
            ``fitting.COARSE_FORCE_ERROR``, that of the experiment's ``sim=coarse2d`` (``fitting.MODEL_FORCE_ERROR``
            with ``sim=slice2d``).
    """

    viscosities: list[float]
    fraction: float
    window: float = 0.5
    iterations: int = 3
    model_error: float = COARSE_FORCE_ERROR

    def __post_init__(self) -> None:
        self.viscosities = [float(v) for v in self.viscosities]
        if (len(self.viscosities) != 2 or not all(math.isfinite(v) and v > 0 for v in self.viscosities)
                or self.viscosities[0] <= self.viscosities[1]):
            raise ConfigError(f"mixing.viscosities = {self.viscosities}; expected [eta1, eta2] in Pa·s, both "
                              "positive, the more viscous first")
        if not (is_number(self.fraction) and 0.0 < self.fraction < 1.0):
            raise ConfigError(f"mixing.fraction = {self.fraction!r}; expected fluid 1's volume fraction in (0, 1)")
        if not (is_number(self.window) and self.window > 0):
            raise ConfigError(f"mixing.window = {self.window!r} s; expected a positive duration in s")
        if not is_whole(self.iterations, 1):
            raise ConfigError(f"mixing.iterations = {self.iterations!r}; expected a whole number of at least 1")
        checked_model_error(self.model_error, "mixing.model_error")
