"""Levers measured on validation bouts or levels, for every experiment that has them:
``python -m wmthesis validate EXPERIMENT LEVER ... [--variant V] [--seeds 0,1] [--count N]``.

A lever is a change that a choice may adopt: the Sokoban agent's config (trained in a folder of its
own unless it changes the search alone), the planner that ends in a fitted PlaNet value, or the
World Models controller's recipe (a variant of ``boxing-wm``). Each is played on the experiment's
validation split only (Boxoban's valid 000-001, the value's validation bouts, ``boxing-wm``'s
validation seeds 10-12), never on what the results report, and saved as it goes: a run cut off
plays only the rest.
The levers that lost, with their numbers, are in ``docs/findings/EXPERIMENT.md``.
"""
from __future__ import annotations

import concurrent.futures

from wmthesis.experiments.planet_boxing_value import (PLANNER_LEVERS as BOXING_LEVERS,
                                                      validate_planners as validate_boxing)
from wmthesis.experiments.planet_freeway_value import (PLANNER_LEVERS as FREEWAY_LEVERS,
                                                       validate_planners as validate_freeway)
from wmthesis.experiments import reproduce
from wmthesis.experiments.sokoban_search import LEVERS as SOKOBAN_LEVERS, validate as validate_sokoban
from wmthesis.planet.value_tables import planner_lever_rows
from wmthesis.sokoban_search.tables import solved_line
from wmthesis.utils import check_choice, process_pool
from wmthesis.variants import FINDINGS
from wmthesis.world_models.variants import BOXING_WM, VALIDATION_SEEDS as BOXING_WM_SEEDS

# Experiment -> its levers (name -> changes).
LEVERS = {"sokoban-search": {name: SOKOBAN_LEVERS.changes(name) for name in SOKOBAN_LEVERS},
          "planet-boxing-value": BOXING_LEVERS, "planet-freeway-value": FREEWAY_LEVERS,
          "boxing-wm": {name: BOXING_WM.changes(name) for name in BOXING_WM}}


def check_levers(experiment: str, levers: list[str]) -> None:
    """Refuse an experiment without levers, or an unknown (or removed) lever, listing the valid ones."""
    check_choice("experiment with levers", experiment, tuple(LEVERS))
    if not levers:
        raise ValueError(f"name at least one lever of {experiment}; valid: {', '.join(LEVERS[experiment])}")
    for lever in levers:
        if lever not in LEVERS[experiment]:
            raise ValueError(f"unknown lever {lever!r} of {experiment}; valid: {', '.join(LEVERS[experiment])} "
                             f"(levers no longer in the code, with their numbers: {FINDINGS}/{experiment}.md)")


def validate(experiment: str, levers: list[str], *, profile: str | None = None, seeds=(0,), variant: str | None = None,
             count: int | None = None, workers: int | None = None, progress: bool = True) -> dict[int, dict]:
    """Each of ``levers`` of ``experiment`` on its validation split, for each of ``seeds``: seed ->
    lever -> its result (Sokoban: :func:`~wmthesis.experiments.sokoban_search.validate`'s; a PlaNet
    value: the planner's config and scores, ``validate_planners``). ``count``: levels (Sokoban) or
    bouts (a value) each, the profile's by default; ``variant``: the value run whose agent the
    planners end in. A value's bouts of every seed share one pool of ``workers`` processes (two by
    default), seed after seed: on a machine with more cores, pass its count."""
    check_levers(experiment, levers)
    if experiment == "boxing-wm":
        wrong = [seed for seed in seeds if seed not in BOXING_WM_SEEDS]
        if wrong:  # the seeds a recipe is reported on never choose one
            raise ValueError(f"boxing-wm's recipes are chosen on seeds {', '.join(map(str, BOXING_WM_SEEDS))}, "
                             f"not {', '.join(map(str, wrong))}")
        return {seed: {lever: reproduce("boxing-wm", profile, seed, lever, progress) for lever in levers}
                for seed in seeds}
    if experiment == "sokoban-search":
        if variant is not None:
            raise ValueError("sokoban-search's levers are variants of its agent: name them as levers, not --variant")
        return {seed: {lever: validate_sokoban(lever, profile, seed, count, progress) for lever in levers}
                for seed in seeds}
    validate_planners = validate_boxing if experiment == "planet-boxing-value" else validate_freeway
    with process_pool(workers) as pool, concurrent.futures.ThreadPoolExecutor(max(1, len(seeds))) as threads:
        futures = {seed: threads.submit(validate_planners, profile, seed, tuple(levers), count, progress,
                                        variant=variant, executor=pool) for seed in seeds}
        return {seed: future.result() for seed, future in futures.items()}


def lever_lines(experiment: str, results: dict[str, dict]) -> list[str]:
    """One seed's results as lines: each lever's solve rates and costs (Sokoban), or the planner
    levers' table rows paired against the first (a value)."""
    if experiment == "sokoban-search":
        return [solved_line(lever, result["rows"]) for lever, result in results.items()]
    if experiment == "boxing-wm":
        return [f"{lever}: {m['score']['mean']:.1f} ± {m['score']['std']:.1f} over {m['score']['episodes']} bouts, "
                f"{m.get('first_run_wall_seconds', m['wall_seconds']) / 60:.0f} min" for lever, m in results.items()]
    return [" | ".join(row) for row in planner_lever_rows(results, LEVERS[experiment])]


__all__ = ["LEVERS", "check_levers", "validate", "lever_lines"]
