"""Check the paper's Table I (density validation) against the uncertainty its own stated resolutions imply.

Prints the markdown table of docs/density.md. Run from the repository root:

    PYTHONPATH=. python3 scripts/density_table.py

The paper's rod: diameter 2.5 cm, immersed 8 cm; force resolution 0.005 N; depth ruler 0.1 mm.
"""

from __future__ import annotations

import math

from diffstir.density import estimate_density, resolution_std
from diffstir.recording import DensityMeasurement
from diffstir.recording.format import GRAVITY

ROD_RADIUS = 0.0125  # m (diameter 2.5 cm)
DEPTH = 0.080  # m
FORCE_RESOLUTION = 0.005  # N
DEPTH_RESOLUTION = 1e-4  # m
DIAMETER_RESOLUTION = 1e-3  # m: "2.5 cm" is stated to the millimetre

# Table I: fluid, rho_est, rho_ref [kg/m³], bias [%] as printed
TABLE_I = [
    ("F60 Syrup", 1333.7, 1290.0, 3.39),
    ("Diluted Syrup", 1065.8, 1139.3, -6.45),
    ("Water", 915.1, 1000.0, -8.49),
    ("Starch A", 1641.6, 1563.7, 4.98),
    ("Starch B", 1814.8, 1845.5, -1.66),
]


def main() -> None:
    volume_g = math.pi * ROD_RADIUS**2 * DEPTH * GRAVITY  # N per kg/m³
    radius_std = resolution_std(DIAMETER_RESOLUTION) / 2
    print("| fluid | rho_est | rho_ref | bias, paper | bias, recomputed | G - R [N] | sigma, forces + depth "
          "| bias / sigma | bias as a G - R error [N] | in 0.005 N steps | sigma, + diameter "
          "| bias / sigma, + diameter |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for fluid, est, ref, printed in TABLE_I:
        bias = est / ref - 1
        buoyancy = est * volume_g
        m = DensityMeasurement(rod_weight=buoyancy, immersed_reading=0.0, immersed_depth=DEPTH)  # only G - R enters
        readings = estimate_density(m, rod_radius=ROD_RADIUS, force_resolution=FORCE_RESOLUTION,
                                    depth_resolution=DEPTH_RESOLUTION)
        with_diameter = estimate_density(m, rod_radius=ROD_RADIUS, force_resolution=FORCE_RESOLUTION,
                                         depth_resolution=DEPTH_RESOLUTION, radius_uncertainty=radius_std)
        force_error = (est - ref) * volume_g
        print(f"| {fluid} | {est:.1f} | {ref:.1f} | {printed:+.2f} % | {100 * bias:+.3f} % | {buoyancy:.4f} "
              f"| {100 * readings.relative_std:.2f} % | {bias / readings.relative_std:+.1f} "
              f"| {force_error:+.4f} | {force_error / FORCE_RESOLUTION:+.1f} "
              f"| {100 * with_diameter.relative_std:.2f} % | {bias / with_diameter.relative_std:+.1f} |")


if __name__ == "__main__":
    main()
