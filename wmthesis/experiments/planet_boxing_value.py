"""Beyond the thesis on PlaNet's Boxing model: the model of
``planet-boxing-agent`` (:mod:`~wmthesis.experiments.planet_boxing`) frozen, a latent action value
fitted on it (:mod:`~wmthesis.value.latent_value`, notebook 09), and CEM with that value at the end of
its horizon (:mod:`~wmthesis.value.planner`, notebook 10), each beside the thesis's CEM on
the same bouts.
"""
from __future__ import annotations

import dataclasses
import time

from wmthesis import runs as run_store
from wmthesis.config import for_profile, profile_name
from wmthesis.declarations import NAMES
from wmthesis.planet.bouts import bout_scores
from wmthesis.value.config import LatentValueConfig, ValueEvaluationConfig, ValuePlannerConfig
from wmthesis.planet.train import load_planet
from wmthesis.value.bouts import value_bout
from wmthesis.value.play import validation_seeds
from wmthesis.value.rounds import agent_rounds, round_values
from wmthesis.value.variants import BOXING_PLANNER_LEVERS, GAME, VALUE_VARIANTS, results_folder, value_folder
from wmthesis.value.comparison import (checked_levers, compare_plans, fit_and_compare, frozen_agent,
                                        lever_scores, slug, start_from)
from wmthesis.references import THESIS_PLANET_BOXING_SCORE, human
from wmthesis.runs import hold, played_bouts, releasing_holds

REFERENCES = {"human": human(GAME), "thesis PlaNet (around 30)": THESIS_PLANET_BOXING_SCORE}  # lines in its figures


@releasing_holds
def planet_boxing_value(profile: str | None = None, seed: int = 0, variant: str | None = None,
                        progress: bool = True) -> dict:
    """The PlaNet agent's model (``planet-boxing-agent``'s run, made first if need be) frozen,
    and a latent action value (:mod:`~wmthesis.value.latent_value`) fitted on random bouts and then on
    its own; after each round, greedy bouts on the agent's evaluation bouts. The round chosen on
    validation bouts of its own (:func:`~wmthesis.value.rounds.best_round`) compares with random
    play and with the CEM planner on the evaluation bouts, and so does CEM with that value at the
    end of its horizon (:mod:`~wmthesis.value.planner`). Returns the metrics:
    ``value`` and ``random`` (scores over full bouts), ``difference``
    (:func:`~wmthesis.metrics.score_difference`), ``planet`` (the CEM agent's), ``value_planner``
    (CEM with the value: full bouts and their first 500 steps), the ``curve`` (one entry per
    round) and ``files``. A ``variant`` of :data:`VALUE_VARIANTS` fits its value in a folder of
    its own, on the same model and bouts (a ``td`` value is discounted in the planner as in its
    targets; one may change the planner alone)."""
    chosen = VALUE_VARIANTS.check(variant)  # its folders: value_folder, results_folder (None: the default)
    profile = profile_name(profile)
    started = time.time()
    agent, planet_run = frozen_agent(NAMES.planet_boxing_agent, profile, seed, progress=progress)  # the shipped one, or trained
    work = hold(value_folder(profile, seed, chosen.name))
    out = results_folder(profile, seed, chosen.name)
    config = for_profile(LatentValueConfig, profile, test_bouts=len(agent["bouts"]),
                         **VALUE_VARIANTS.changes(chosen.name, "value"))
    if chosen.builds_on is not None:
        start_from(work, value_folder(profile, seed, chosen.builds_on))
    discount = {"discount": config.discount} if config.target != "reward-sum" else {}
    planner = for_profile(ValuePlannerConfig, profile, **{**discount, **VALUE_VARIANTS.changes(chosen.name, "planner")})
    return fit_and_compare(NAMES.planet_boxing_value, GAME, planet_run, work, out, config, planner,
                           {"random": agent["random"], "planet": agent["agent"]}, agent["bouts"], profile=profile,
                           seed=seed, progress=progress, references=REFERENCES, variant=VALUE_VARIANTS.folder_name(chosen.name), started=started)


def value_plan_choices(profile: str | None = None, seed: int = 0, progress: bool = True,
                       variant: str | None = None) -> dict:
    """Where the value changes the plan on Boxing (:func:`~wmthesis.value.comparison.compare_plans`
    on the run of :func:`planet_boxing_value` with ``variant``, run first if need be; cached)."""
    profile = profile_name(profile)
    metrics = planet_boxing_value(profile, seed, variant, progress)
    return compare_plans(GAME, run_store.work_folder(profile, NAMES.planet_boxing_agent, seed), value_folder(profile, seed, variant),
                         results_folder(profile, seed, variant),
                         metrics, for_profile(ValueEvaluationConfig, profile).plan_steps, seed)


