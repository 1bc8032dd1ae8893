"""The rectifier's results for docs/rectifier.md: held-out errors in the paper's Table V format, an ablation of
inputs, sizes and the residual form, the refinement on pairs with effects it was not trained on, and a
refined-versus-reference plot.

    python scripts/rectifier_report.py --unseen outputs/pairs-unseen-sensor-c1/pairs.jsonl \
        outputs/pairs-unseen-physics-c1/pairs.jsonl --figure docs/figures/rectifier.png
    python scripts/rectifier_report.py --seeds 1 --near 0.047 0.63   # what the pairs say near one estimate

Every variant of the ablation is trained by ``diffstir.rectifier.training.train`` on the same fluid split as the
shipped checkpoint (seeds 0, 1, 2), and scored on the same held-out fluids.
"""

from __future__ import annotations

import argparse
import json
import math
import warnings
from pathlib import Path

import lightning as L
import numpy as np
import torch

from diffstir.rectifier.apply import load_rectifier, refine
from diffstir.rectifier.training import PairData, evaluate, load_pairs, tensors, train

PAPER = {"preliminary": {"mae_mpas": 348.80, "rmse_mpas": 534.11}, "refined": {"mae_mpas": 55.53, "rmse_mpas": 101.99}}
VARIANTS = {
    "paper 2-8-1 (speed, η_p)": dict(inputs=["mean_stirring_speed", "preliminary_viscosity"], hidden=[8]),
    "1-8-1 (η_p only)": dict(inputs=["preliminary_viscosity"], hidden=[8]),
    "3-8-1 (speed, η_p, ρ)": dict(inputs=["mean_stirring_speed", "preliminary_viscosity", "density_estimate"],
                                  hidden=[8]),
    "2-32-32-1 (speed, η_p)": dict(inputs=["mean_stirring_speed", "preliminary_viscosity"], hidden=[32, 32]),
    "2-8-1 residual (speed, η_p)": dict(inputs=["mean_stirring_speed", "preliminary_viscosity"], hidden=[8],
                                        residual=True),
    "1-8-1 residual (η_p only)": dict(inputs=["preliminary_viscosity"], hidden=[8], residual=True),
}


def row(name: str, errors: dict) -> str:
    p, r = errors["preliminary"], errors["refined"]
    return (f"| {name} | {p['n']} | {p['mae_mpas']:.1f} | {r['mae_mpas']:.1f} | {p['rmse_mpas']:.1f} | "
            f"{r['rmse_mpas']:.1f} | {100 * p['median_relative']:.1f} | {100 * r['median_relative']:.1f} |")


HEADER = ("| pairs | n | MAE before [mPa·s] | MAE after | RMSE before [mPa·s] | RMSE after | "
          "median rel. error before [%] | after [%] |\n|---|---|---|---|---|---|---|---|")


