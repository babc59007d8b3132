"""Search the scripted loader's settings for more tonnes per hour with little spill (CMA-ES).

The loader's targets and thresholds (:class:`hexgym.agents.scripted.LoaderSettings`) were set by
hand. :func:`tune_loader` searches them at once with CMA-ES (the ``cmaes`` package) within their
ranges (``SETTING_RANGES``; all but those for teaching clones, ``TEACHING_SETTINGS``), scoring each candidate
on whole seeded episodes of ``HexLoading-v0``: the tonnes per hour pooled over the episodes, less a
penalty for every percentage point of spill above ``spill_target`` and for contacts (the task's
contact reward). The search starts from the defaults; the best candidate met is saved after every generation, so an
interrupted search (Ctrl-C) keeps its best so far. Episodes run in a :class:`hexgym.parallel.LocalPool`. Select on one
seed set here and measure the result on others (``hexgym scripted --loader-settings`` / ``hexgym evaluate``).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from hexgym.agents.scripted import SETTING_RANGES, TEACHING_SETTINGS, LoaderSettings, run_scripted
from hexgym.checks import check_count, check_range
from hexgym.files import check_output_file
from hexgym.parallel import LocalPool
from hexgym_lab.progress import Progress

MIN_POPULATION = 4  # candidates per generation: fewer, CMA-ES has no covariance to learn from
SPILL_PENALTY = 15.0  # t/h per percentage point of spill above the target
CONTACT_PENALTY = 20.0  # t/h per unit of the task's contact reward per episode (-1: 100 kN s of hard contact)
START_SIGMA = 0.15  # of each setting's range: the search's first step
SEARCHED = tuple(name for name in SETTING_RANGES if name not in TEACHING_SETTINGS)


@dataclass(frozen=True)
class Score:
    """One candidate's figures over the search's episodes."""

    objective: float  # t/h less the penalties
    tonnes_per_hour: float
    spilled_fraction: float
    contact_reward: float  # per episode (<= 0)


def episode_figures(settings: LoaderSettings, seed: int) -> tuple[float, float, float, float]:
    """(delivered t, spilled t, seconds, contact reward) of one whole episode of the loader with ``settings``."""
    from hexgym.envs.loading import HexLoadingEnv

    env = HexLoadingEnv()
    run = run_scripted(env, seed=seed, settings=settings)
    env.close()
    return run["delivered_t"], run["spilled_t"], run["sim_seconds"], run["return_terms"]["contact"]


def _episode_figures(job: tuple[LoaderSettings, int]) -> tuple[float, float, float, float]:
    return episode_figures(*job)


def score(settings: LoaderSettings, seeds: list[int], pool: LocalPool, spill_target: float) -> Score:
    """The objective of ``settings`` over ``seeds`` (episodes run in ``pool``)."""
    runs = pool.map(_episode_figures, [(settings, seed) for seed in seeds])
    delivered, spilled, seconds, contact = (sum(column) for column in zip(*runs, strict=True))
    tph = delivered / (seconds / 3600.0)
    spill = spilled / max(spilled + delivered, 1e-9)
    contact /= len(seeds)
    objective = tph - SPILL_PENALTY * 100.0 * max(0.0, spill - spill_target) + CONTACT_PENALTY * contact
    return Score(objective, tph, spill, contact)


def _to_settings(z: np.ndarray, start: LoaderSettings) -> LoaderSettings:
    """``start`` with the searched settings taken from the search's unit cube."""
    low, high = _bounds()
    values = low + np.clip(z, 0.0, 1.0) * (high - low)
    return replace(start, **{name: float(v) for name, v in zip(SEARCHED, values, strict=True)})


def _to_unit(settings: LoaderSettings) -> np.ndarray:
    """The search's unit-cube point of ``settings``."""
    low, high = _bounds()
    return (np.array([getattr(settings, name) for name in SEARCHED]) - low) / (high - low)


def _bounds() -> tuple[np.ndarray, np.ndarray]:
    """Each searched setting's (low, high)."""
    ranges = np.array([SETTING_RANGES[name] for name in SEARCHED])
    return ranges[:, 0], ranges[:, 1]


def tune_loader(
    out: str | Path,
    seeds: list[int],
    generations: int = 14,
    population: int = 10,
    spill_target: float = 0.05,
    seed: int = 1,
    workers: int | None = None,
    log: Callable[[str], None] | None = None,
    start: LoaderSettings | None = None,
) -> tuple[LoaderSettings, Score]:
    """CMA-ES over the loader's settings from ``start`` (default: the hand-set ones; its settings for teaching are
    held, not searched); the best met is written to ``out`` (JSON) after each generation and returned. Ctrl-C
    stops the workers at once; ``out`` then holds the best of the generations finished (or its old content,
    before the first). ``population``: candidates per generation, at least :data:`MIN_POPULATION`. Progress
    (:mod:`hexgym_lab.progress`): a count of candidates scored, and a line per generation (to ``log`` where
    given)."""
    try:
        from cmaes import CMA
    except ImportError:
        raise ImportError("the loader search needs the cmaes package: pip install 'hexgym[train]'") from None
    check_count("generations", generations)
    check_count("population", population, MIN_POPULATION)
    check_range("spill_target", spill_target, 0.0, 1.0, "(fraction)")
    if not seeds:
        raise ValueError("seeds: give at least one episode seed")
    check_output_file(out, "loader settings")
    start = start or LoaderSettings()
    optimiser = CMA(mean=_to_unit(start), sigma=START_SIGMA, bounds=np.array([[0.0, 1.0]] * len(SEARCHED)),
                    seed=seed, population_size=population)  # fmt: skip
    workers = max(1, min(workers or os.cpu_count() or 1, len(seeds)))
    with LocalPool(workers) as pool, Progress(1 + generations * population, "tune-loader", "candidate") as progress:
        say = log or progress.note
        best = (start, score(start, seeds, pool, spill_target))
        say(f"start: {_describe(best[1])}")
        progress.update(best_t_per_h=f"{best[1].tonnes_per_hour:.1f}")
        for generation in range(generations):
            told = []
            for _ in range(population):
                z = optimiser.ask()
                candidate = _to_settings(z, start)
                result = score(candidate, seeds, pool, spill_target)
                told.append((z, -result.objective))
                if result.objective > best[1].objective:
                    best = (candidate, result)
                progress.update(best_t_per_h=f"{best[1].tonnes_per_hour:.1f}")
            optimiser.tell(told)
            best[0].save(out)  # what was found is kept, however the search ends
            say(f"generation {generation}: best so far {_describe(best[1])} (written to {out})")
    return best


def _describe(s: Score) -> str:
    return (f"objective {s.objective:.1f}, {s.tonnes_per_hour:.1f} t/h, spilled {s.spilled_fraction:.3f}, "
            f"contact {s.contact_reward:.2f} per episode")  # fmt: skip
