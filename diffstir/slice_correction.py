"""The slice's error: the 3-D force on the rod over the 2-D slice's force per length times the immersion.

A 2-D slice gives the force per length F'_2D [N/m] of the rig's cross-section; the rod in a real cup feels F_3D [N].
Their ratio, from the 3-D finite-element study (``scripts/slice_error.py``, docs/accuracy-slice.md, The slice's error),
is modelled as a tip that adds an effective length a ℓ to the immersion h:

    F_3D = F'_2D (h + a ℓ),    factor = F_3D / (F'_2D h) = 1 + ℓ a / h,
    ℓ = c_1 + c_2 a/g + c_3 R/a + c_4 (1 − n) g/a + c_5 Re,

with R the cup's radius, a the rod's, e the circle's, g = H − h the tip's gap above the bottom [m], n the flow
index [1] and Re = ρ U 2a / η [1]: the flow that escapes round the tip (a negative constant), the shear under the
tip (a disc at height g over the bottom adds about η U π a² / g), the cup's size (a wide cup makes the 2-D force per
length small, about 1 / ln(R/a), so the tip's share larger), shear thinning (its effect grows with the room under
the tip, where the escaping flow thins) and inertia. The coefficients c, their residual scatter σ (the 1-σ relative
uncertainty of the factor) and the swept ranges are read from ``diffstir/data/slice_correction.json``, which
records the command that fitted them, the date and the machine.

Outside the swept ranges each group is clamped to the nearest swept value and σ widens; h/a above its range counts
as inside (the tip's added length a ℓ does not depend on h once h ≫ a, so 1 + ℓ a / h holds there). σ widens to
sqrt(σ² + (factor − 1)²) (1 + D), D the summed distance of the clamped groups from their range in ln units
(ln(1 + Re) for Re, widths of the swept range for e/R, which is 0 for a rod on the cup's axis): there the model's
form is untested, so the whole correction is as uncertain as its size, growing with the extrapolation.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .errors import is_number
from .rheology import RheologyLaw
from .rig import Rig

TABLE = Path(__file__).resolve().parent / "data" / "slice_correction.json"
FEATURES = ("one", "a_over_g", "R_over_a", "one_minus_n_times_g_over_a", "reynolds")
GROUPS = ("h_over_a", "g_over_a", "wall_gap_over_a", "e_over_R", "R_over_a", "n", "reynolds")


@dataclass(frozen=True)
class SliceCorrection:
    factor: float  # F_3D / (F'_2D h) [1]
    sigma: float  # its relative 1-sigma uncertainty [1]
    inside: bool  # the rig, flow index and Reynolds number within the swept ranges
    flow_index: float = 1.0  # n [1] it was evaluated at
    reynolds: float = 0.0  # rho U 2a / eta [1] it was evaluated at


def groups(cup_radius: float, fill_height: float, rod_radius: float, immersion_depth: float, orbit_radius: float,
           flow_index: float = 1.0, reynolds: float = 0.0) -> dict:
    """The dimensionless rig {h/a, g/a, (R − e − a)/a, e/R, R/a, n, Re}; lengths [m]."""
    for name, value in (("cup_radius", cup_radius), ("fill_height", fill_height), ("rod_radius", rod_radius),
                        ("immersion_depth", immersion_depth)):
        if not (is_number(value) and value > 0):
            raise ValueError(f"{name} = {value!r} m; expected a positive length in m")
    if not (is_number(orbit_radius) and orbit_radius >= 0):
        raise ValueError(f"orbit_radius = {orbit_radius!r} m; expected the rod's distance from the cup's axis, >= 0 m")
    if not (is_number(flow_index) and flow_index > 0):
        raise ValueError(f"flow_index = {flow_index!r}; expected a positive power-law index (1 Newtonian)")
    if not (is_number(reynolds) and reynolds >= 0):
        raise ValueError(f"reynolds = {reynolds!r}; expected rho U 2a / eta >= 0 (dimensionless)")
    if orbit_radius + rod_radius >= cup_radius:
        raise ValueError(f"orbit_radius = {orbit_radius} m: the rod (rod_radius = {rod_radius} m) does not fit in the "
                         f"cup (cup_radius = {cup_radius} m); expected orbit_radius + rod_radius < cup_radius in m")
    if immersion_depth >= fill_height:
        raise ValueError(f"immersion_depth = {immersion_depth} m reaches the bottom (fill_height = {fill_height} m); "
                         f"expected immersion_depth < fill_height in m")
    a = rod_radius
    return {"h_over_a": immersion_depth / a, "g_over_a": (fill_height - immersion_depth) / a,
            "wall_gap_over_a": (cup_radius - orbit_radius - a) / a, "e_over_R": orbit_radius / cup_radius,
            "R_over_a": cup_radius / a, "n": float(flow_index), "reynolds": float(reynolds)}


def features(g: dict) -> np.ndarray:
    """The model's regressors (``FEATURES``) of the dimensionless rig ``g`` (``groups``): ℓ = c · features."""
    return np.array([1.0, 1.0 / g["g_over_a"], g["R_over_a"], (1.0 - g["n"]) * g["g_over_a"], g["reynolds"]])


@lru_cache(maxsize=1)
def slice_correction_table() -> dict:
    """The shipped correction (``TABLE``): coefficients, residual σ, swept ranges, and how they were made."""
    return json.loads(TABLE.read_text())