def usable(rectifier, metadata, pairs, checkpoint):
    """Pairs the rectifier refines in ``diffstir-fit`` (``refine`` gives a value: the estimator matches, viscosity
    is resolved and the inputs lie in the training range; no extrapolation)."""
    return [p for p in pairs if refine(rectifier, metadata, {
        "viscosity": p["preliminary_viscosity"], "mean_stirring_speed": p["mean_stirring_speed"],
        "resolves": p["resolves"], "estimator": p["estimator_config"]}, p["density_estimate"], checkpoint)["value"]
        is not None]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoint", default="checkpoints/rectifier/rectifier.ckpt")
    parser.add_argument("--card", default="checkpoints/rectifier/card.json")
    parser.add_argument("--unseen", nargs="*", default=[], help="pairs.jsonl files of effects not trained on")
    parser.add_argument("--figure", default=None, help="where to save the refined-versus-reference plot")
    parser.add_argument("--json", default=None, help="where to save every number as JSON")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--near", type=float, nargs=2, metavar=("SPEED", "ETA"), default=None,
                        help="also print reference / preliminary by law over the resolving pairs near this mean "
                             "stirring speed [m/s] and preliminary viscosity [Pa s] (within a factor 1.3 and 2)")
    args = parser.parse_args()
    warnings.filterwarnings("ignore", ".*does not have many workers.*")
    torch.set_num_threads(1)
    card = json.loads(Path(args.card).read_text())
    rectifier, metadata = load_rectifier(args.checkpoint)
    split, train_cfg = card["config"]["split"], card["config"]["train"]
    data = PairData(card["config"]["data"], list(rectifier.inputs), val_fraction=split["val_fraction"],
                    test_fraction=split["test_fraction"], batch_size=train_cfg["batch_size"], seed=split["seed"])
    results = {"checkpoint": {"test": evaluate(rectifier, data.test)}, "ablation": {}, "unseen": {}}

    print(f"## Held-out fluids ({card['fluids']['test']} fluids never seen in training)\n")
    print(HEADER)
    print(row("shipped checkpoint, test fluids", results["checkpoint"]["test"]))
    for law in sorted({p["law"] for p in data.test}):
        subset = [p for p in data.test if p["law"] == law]
        results["checkpoint"][law] = evaluate(rectifier, subset)
        print(row(f"  of which {law}", results["checkpoint"][law]))
    print(f"| the paper (six real fluids) | 6 | {PAPER['preliminary']['mae_mpas']} | {PAPER['refined']['mae_mpas']} | "
          f"{PAPER['preliminary']['rmse_mpas']} | {PAPER['refined']['rmse_mpas']} | - | - |")

    print(f"\n## Ablation (test fluids; mean ± std over seeds 0-{args.seeds - 1})\n")
    print("| network | MAE after [mPa·s] | RMSE after [mPa·s] | median rel. error after [%] |\n|---|---|---|---|")
    for name, variant in VARIANTS.items():
        variant_data = PairData(card["config"]["data"], variant["inputs"], val_fraction=split["val_fraction"],
                                test_fraction=split["test_fraction"], batch_size=train_cfg["batch_size"],
                                seed=split["seed"])
        scores = []
        for seed in range(args.seeds):
            L.seed_everything(seed, verbose=False)
            module, _ = train(variant_data, hidden=variant["hidden"], learning_rate=train_cfg["learning_rate"],
                              epochs=train_cfg["epochs"], residual=variant.get("residual", False))
            scores.append(evaluate(module.rectifier, variant_data.test)["refined"])
        results["ablation"][name] = scores
        stat = {k: (np.mean([s[k] for s in scores]), np.std([s[k] for s in scores]))
                for k in ("mae_mpas", "rmse_mpas", "median_relative")}
        print(f"| {name} | {stat['mae_mpas'][0]:.1f} ± {stat['mae_mpas'][1]:.1f} | {stat['rmse_mpas'][0]:.1f} ± "
              f"{stat['rmse_mpas'][1]:.1f} | {100 * stat['median_relative'][0]:.1f} ± "
              f"{100 * stat['median_relative'][1]:.1f} |")

    if args.near:
        speed, eta = args.near
        near = [p for p in data.all_pairs if p["resolves"] and abs(math.log(p["mean_stirring_speed"] / speed)) <=
                math.log(1.3) and abs(math.log(p["preliminary_viscosity"] / eta)) <= math.log(2.0)]
        print(f"\n## Pairs near U = {speed:g} m/s, η_p = {eta:g} Pa·s ({len(near)} resolving pairs, all splits)\n")
        print("| law | pairs | median η_ref / η_p |\n|---|---|---|")
        for law in sorted({p["law"] for p in near}):
            ratios = [p["reference_viscosity"] / p["preliminary_viscosity"] for p in near if p["law"] == law]
            print(f"| {law} | {len(ratios)} | {np.median(ratios):.2f} |")
        results["near"] = {"speed": speed, "eta": eta, "pairs": len(near)}

    if args.unseen:
        print("\n## Effects the rectifier was not trained on (shipped checkpoint)\n")
        print(HEADER)
        for path in args.unseen:
            pairs = load_pairs(path)
            refined = usable(rectifier, metadata, pairs, args.checkpoint)
            results["unseen"][path] = {"pairs": len(pairs), "refined": len(refined),
                                       "errors": evaluate(rectifier, refined) if refined else None}
            if refined:
                print(row(f"{Path(path).parent.name} ({len(pairs) - len(refined)} of {len(pairs)} not refined)",
                          results["unseen"][path]["errors"]))

    if args.figure:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        x, y = tensors(data.test, rectifier.inputs)
        with torch.no_grad():
            refined = rectifier(x.float()).double().numpy()
        prelim = np.array([p["preliminary_viscosity"] for p in data.test])
        fig, ax = plt.subplots(figsize=(5, 4.5))
        ax.loglog(y, prelim, ".", ms=3, alpha=0.5, label="preliminary (ladder, 5 mm)")
        ax.loglog(y, refined, ".", ms=3, alpha=0.7, label="refined (2-8-1)")
        lims = [float(y.min()) / 1.5, float(y.max()) * 1.5]
        ax.plot(lims, lims, "k-", lw=0.8)
        ax.set_xlabel("reference viscosity [Pa·s]")
        ax.set_ylabel("estimate [Pa·s]")
        ax.set_title("held-out fluids")
        ax.legend()
        fig.tight_layout()
        Path(args.figure).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(args.figure, dpi=120)
        print(f"\nwrote {args.figure}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
