"""Rank the rheology laws on every bundled flow curve and print a markdown table (for docs/rheology.md).

Usage: python3 scripts/rank_flow_curves.py   (with diffstir installed, or PYTHONPATH set to the repository root)
"""

from diffstir.rheology.flow_curve import bundled_flow_curves, rank_laws


def format_params(fit) -> str:
    parts = []
    for key, value in fit.params.items():
        unit = "" if fit.units[key] == "1" else f" {fit.units[key]}"
        flag = "" if fit.identifiable[key] else "†"
        parts.append(f"{key} = {value:.3g}{unit}{flag}")
    return ", ".join(parts)


def main() -> None:
    print("| curve | N | best law (BIC) | parameters | rms log residual | BIC | runner-up (ΔBIC) |")
    print("|---|---|---|---|---|---|---|")
    for key, curve in bundled_flow_curves().items():
        best, second = rank_laws(curve)[:2]
        print(
            f"| {key} | {best.n_points} | {best.law.name} | {format_params(best)} | "
            f"{best.rms_log_residual:.3f} | {best.bic:.1f} | {second.law.name} (+{second.bic - best.bic:.1f}) |"
        )


if __name__ == "__main__":
    main()
