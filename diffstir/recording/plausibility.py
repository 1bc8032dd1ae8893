"""What the rig can physically record: a force within reach of some fluid the viscosity laws allow, and a sensor
that responds while the rod stirs. Checked on loading, before any simulation (``load_recording`` calls
``check_plausibility`` after ``validate_recording``).

The force bound is an upper bound on the horizontal force [N] on the rod at any law the fitter can reach, the sum of

    viscous   F_v = 4π η_max U L / (ln(b/a) − (b² − a²)/(b² + a²)) · max(1, (a/h)^(3/2))
    yield     F_y = 12 τ_max (2a) L
    inertial  F_i = C_D ρ_max U² a L,  C_D = 2

with a, b the rod's and the cup's radii [m], L the fill height [m] (the longest immersed length), U the rod's
largest speed [m/s] (finite differences of the positions: jitter only raises it), h the rod's closest gap to the
wall [m], η_max the largest apparent viscosity [Pa·s] of the laws at shear rate U/a over their parameter bounds,
τ_max the largest yield stress [Pa]. F_v is the Stokes drag per length of a rod in the middle of a cup, raised by
the lubrication factor of a rod near the wall; F_y is the plastic limit load of a cylinder (about 11.9 τ_y · 2a);
F_i a bluff body's drag. A recording is refused only when its force exceeds ``FORCE_MARGIN`` times this bound.
"""

from __future__ import annotations

import math

import numpy as np

from diffstir.recording.errors import RecordingError
from diffstir.recording.format import Recording
from diffstir.recording.validate import PLAUSIBLE_DENSITY

# The laws' parameter bounds (diffstir.rheology.laws; tests/test_malformed_recordings.py checks that they agree).
VISCOSITY_MAX = 1e3  # Pa·s: the upper bound of every viscosity parameter (η, η0, η_inf, η_p)
CONSISTENCY_MAX = 1e3  # Pa·s^n: the upper bound of a power law's consistency K
FLOW_INDEX_RANGE = (0.01, 2.0)  # 1: the widest bounds of a flow index n (Cross: 0.01; power laws: 0.05 to 2)
YIELD_STRESS_MAX = 1e3  # Pa: the upper bound of a yield stress τ_y
DRAG_COEFFICIENT = 2.0  # 1: C_D of the inertial bound, above a cylinder's ≈ 1.2 at high Reynolds number
YIELD_LOAD_FACTOR = 12.0  # 1: limit load per (τ_y · diameter · length) of a cylinder in a plastic fluid (11.9)
FORCE_MARGIN = 10.0  # 1: a force is refused only beyond this multiple of the bound


def largest_viscosity(shear_rate: float) -> float:
    """η_max [Pa·s] at ``shear_rate`` [1/s]: the largest apparent viscosity any law reaches within its bounds,
    max(η_max, K_max γ̇^(n − 1) for n at either end of its bounds), without the yield stress."""
    rate = max(shear_rate, 1e-6)
    return max(VISCOSITY_MAX, *(CONSISTENCY_MAX * rate ** (n - 1.0) for n in FLOW_INDEX_RANGE))


def force_bound(rec: Recording) -> tuple[float, float, float]:
    """(F_max [N], U [m/s], η_max [Pa·s]): the largest horizontal force on ``rec``'s rod at any law within the
    bounds, the rod's top speed and the viscosity that bound used (module docstring)."""
    a, b = rec.rod.radius, rec.cup.radius
    length = rec.cup.resolved_fill_height()
    speed = float(np.max(np.linalg.norm(rec.velocity(), axis=-1)))
    eta = largest_viscosity(speed / a)
    gap = b - a - float(np.max(np.hypot(rec.x, rec.y)))
    near_wall = max(1.0, (a / gap) ** 1.5)
    viscous = 4 * math.pi * eta * speed * length / (math.log(b / a) - (b**2 - a**2) / (b**2 + a**2)) * near_wall
    plastic = YIELD_LOAD_FACTOR * YIELD_STRESS_MAX * 2 * a * length
    inertial = DRAG_COEFFICIENT * PLAUSIBLE_DENSITY[1] * speed**2 * a * length
    return viscous + plastic + inertial, speed, eta


def check_plausibility(rec: Recording) -> list[str]:
    """Raise RecordingError if ``rec``'s force is beyond what its rig can make (``force_bound`` times
    ``FORCE_MARGIN``) or never changes while the rod stirs; return warnings. A partial recording gets the
    errors as warnings. Expects a recording that ``validate_recording`` accepts."""
    if rec.t.size < 2:
        return []
    where = rec.source("csv")
    errors: list[str] = []
    bound, speed, eta = force_bound(rec)
    peak = np.abs(rec.force)
    i = int(np.argmax(peak))
    if peak[i] > FORCE_MARGIN * bound:
        errors.append(
            f"{where}: column 'force' peaks at {rec.force[i]:.4g} N at data row {i + 1} (t = {rec.t[i]:.6g} s); a "
            f"rod of radius {rec.rod.radius:g} m in {rec.cup.resolved_fill_height():.4g} m of fluid in a cup of "
            f"radius {rec.cup.radius:g} m at up to {speed:.3g} m/s cannot exceed {bound:.3g} N at any viscosity up "
            f"to {eta:.3g} Pa·s (yield stress up to {YIELD_STRESS_MAX:g} Pa): is the force in mN? expected N")
    elif np.ptp(rec.force) == 0.0:
        errors.append(
            f"{where}: column 'force' reads {rec.force[0]:g} N in all {rec.t.size} rows while the rod stirs at up "
            f"to {speed:.3g} m/s: the sensor is silent (disconnected, or blind at this force); expected a force "
            f"that varies, in N")
    if not rec.complete:
        return [f"{e} (partial recording: not raised)" for e in errors]
    if errors:
        raise RecordingError(errors[0])
    return []
