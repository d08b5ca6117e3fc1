"""The thesis's experiments end to end, as used by ``python -m wmthesis reproduce NAME``: one recipe
module each, declared in :mod:`wmthesis.declarations` (its section, variants, what it builds on,
its agent). :mod:`wmthesis.runs` holds what the recipes share to write their results.

Each experiment writes its artifacts (stores, checkpoints) under ``data/<profile>/<name>/``
and its results (figures, ``metrics.json``, rerun recordings) under
``data/results/<name>/<profile>-seed<seed>/`` (PlaNet's: one subfolder per variant).
Every step skips work whose artifact exists, so re-running resumes.
"""
from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
from typing import Callable

from wmthesis.config import EXPERIMENTS, profile_name
from wmthesis.declarations import NAMES, Declaration, Declared, Of, resolve
from wmthesis.experiments.alphazero import RECORDING_STEPS, boxing_wm_alphazero
from wmthesis.experiments.planet import PLANET_GAMES, planet_experiment, planet_variants
from wmthesis.experiments.planet_boxing import planet_boxing_agent, planet_boxing_study
from wmthesis.experiments.planet_boxing_value import planet_boxing_value
from wmthesis.experiments.planet_freeway_value import planet_freeway_value
from wmthesis.experiments.planning_budget import planning_budget
from wmthesis.experiments.sokoban_search import sokoban_search
from wmthesis.experiments.sokoban_world_models import (SOKOBAN_FRAME_SIZE, SOKOBAN_WM_CONTROLLERS,
                                                       SOKOBAN_WM_VARIANTS, sokoban_wm_configs,
                                                       sokoban_world_models)
from wmthesis.experiments.world_models import boxing_world_models
from wmthesis.experiments.world_models_dream import boxing_wm_dream
from wmthesis.alphazero.variants import VARIANTS as ALPHAZERO_VARIANTS
from wmthesis.world_models.variants import BOXING_WM
from wmthesis.planet.profiles import ATARI_CHANGES, SOKOBAN_CHANGES
from wmthesis.planet.search_run import planet_boxing_search
from wmthesis.value.variants import VALUE_VARIANTS as BOXING_VALUE_VARIANTS
from wmthesis.planet.variants import REGISTRIES as PLANET_REGISTRIES
from wmthesis.schemas import check_metrics
from wmthesis.runs import read_json, register_runner, results_folder
from wmthesis.utils import check_choice, check_seed, worker_init
from wmthesis.variants import no_variant

# Experiment -> its recipe, each called ``recipe(profile, seed, variant, progress)``, and its registry of
# variants (:mod:`wmthesis.variants`), for those that have them: from the declarations.
RECIPES = Of(lambda d: resolve(d.recipe))
VARIANTS = Of(Declaration.registry, lambda d: d.variants is not None)
NO_VARIANTS = Declared(lambda d: d.variants is None)
# Experiment -> the variant its default run's metrics name (None: it names none, its runs keep the
# experiment's own folders), for the experiments whose default has a name in its metrics.
DEFAULT_RESULTS = {**{name: registry.default.name for name, registry in PLANET_REGISTRIES.items()},
                   NAMES.planet_boxing_value: BOXING_VALUE_VARIANTS.folder_name(None), NAMES.planet_freeway_value: None,
                   NAMES.boxing_wm: BOXING_WM.folder_name(None), NAMES.boxing_wm_alphazero: ALPHAZERO_VARIANTS.default.name}


def reproduce(name: str, profile: str | None = None, seed: int = 0, variant: str | None = None,
              progress: bool = True) -> dict:
    """Run experiment ``name`` (one of :data:`EXPERIMENTS`) and return its metrics; a recipe has
    the runs it builds on (same profile and seed) made first through
    :func:`~wmthesis.runs.built_on`, which calls this function.

    ``variant`` selects a variant of experiments that have them (PlaNet's, AlphaZero's, the
    PlaNet value's); others refuse one.
    """
    check_choice("experiment", name, EXPERIMENTS)
    seed = check_seed(seed)
    if name in VARIANTS:
        VARIANTS[name].check(variant)
    else:
        no_variant(name, variant)
    return RECIPES[name](profile_name(profile), seed, variant, progress)  # its prerequisites first (built_on)


register_runner(reproduce)


def seed_runs(name: str, profile: str | None, seeds, variant: str | None = None, train: bool = False,
              say: Callable[[str], None] | None = None) -> dict:
    """``{seed: metrics}`` of experiment ``name``'s ``variant`` (None: the default) for each of
    ``seeds``: with ``train``, each run here (resuming; :func:`reproduce`); without, the metrics
    each committed run wrote (``data/results/``), the seeds without one left out, and ``say``
    (``print`` in a notebook) told which and the command that runs them."""
    check_choice("experiment", name, EXPERIMENTS)
    profile = profile_name(profile)
    if train:
        return {seed: reproduce(name, profile, seed, variant, progress=False) for seed in seeds}
    if name not in VARIANTS:
        no_variant(name, variant)
    folder = VARIANTS[name].folder_name(variant) if name in VARIANTS else None
    paths = {seed: results_folder(name, profile, seed, folder) / "metrics.json" for seed in seeds}
    found = {seed: read_json(path) for seed, path in paths.items()}
    missing = [seed for seed, metrics in found.items() if metrics is None]
    if missing and say is not None:
        say(f"no committed {profile} run of {name}{f' {variant}' if variant else ''} for seed(s) "
            f"{', '.join(map(str, missing))}: TRAIN = True, or `python -m wmthesis reproduce {name} --profile {profile} "
            f"--seed {missing[0]}{f' --variant {variant}' if variant else ''}`")
    return {seed: check_metrics(metrics, paths[seed]) for seed, metrics in found.items() if metrics is not None}


def reproduce_all(runs, profile: str | None = None, seed: int = 0, workers: int = 1) -> dict:
    """Run several experiments, ``workers`` at a time, and return their metrics by run.

    ``runs``: ``(name, variant)`` pairs (variant None: the default). With ``workers`` > 1 each
    run goes to a spawned process with ``cpu_count // workers`` torch threads (runs are
    independent; each resumes from its own artifacts). Returns ``{(name, variant): metrics}``
    in the order of ``runs``.
    """
    runs = [tuple(run) for run in runs]
    for name, _ in runs:
        check_choice("experiment", name, EXPERIMENTS)
    profile = profile_name(profile)
    if workers <= 1:
        return {run: reproduce(run[0], profile, seed, variant=run[1], progress=False) for run in runs}
    threads = max(1, (os.cpu_count() or 1) // workers)
    with concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                                initializer=worker_init, initargs=(threads,)) as executor:
        futures = {run: executor.submit(reproduce, run[0], profile, seed, variant=run[1], progress=False)
                   for run in runs}
        return {run: future.result() for run, future in futures.items()}


__all__ = ["EXPERIMENTS", "VARIANTS", "DEFAULT_RESULTS", "reproduce", "reproduce_all", "seed_runs", "sokoban_search", 
           "sokoban_world_models", "sokoban_wm_configs", "SOKOBAN_WM_VARIANTS", "SOKOBAN_WM_CONTROLLERS",
           "SOKOBAN_FRAME_SIZE",
           "boxing_world_models", "boxing_wm_dream",
           "boxing_wm_alphazero", "RECORDING_STEPS",
           "planet_experiment", "planet_variants", "planet_boxing_study", "planet_boxing_agent", "planet_boxing_value",
           "planet_freeway_value",
           "PLANET_GAMES", "ATARI_CHANGES",
           "SOKOBAN_CHANGES"]
