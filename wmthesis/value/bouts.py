"""Bouts of a fitted value on its frozen PlaNet model, each saved as it ends: the value agent's
(:func:`value_bout`) and CEM's with the value at the end of its horizon (:func:`value_planner_bout`),
their scores cached for the value agent, the planner's config and the bouts (:func:`value_planners_scores`)."""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from wmthesis.planet.bouts import bout_result, bout_scores
from wmthesis.value.config import ValuePlannerConfig
from wmthesis.value.own_rewards import planner_model
from wmthesis.planet.train import load_planet
from wmthesis.planet.frames import make_planet_env
from wmthesis.value.planner import play_value_planner
from wmthesis.value.play import play_value
from wmthesis.value.rounds import load_rounds
from wmthesis.runs import cached_for, played_groups, write_json
from wmthesis.training import with_added_defaults


def value_planner_bout(planet_run: Path, value_run: Path, planner, env_seed: int, mind_seed: int,
                       game: str = "boxing") -> dict:
    """One full episode of ``game``, CEM with the chosen value at its end
    (:func:`~wmthesis.value.planner.play_value_planner`) on the frozen model of
    ``planet_run``: its ``return``, the return of its first :data:`FIRST_STEPS` steps, its
    ``steps`` and the ``seconds`` it took (the planner's thinking, the game and the encoding)."""
    model, planet, value = planner_model(planet_run, value_run, planner)
    env = make_planet_env(game, planet)
    try:
        start = time.perf_counter()
        rewards = play_value_planner(env, model, value, planet, planner, env_seed, mind_seed)
        seconds = time.perf_counter() - start
    finally:
        env.close()
    return {**bout_result(rewards), "seconds": round(seconds, 3)}


def planner_defaults(key: dict) -> dict:
    """A saved cache key whose ``planner`` (a :class:`~wmthesis.planet.config.ValuePlannerConfig` saved
    before a field was added) reads as what it did (:func:`~wmthesis.training.with_added_defaults`)."""

    if isinstance(key.get("planner"), dict):
        key["planner"] = with_added_defaults(ValuePlannerConfig, key["planner"])
    return key


def cached_plan(path: Path, key: dict) -> dict | None:
    """The JSON cache at ``path`` if it was written for ``key``, a key that holds a planner's config
    (:func:`~wmthesis.experiments.results.cached_for`, a planner saved before a field was added
    read as what it did)."""
    return cached_for(path, key, planner_defaults)


def value_bout(planet_run: Path, value_run: Path, rounds: list[int], env_seed: int, mind_seed: int,
               game: str = "boxing") -> dict:
    """One full greedy episode of ``game`` of the mean of the values of ``rounds`` of the value
    run (:func:`~wmthesis.value.rounds.load_rounds`) on the frozen model of ``planet_run``: its
    ``return``, the return of its first :data:`FIRST_STEPS` steps and its ``steps``."""
    model, planet, _ = load_planet(planet_run)
    env = make_planet_env(game, planet)
    try:
        rewards = play_value(env, model, load_rounds(value_run, model, rounds), planet.bits, env_seed, mind_seed)["rewards"]
    finally:
        env.close()
    return bout_result([float(r) for r in rewards])


def value_planner_scores(planet_run: Path, value_run: Path, planner, bouts: list, best: int | list[int], progress: bool,
                         cache: Path | None = None, game: str = "boxing") -> dict:
    """The planner with value over ``bouts`` ((env, mind) seeds): full-episode and
    first-500-step scores, cached in ``cache`` (``value_run/value_planner.json`` by default)
    for the value agent ``best`` (its chosen round, or the rounds whose mean it is), the
    planner's config and the bouts."""
    cache = value_run / "value_planner.json" if cache is None else cache
    return value_planners_scores(planet_run, value_run, [(planner, cache)], bouts, best, progress, game)[0]


def value_planners_scores(planet_run: Path, value_run: Path, planners: list[tuple], bouts: list, best: int | list[int],
                          progress: bool, game: str = "boxing", executor=None) -> list[dict]:
    """:func:`value_planner_scores` for each ``(planner, cache)`` of ``planners``, their bouts
    all in one pool (``executor``, :func:`~wmthesis.utils.process_pool`; two at a time by
    default), each planner's saved as they end."""
    keys = [{"round": best, "planner": dataclasses.asdict(planner), "bouts": [list(b) for b in bouts]}
            for planner, _ in planners]
    cached = [cached_plan(cache, key) for (_, cache), key in zip(planners, keys)]
    todo = [j for j, c in enumerate(cached) if c is None]
    plays = played_groups([(planners[j][1].with_name(planners[j][1].stem + "-bouts.json"), keys[j],
                            [(value_planner_bout, planet_run, value_run, planners[j][0], *bout, game) for bout in bouts],
                            planner_defaults) for j in todo], progress, executor)
    for j, played in zip(todo, plays):
        scores = {**bout_scores(played), "config": dataclasses.asdict(planners[j][0])}
        write_json(planners[j][1], {"key": keys[j], "scores": scores})
        cached[j] = {"scores": scores}
    return [c["scores"] for c in cached]


__all__ = ["value_bout", "value_planner_bout", "value_planner_scores", "value_planners_scores", "cached_plan",
           "planner_defaults"]
