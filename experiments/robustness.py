"""The loaders and the shipped agent on HexLoading-v0 off its nominal conditions: the robustness table.

Runs ``hexgym evaluate``'s :func:`hexgym_lab.agents.evaluate.evaluate` for each policy (the hand-set scripted
loader, the tuned loader ``training/loader_tuned.json``, the shipped agent) under each condition (nominal; the pile
and truck outside their training ranges, ``site_ranges="shifted"``; a material 25 % denser,
``material_density_scale=1.25``; an engine 10 % weaker, ``engine_power_scale=0.9``) on the same seeds, and prints a
markdown table: success, t/h and its change from nominal, spilled fraction, mean cycle time. Nothing is tuned.

    python experiments/robustness.py --episodes 20 --seed 2000 --json out/robustness.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from hexgym_lab.agents.evaluate import evaluate

REPO = Path(__file__).resolve().parent.parent
POLICIES = {
    "scripted loader": ("scripted", None),
    "tuned loader": ("scripted", REPO / "training" / "loader_tuned.json"),
    "shipped agent": ("shipped", None),
}
CONDITIONS = {
    "nominal": {},
    "shifted layout": {"site_ranges": "shifted"},
    "density x1.25": {"material_density_scale": 1.25},
    "engine x0.9": {"engine_power_scale": 0.9},
}


def measure(episodes: int, seed: int, workers: int, policies: list[str], conditions: list[str]) -> list[dict]:
    """Every policy of ``policies`` under every condition of ``conditions`` on seeds ``seed``..``seed+episodes-1``:
    a row each."""
    rows = []
    for name in policies:
        spec, settings = POLICIES[name]
        nominal = None
        for condition in conditions:
            kwargs = CONDITIONS[condition]
            r = evaluate(spec, episodes=episodes, seed=seed, env_kwargs=dict(kwargs), workers=workers,
                         loader_settings=settings)  # fmt: skip
            nominal = r["tonnes_per_hour"] if condition == "nominal" else nominal
            rows.append({
                "policy": name, "condition": condition, "success_rate": r["success_rate"],
                "tonnes_per_hour": r["tonnes_per_hour"], "tonnes_per_hour_ci95": r["tonnes_per_hour_ci95"],
                "tph_change_percent": 100.0 * (r["tonnes_per_hour"] / nominal - 1.0) if nominal else None,
                "spilled_fraction": r["spilled_fraction"], "mean_cycle_time_s": r["mean_cycle_time_s"],
                "episodes": r["episodes"], "seed": seed,
            })  # fmt: skip
            print(json.dumps(rows[-1]), flush=True)
    return rows


def table(rows: list[dict]) -> str:
    """The rows as a markdown table."""
    lines = ["| policy | condition | success | t/h | t/h vs nominal | spilled | cycle |",
             "|--------|-----------|---------|-----|----------------|---------|-------|"]  # fmt: skip
    for r in rows:
        cycle = f"{r['mean_cycle_time_s']:.1f} s" if r["mean_cycle_time_s"] is not None else "-"
        change = "-" if r["condition"] == "nominal" else f"{r['tph_change_percent']:+.1f} %"
        lines.append(f"| {r['policy']} | {r['condition']} | {r['success_rate']:.2f} | {r['tonnes_per_hour']:.1f} | "
                     f"{change} | {r['spilled_fraction']:.3f} | {cycle} |")  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    """Measure and print the table (and write the rows to ``--json``)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=20, help="episodes per policy and condition (default: 20)")
    parser.add_argument("--seed", type=int, default=2000, help="first seed (default: 2000, held out)")
    parser.add_argument("--workers", type=int, default=1, help="processes per evaluation (default: 1)")
    parser.add_argument("--policies", nargs="+", choices=list(POLICIES), default=list(POLICIES), metavar="NAME",
                        help=f"which of {list(POLICIES)} (default: all)")  # fmt: skip
    parser.add_argument("--conditions", nargs="+", choices=list(CONDITIONS), default=list(CONDITIONS), metavar="NAME",
                        help=f"which of {list(CONDITIONS)} (default: all; nominal gives the change)")  # fmt: skip
    parser.add_argument("--json", default=None, help="also write the rows to this JSON file")
    args = parser.parse_args()
    rows = measure(args.episodes, args.seed, args.workers, args.policies, args.conditions)
    print(table(rows))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
