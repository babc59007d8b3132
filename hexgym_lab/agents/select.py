"""``hexgym select``: keep the checkpoint of a training run that loads most on selection seeds.

A fine-tune's deterministic t/h moves by 10-20 % between checkpoints 100k steps apart (a policy that stalls in
one episode of twenty loses a tenth of its t/h), so a recipe keeps the checkpoint with the highest mean t/h over
seed sets chosen for selection, never the seeds its figures are reported on.
"""

from __future__ import annotations

import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hexgym.agents.policy_files import normalizer_path
from hexgym.checks import check_count, check_seed
from hexgym.files import atomic_paths, check_input_dir, check_output_file
from hexgym_lab.agents.evaluate import evaluate
from hexgym_lab.agents.training import checkpoints
from hexgym_lab.progress import Progress

SELECTION_SEEDS = ((0, 20), (100, 10))  # (first seed, episodes): the shipped agent's selection sets


def select_checkpoint(
    directory: str | Path, out: str | Path, seed_sets: Sequence[tuple[int, int]] = SELECTION_SEEDS
) -> list[dict[str, Any]]:
    """Evaluate every checkpoint in ``directory`` on ``seed_sets`` ((first seed, episodes) each) and copy the one
    with the highest mean t/h over the sets to ``out`` (its normaliser beside it, atomically); a row per
    checkpoint (its steps, t/h, spill and success per set, the mean t/h, whether it was kept)."""
    check_input_dir(directory, "checkpoint directory")
    check_output_file(out, "selected model")
    if not seed_sets:
        raise ValueError("seed sets: give at least one (first seed, episodes)")
    for first, episodes in seed_sets:
        check_seed("seed", first)
        check_count("episodes", episodes)
    found = checkpoints(directory)
    if not found:
        raise ValueError(f"{directory}: no checkpoints (rl_model_<steps>_steps.zip) to select from")
    rows = []
    with Progress(len(found), "select", "checkpoint") as progress:
        for steps, path in found:
            sets = [evaluate(str(path), episodes=n, seed=first) for first, n in seed_sets]
            row = {"checkpoint": str(path), "steps": steps,
                   "tonnes_per_hour": [s["tonnes_per_hour"] for s in sets],
                   "spilled_fraction": [s["spilled_fraction"] for s in sets],
                   "success_rate": [s["success_rate"] for s in sets]}  # fmt: skip
            row["mean_tonnes_per_hour"] = sum(row["tonnes_per_hour"]) / len(sets)
            rows.append(row)
            progress.note(f"{row['steps']} steps: " + ", ".join(f"{t:.1f}" for t in row["tonnes_per_hour"])
                          + f" t/h (mean {row['mean_tonnes_per_hour']:.1f})")  # fmt: skip
            progress.update()
    best = max(rows, key=lambda r: r["mean_tonnes_per_hour"])
    for row in rows:
        row["selected"] = row is best
    source = Path(best["checkpoint"])
    with atomic_paths(out, normalizer_path(out)) as (model_tmp, normalizer_tmp):
        shutil.copyfile(source, model_tmp)
        shutil.copyfile(normalizer_path(source), normalizer_tmp)
    return rows