def _distance(name: str, value: float, clamped: float, swept: tuple[float, float]) -> float:
    """How far ``value`` of group ``name`` lies from ``clamped``, its nearest swept value: in ln units, ln(1 + Re)
    for the Reynolds number, and in widths of the ``swept`` range for e/R (a rod on the cup's axis has e/R = 0)."""
    if name == "reynolds":
        return abs(math.log1p(value) - math.log1p(clamped))
    if name == "e_over_R":
        return abs(value - clamped) / (swept[1] - swept[0])
    return abs(math.log(value / clamped))


def slice_correction(cup_radius: float, fill_height: float, rod_radius: float, immersion_depth: float,
                     orbit_radius: float, flow_index: float = 1.0, reynolds: float = 0.0) -> SliceCorrection:
    """F_3D / (F'_2D h) of a rod of radius ``rod_radius`` immersed ``immersion_depth`` in fluid ``fill_height`` deep
    in a cup of radius ``cup_radius``, its axis on a circle of ``orbit_radius`` (all [m]), for a power law's
    ``flow_index`` n [1] (1: Newtonian) at ``reynolds`` ρ U 2a / η [1], with its relative 1-σ uncertainty (the
    module's docstring has the model, its source and range)."""
    g = groups(cup_radius, fill_height, rod_radius, immersion_depth, orbit_radius, flow_index, reynolds)
    table = slice_correction_table()
    clamped, distance = dict(g), 0.0
    for name in GROUPS:
        low, high = table["ranges"][name]
        if name == "h_over_a":
            high = math.inf
        clamped[name] = min(max(g[name], low), high)
        distance += _distance(name, g[name], clamped[name], table["ranges"][name])
    ell = float(np.dot(table["coefficients"], features(clamped)))
    factor = 1.0 + ell / g["h_over_a"]
    sigma = float(table["sigma"])
    inside = distance < 1e-9  # round-off of the table's lengths
    if not inside:
        sigma = math.hypot(sigma, factor - 1.0) * (1.0 + distance)
    return SliceCorrection(factor, sigma, inside, g["n"], g["reynolds"])


def flow_state(material: nn.Module | None, shear_rate: float, density: float, speed: float,
               length: float) -> tuple[float, float]:
    """The local flow index n = 1 + d ln η / d ln γ̇ [1] of ``material``'s rheology law at ``shear_rate`` [1/s]
    (a central difference over a factor 1.1 each way) and the Reynolds number ρ U L / η [1] of ``density``
    [kg/m³], ``speed`` [m/s] and ``length`` [m], η its viscosity there [Pa·s]; (1, 0) without a law (``material``
    None, the corotated baseline). A law wrapped with hidden physics (``material.law``) is read through its law."""
    law = material if isinstance(material, RheologyLaw) else getattr(material, "law", None)
    if not isinstance(law, RheologyLaw) or not shear_rate > 0:
        return 1.0, 0.0
    parameter = next(law.parameters(), None)
    device = parameter.device if parameter is not None else "cpu"
    with torch.no_grad():
        rates = torch.tensor([shear_rate / 1.1, shear_rate, shear_rate * 1.1], dtype=torch.float64, device=device)
        eta = law(rates).double().reshape(-1).cpu().numpy()
    index = 1.0 + math.log(eta[2] / eta[0]) / math.log(1.21)
    return max(index, 1e-3), density * speed * length / float(eta[1])


def stir_correction(rig: Rig, material: nn.Module | None, density: float, speed: float,
                    orbit_radius: float) -> SliceCorrection:
    """C of ``rig`` (``slice_correction``) for the flow ``material`` makes when its rod stirs at ``speed`` U [m/s]
    on a circle of ``orbit_radius`` [m] in fluid of ``density`` [kg/m³]: at the shear rate U/a, its local flow
    index and Reynolds number ρ U 2a / η (``flow_state``)."""
    rod, cup = rig.rod, rig.cup
    index, reynolds = flow_state(material, speed / rod.radius, density, speed, 2 * rod.radius)
    return slice_correction(cup.radius, cup.fill_height, rod.radius, rod.immersion_depth, orbit_radius,
                            flow_index=index, reynolds=reynolds)


#: A sample counts as stirring where the rod moves faster than this share of its top speed [1].
MOVING_SHARE = 0.05


def stir_scales(position: np.ndarray, velocity: np.ndarray) -> tuple[float, float]:
    """The rod's mean speed U [m/s] over the samples where it stirs (faster than ``MOVING_SHARE`` of its top
    speed) and its mean distance e [m] from the cup's axis there (over every sample when it rests); ``position``
    [m] and ``velocity`` [m/s] (N, 2) about the cup's axis."""
    speed = np.linalg.norm(velocity, axis=1)
    moving = speed > MOVING_SHARE * speed.max() if speed.max() > 0 else np.ones(speed.size, dtype=bool)
    return float(np.mean(speed[moving])), float(np.mean(np.linalg.norm(position[moving], axis=1)))


def trajectory_correction(rig: Rig, material: nn.Module | None, density: float, trajectory,
                          times: np.ndarray) -> SliceCorrection:
    """C of ``rig`` for ``material`` (``stir_correction``) stirred along ``trajectory``
    (``diffstir.trajectory.Trajectory``) at the stir's speed and circle over ``times`` [s]."""
    xy = trajectory.poses(times)[0]
    speed, orbit = stir_scales(xy, np.gradient(xy, times, axis=0))
    return stir_correction(rig, material, density, speed, orbit)
