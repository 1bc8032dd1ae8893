"""diffstir-import: write the DiffStir authors' recording (data/traj.npy, data/force.npy, config/arguments.json)
as a diffstir recording, and print the inferred frame, the sensor's dead start and the density to pass to a fit.

    diffstir-import source=DiffStir/real_data/castor_oil out=recordings/castor_oil
    diffstir-fit recording=recordings/castor_oil density=960 out=outputs/castor_oil
"""

from __future__ import annotations

from hydra.utils import to_absolute_path
from omegaconf import DictConfig

from diffstir.apps import command
from diffstir.recording.diffstir_authors import ImportSettings, import_diffstir_authors


@command("diffstir-import", "import")
def main(cfg: DictConfig) -> None:
    settings = ImportSettings(sample_rate=float(cfg.sample_rate), mode=str(cfg.sensor.mode),
                              axis=None if cfg.sensor.axis is None else tuple(float(a) for a in cfg.sensor.axis),
                              one_sided=bool(cfg.sensor.one_sided))
    out = to_absolute_path(str(cfg.out))
    imported = import_diffstir_authors(to_absolute_path(str(cfg.source)), out, settings,
                                       overwrite=bool(cfg.overwrite))
    rec = imported.recording
    print(f"traj.npy column {imported.vertical_column} is vertical (the least varying); the cup's axis is the "
          f"least-squares circle's centre ({imported.centre[0]:.4g}, {imported.centre[1]:.4g}) m, radius "
          f"{imported.radius:.4g} m, rms off it {imported.circle_rms:.2g} m")
    print(f"sensor: {settings.mode}{', one-sided' if settings.one_sided else ''} at {settings.sample_rate:g} Hz "
          f"(not stated by the files); it reads 0 for the first {imported.dead_start:.3g} s")
    print(f"wrote {out} ({rec.t.size} rows, {rec.duration:.3g} s); no density measurement in the files: fit with "
          f"density={imported.density:g} (the stated liquid_density, kg/m^3)")


if __name__ == "__main__":
    main()
