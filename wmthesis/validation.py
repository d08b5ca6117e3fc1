"""Levers measured on validation bouts or levels, for every experiment that declares them:
``python -m wmthesis validate EXPERIMENT LEVER ... [--variant V] [--seeds 0,1] [--count N]``.

A lever is a change that a choice may adopt: the Sokoban agent's config (trained in a folder of its
own unless it changes the search alone), the planner that ends in a fitted PlaNet value, or the
World Models controller's recipe (a variant of ``boxing-wm``). Each is played on the experiment's
validation split only (Boxoban's valid 000-001, the value's validation bouts, ``boxing-wm``'s
validation seeds 10-12), never on what the results report, and saved as it goes: a run cut off
plays only the rest. An experiment's levers are its declaration's
(:class:`~wmthesis.variants.Levers`).
The levers that lost, with their numbers, are in ``docs/findings/EXPERIMENT.md``.
"""
from __future__ import annotations

from wmthesis.declarations import NAMES, DECLARED, Declared, resolve
from wmthesis.utils import check_choice, over_seeds
from wmthesis.variants import FINDINGS, Levers

# ---------------------------------------------------------------------------- the lever sets
def validate_recipes(levers, *, profile=None, seeds=(0,), variant=None, count=None, workers=None,
                     progress: bool = True) -> dict[int, dict]:
    """boxing-wm: each controller recipe of ``levers`` (its variants) trained on each of ``seeds``,
    which must be its validation seeds (the reported seeds never choose a recipe)."""
    from wmthesis.experiments import reproduce
    from wmthesis.world_models.variants import VALIDATION_SEEDS

    wrong = [seed for seed in seeds if seed not in VALIDATION_SEEDS]
    if wrong:
        raise ValueError(f"boxing-wm's recipes are chosen on seeds {', '.join(map(str, VALIDATION_SEEDS))}, "
                         f"not {', '.join(map(str, wrong))}")
    return {seed: {lever: reproduce(NAMES.boxing_wm, profile, seed, lever, progress) for lever in levers} for seed in seeds}


def recipe_lines(results: dict[str, dict]) -> list[str]:
    return [f"{lever}: {m['score']['mean']:.1f} ± {m['score']['std']:.1f} over {m['score']['episodes']} bouts, "
            f"{m.get('first_run_wall_seconds', m['wall_seconds']) / 60:.0f} min" for lever, m in results.items()]


def validate_agent_levers(levers, *, profile=None, seeds=(0,), variant=None, count=None, workers=None,
                          progress: bool = True) -> dict[int, dict]:
    """sokoban-search: each lever (a change to the pixel agent) on each seed's validation levels."""
    import importlib

    if variant is not None:
        raise ValueError("sokoban-search's levers are variants of its agent: name them as levers, not --variant")
    recipe = importlib.import_module("wmthesis.experiments.sokoban_search")
    return {seed: {lever: recipe.validate(lever, profile, seed, count, progress) for lever in levers} for seed in seeds}


def agent_lever_lines(results: dict[str, dict]) -> list[str]:
    from wmthesis.sokoban_search.tables import solved_line

    return [solved_line(lever, result["rows"]) for lever, result in results.items()]


def planner_levers(module: str, levers: dict) -> Levers:
    """A value experiment's planner ``levers`` (name -> the planner's changes), measured by
    ``module``'s ``validate_planners`` (imported when they run), every seed's validation bouts in
    one pool of ``workers`` processes."""
    import importlib

    def run(names, *, profile=None, seeds=(0,), variant=None, count=None, workers=None, progress=True):
        recipe = importlib.import_module(module)
        return over_seeds(lambda seed, pool: recipe.validate_planners(profile, seed, tuple(names), count, progress,
                                                                      variant=variant, executor=pool), seeds, workers)

    def lines(results):
        from wmthesis.value.tables import planner_lever_rows

        return [" | ".join(row) for row in planner_lever_rows(results, levers)]

    return Levers(levers, run, lines)


def boxing_wm_levers() -> Levers:
    from wmthesis.world_models.variants import BOXING_WM

    return Levers({name: BOXING_WM.changes(name) for name in BOXING_WM}, validate_recipes, recipe_lines)


def sokoban_levers() -> Levers:
    from wmthesis.sokoban_search.variants import LEVERS

    return Levers({name: LEVERS.changes(name) for name in LEVERS}, validate_agent_levers, agent_lever_lines)


def boxing_value_levers() -> Levers:
    from wmthesis.value.variants import BOXING_PLANNER_LEVERS

    return planner_levers("wmthesis.experiments.planet_boxing_value", BOXING_PLANNER_LEVERS)


def freeway_value_levers() -> Levers:
    from wmthesis.value.variants import FREEWAY_PLANNER_LEVERS

    return planner_levers("wmthesis.experiments.planet_freeway_value", FREEWAY_PLANNER_LEVERS)


WITH_LEVERS = Declared(lambda d: d.levers is not None)


def levers_of(experiment: str) -> Levers:
    """``experiment``'s :class:`~wmthesis.variants.Levers` (its declaration names the function that
    makes them); ValueError naming the experiments that have some."""
    check_choice("experiment with levers", experiment, WITH_LEVERS)
    return resolve(DECLARED[experiment].levers)()


def check_levers(experiment: str, levers: list[str]) -> None:
    """Refuse an experiment without levers, or an unknown (or removed) lever, listing the valid ones."""
    names = levers_of(experiment).changes
    valid = "; ".join(names)
    if not levers:
        raise ValueError(f"name at least one lever of {experiment}; valid: {valid}")
    for lever in levers:
        if lever not in names:
            raise ValueError(f"unknown lever {lever!r} of {experiment}; valid: {valid} "
                             f"(levers no longer in the code, with their numbers: {FINDINGS}/{experiment}.md)")


def validate(experiment: str, levers: list[str], *, profile: str | None = None, seeds=(0,), variant: str | None = None,
             count: int | None = None, workers: int | None = None, progress: bool = True) -> dict[int, dict]:
    """Each of ``levers`` of ``experiment`` on its validation split, for each of ``seeds``: seed ->
    lever -> its result. ``count``: levels (Sokoban) or bouts (a value) each, the profile's by
    default; ``variant``: the value run whose agent the planners end in; ``workers``: the
    processes a value's bouts share (two by default)."""
    check_levers(experiment, levers)
    return levers_of(experiment).run(levers, profile=profile, seeds=seeds, variant=variant, count=count,
                                     workers=workers, progress=progress)


def lever_lines(experiment: str, results: dict[str, dict]) -> list[str]:
    """One seed's results as lines, as the experiment says them."""
    return levers_of(experiment).lines(results)


__all__ = ["WITH_LEVERS", "levers_of", "check_levers", "validate", "lever_lines", "planner_levers", "validate_recipes",
           "validate_agent_levers", "boxing_wm_levers", "sokoban_levers", "boxing_value_levers", "freeway_value_levers"]