def validate_planners(profile: str | None = None, seed: int = 0, levers: tuple[str, ...] | None = None,
                      bouts: int | None = None, progress: bool = True, variant: str | None = None,
                      executor=None, metrics: dict | None = None) -> dict[str, dict]:
    """CEM with the value agent of ``variant``'s run (:func:`planet_boxing_value`, run first if
    need be) under each of ``levers`` (names in :data:`BOXING_PLANNER_LEVERS`; all by default), on
    ``bouts`` (the profile's ``ValueEvaluationConfig.lever_bouts`` by default) of the value's validation bouts
    (:func:`~wmthesis.value.play.validation_seeds`: apart from the evaluation bouts), each
    lever cached in the value's folder (a variant that changes the planner alone plays on the
    value it copied, in its own folder: a copy made, or a value fitted from scratch where there was
    none to copy, plays as that run played). All levers' bouts are played in one pool,
    lever by lever: ``executor`` (:func:`~wmthesis.utils.process_pool`), two at a time by
    default; a machine with more cores plays them that many at a time. ``metrics``: the value
    run's, where it was read from its ``metrics.json`` (a machine that holds only the models).
    Returns lever -> the
    planner's ``config`` and its ``full`` and ``first``-500-step :func:`~wmthesis.metrics.score_summary`."""
    profile = profile_name(profile)
    levers, bouts = checked_levers("planner lever", levers, BOXING_PLANNER_LEVERS, bouts, for_profile(ValueEvaluationConfig, profile).lever_bouts)
    metrics = planet_boxing_value(profile, seed, variant, progress) if metrics is None else metrics
    planet_run = run_store.work_folder(profile, NAMES.planet_boxing_agent, seed)
    work = value_folder(profile, seed, variant)  # the run's value: fitted there, or copied from the run it builds on
    planners = {lever: for_profile(ValuePlannerConfig, profile, **BOXING_PLANNER_LEVERS[lever]) for lever in levers}
    return lever_scores(planet_run, work, metrics, planners, [validation_seeds(seed, k) for k in range(bouts)],
                        progress, executor=executor)


# Which fitted values make the value agent (``LatentValueConfig.agent_rounds``), each measured on
# validation bouts of a run's own that did not choose its round: the round chosen on validation
# (the default), the last round, or the mean of the last rounds' values (a snapshot ensemble).
AGENT_RULES = {"round chosen on validation": 0, "last round": 1, "mean of the last 3": 3, "mean of the last 5": 5}


def validate_agents(profile: str | None = None, seed: int = 0, variant: str | None = "rounds-10",
                    rules: tuple[str, ...] | None = None, bouts: int | None = None, progress: bool = True) -> dict[str, dict]:
    """The value agent of ``variant``'s run (:func:`planet_boxing_value`, run first if need be;
    its rounds' values refitted once if they were not kept, :func:`~wmthesis.value.rounds.round_values`)
    under each of ``rules`` (names in :data:`AGENT_RULES`; all by default) on ``bouts`` (the
    profile's ``ValueEvaluationConfig.lever_bouts`` by default) greedy validation bouts that follow those that chose
    its round (:func:`~wmthesis.value.play.validation_seeds` from ``validation_bouts`` on: apart
    from the choice among rounds and from the evaluation bouts). Each bout is saved as it ends.
    Returns rule -> its ``rounds`` and their ``full`` and ``first``-500-step scores."""
    profile = profile_name(profile)
    rules, bouts = checked_levers("agent rule", rules, AGENT_RULES, bouts, for_profile(ValueEvaluationConfig, profile).lever_bouts)
    metrics = planet_boxing_value(profile, seed, variant, progress)
    planet_run = run_store.work_folder(profile, NAMES.planet_boxing_agent, seed)
    work = value_folder(profile, seed, variant)
    model, planet, _ = load_planet(planet_run)
    round_values(model, planet.bits, work, seed=seed, progress=progress)
    config = LatentValueConfig(**metrics["config"])
    validation = [list(validation_seeds(seed, config.validation_bouts + k)) for k in range(bouts)]
    results = {}
    for rule in rules:
        rounds = agent_rounds(metrics["curve"], dataclasses.replace(config, agent_rounds=AGENT_RULES[rule]))
        plays = played_bouts(work / "agent-validation" / f"{slug(rule)}.json", {"rounds": rounds, "bouts": validation},
                             progress, [(value_bout, planet_run, work, rounds, *bout, GAME) for bout in validation])
        results[rule] = {"rounds": rounds, **bout_scores(plays)}
    return results


__all__ = ["planet_boxing_value", "REFERENCES", "value_plan_choices", "validate_planners",
           "AGENT_RULES", "validate_agents"]
