"""diffstir-pairs: make one shard of the rectifier's training pairs, or gather the shards (``collect=true``).

    diffstir-pairs -m shard='range(25)' hydra/launcher=joblib hydra.launcher.n_jobs=2
    diffstir-pairs collect=true
"""

from __future__ import annotations

import sys

import torch
from hydra.utils import instantiate, to_absolute_path
from omegaconf import DictConfig, OmegaConf

from diffstir.apps import check_processes, command
from diffstir.errors import ConfigError, check_at_least
from diffstir.rectifier.pairs import collect, run_shard


@command("diffstir-pairs", "pairs")
def main(cfg: DictConfig) -> None:
    check_processes(cfg)
    check_at_least("shard", cfg.shard, 0)
    check_at_least("retries", cfg.retries, 0)
    design = OmegaConf.to_object(cfg.pairs.design).design()  # a DesignSettings, checked (its schema)
    if not cfg.collect and cfg.shard >= design.shards:
        raise ConfigError(f"shard = {cfg.shard}; expected 0 <= shard < {design.shards} (the design's programmes x "
                          "densities)")
    torch.set_num_threads(int(cfg.threads))
    out = to_absolute_path(str(cfg.out))
    if cfg.collect:
        manifest = collect(design, out)
        print(f"{manifest['pairs']} of {manifest['expected_pairs']} pairs from {manifest['fluids']} fluids; "
              f"wrote {out}/pairs.jsonl and {out}/manifest.json")
        if not manifest["complete"]:
            short = [s["shard"] for s in manifest["shards"] if s["missing_fluids"] or s["failed"]]
            sys.exit(f"incomplete: shards {short} lack pairs (failed fluids: {manifest['failed']}); "
                     "rerun their shards to resume")
        return
    report = run_shard(design, int(cfg.shard), out, truth_config=instantiate(cfg.truth),
                       estimator_config=instantiate(cfg.estimator), retries=int(cfg.retries))
    print(f"shard {report['shard']}: {report['fluids']} of {report['expected_fluids']} fluids")
    if report["failed"]:
        sys.exit(f"shard {report['shard']}: fluids {report['failed']} failed after {cfg.retries + 1} attempts "
                 "(see shards/*.failures.jsonl); rerun the shard to retry them")


if __name__ == "__main__":
    main()
