"""diffstir-simulate: stir a fluid in the simulated rig and write the force on the rod (CSV and plot).

    diffstir-simulate law=cross sim=paper3d stir.speed=0.05 out=outputs/cross
"""

from __future__ import annotations

from pathlib import Path

from hydra.utils import instantiate, to_absolute_path
from omegaconf import DictConfig

from diffstir.apps import Run, command
from diffstir.errors import ConfigError
from diffstir.mpm import StirringSimulator
from diffstir.plots import plot_forces
from diffstir.trajectory import circle


@command("diffstir-simulate", "simulate")
def main(cfg: DictConfig) -> None:
    rig, sim_config, law = instantiate(cfg.rig), instantiate(cfg.sim), instantiate(cfg.law)
    try:
        trajectory = circle(cfg.stir.radius, cfg.stir.speed, cfg.stir.duration, ramp_time=cfg.stir.ramp_time)
    except ValueError as error:
        raise ConfigError(f"stir: {error}") from None
    out = Run.writes(Path(to_absolute_path(str(cfg.out))))
    simulator = StirringSimulator(law, rig, sim_config, density=cfg.density)
    result = simulator(trajectory)
    csv, png = plot_forces(result, law, out)
    print(f"{len(result.times)} steps of {result.dt:.3g} s; wrote {csv} and {png}")


if __name__ == "__main__":
    main()
