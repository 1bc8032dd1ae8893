"""diffstir-simulate: stir a fluid in the simulated rig and write the force on the rod (CSV and plot).

    diffstir-simulate law=cross sim=paper3d stir.speed=0.05 out=outputs/cross
"""

from __future__ import annotations

from pathlib import Path

import hydra
from hydra.utils import instantiate
from omegaconf import DictConfig

from diffstir.apps import CONF_DIR
from diffstir.mpm import StirringSimulator
from diffstir.plots import plot_forces
from diffstir.trajectory import circle


@hydra.main(config_path=CONF_DIR, config_name="simulate", version_base="1.3")
def main(cfg: DictConfig) -> None:
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    rig, sim_config, law = instantiate(cfg.rig), instantiate(cfg.sim), instantiate(cfg.law)
    trajectory = circle(cfg.stir.radius, cfg.stir.speed, cfg.stir.duration, ramp_time=cfg.stir.ramp_time)
    simulator = StirringSimulator(law, rig, sim_config, density=cfg.density)
    result = simulator(trajectory)
    csv, png = plot_forces(result, law, out)
    print(f"{len(result.times)} steps of {result.dt:.3g} s; wrote {csv} and {png}")


if __name__ == "__main__":
    main()
