"""Beyond the thesis on PlaNet's Boxing model (issue 31): the model of
:func:`~wmthesis.experiments.planet_boxing.planet_boxing_agent` frozen, a latent action value
fitted on it (:mod:`~wmthesis.planet.value`, notebook 09), and CEM with that value at the end of
its horizon (:mod:`~wmthesis.planet.value_planner`, notebook 10), each beside the thesis's CEM on
the same bouts.
"""
from __future__ import annotations

import dataclasses
import time

from wmthesis.config import profile_name
from wmthesis.experiments.planet_boxing import AGENT, GAME, planet_boxing_agent
from wmthesis.metrics import score_cell
from wmthesis import runs
from wmthesis.variants import Variant, Variants
from wmthesis.references import HUMAN, THESIS_PLANET_BOXING_SCORE, human
from wmthesis.experiments.planet_value import (PLAN_STEPS, checked_levers, compare_plans, fit_and_compare, lever_scores,
                                              slug, start_from)
from wmthesis.utils import data_dir
from wmthesis.runs import hold, releasing_holds

# Each variant fits its value on the same frozen model and bouts, in a folder of its own; one that
# builds on another starts from a copy of that run's bouts and values (the same seeds give the same
# first rounds), and one that changes the planner alone plays on that run's value. The numbers of
# the variants and levers that left the code: docs/findings/planet-boxing-value.md.
LEAN = dict(rounds=10, agent_rounds=3, score_rounds=False)
VALUE_VARIANTS = Variants(
    "planet-boxing-value",
    Variant("default", "the value of the round chosen on validation bouts, every round scored (notebook 09)",
            default=True),
    Variant("rounds-10", "ten rounds, each scored", dict(value=dict(rounds=10)), builds_on="default"),
    Variant("rounds-10-mean-3", "rounds-10's agent as the mean of its last 3 rounds' values (chosen by validate_agents)",
            dict(value=dict(agent_rounds=3)), builds_on="rounds-10"),
    Variant("lean", "that agent from scratch, no greedy bouts after each round: issue 31's hour", dict(value=LEAN)),
    Variant("lean-value-rewards-0.7", "lean's value; CEM scores every imagined step by the value's Q, discount 0.7 "
            "(chosen on two seeds' validation bouts)", dict(planner=dict(rewards="value", discount=0.7)),
            builds_on="lean"),
)


def folder_variant(variant: str | None) -> str | None:
    """A variant's name in its folders: None for the one named ``default`` (checked first)."""
    name = VALUE_VARIANTS.check(variant).name
    return None if name == "default" else name


def value_run(variant: str | None) -> str | None:
    """The variant whose run fitted ``variant``'s value: itself, or for one that changes the planner
    alone, the run it builds on (as :func:`folder_variant` names it)."""
    chain = VALUE_VARIANTS.lineage(variant)
    while "value" not in chain[-1].changes and chain[-1].builds_on is not None and len(chain) > 1:
        chain.pop()
    return folder_variant(chain[-1].name)


def value_folder(profile: str, seed: int, variant: str | None = None):
    """The work folder of the value run of ``variant`` (None: the default) and ``seed``."""
    return runs.work_folder(profile, "planet-boxing-value", seed, folder_variant(variant))


def results_folder(profile: str, seed: int, variant: str | None = None):
    """Where the value run of ``variant`` (None: the default) and ``seed`` writes its ``metrics.json`` and figures."""
    return runs.results_folder("planet-boxing-value", profile, seed, folder_variant(variant))


@releasing_holds
def planet_boxing_value(profile: str | None = None, seed: int = 0, progress: bool = True,
                        variant: str | None = None) -> dict:
    """The PlaNet agent's model (:func:`planet_boxing_agent`, trained first if need be) frozen,
    and a latent action value (:mod:`~wmthesis.planet.value`) fitted on random bouts and then on
    its own; after each round, greedy bouts on the agent's evaluation bouts. The round chosen on
    validation bouts of its own (:func:`~wmthesis.planet.value.best_round`) compares with random
    play and with the CEM planner on the evaluation bouts, and so does CEM with that value at the
    end of its horizon (:mod:`~wmthesis.planet.value_planner`). Returns the metrics:
    ``value`` and ``random`` (scores over full bouts), ``difference``
    (:func:`~wmthesis.metrics.score_difference`), ``planet`` (the CEM agent's), ``value_planner``
    (CEM with the value: full bouts and their first 500 steps), the ``curve`` (one entry per
    round) and ``files``. A ``variant`` of :data:`VALUE_VARIANTS` fits its value in a folder of
    its own, on the same model and bouts (a ``td`` value is discounted in the planner as in its
    targets; one may change the planner alone)."""
    from wmthesis.config import LatentValueConfig, ValuePlannerConfig, for_profile

    chosen, variant = VALUE_VARIANTS.check(variant), folder_variant(variant)
    profile = profile_name(profile)
    started = time.time()
    agent = planet_boxing_agent(profile, seed, progress)
    planet_run = data_dir(profile, "planet-boxing-agent", f"seed{seed}")
    work = hold(value_folder(profile, seed, variant))
    out = results_folder(profile, seed, variant)
    config = for_profile(LatentValueConfig, profile, test_bouts=AGENT[profile]["bouts"],
                         **VALUE_VARIANTS.changes(chosen.name, "value"))
    if chosen.builds_on is not None:
        start_from(work, value_folder(profile, seed, folder_variant(chosen.builds_on)))
    discount = {"discount": config.discount} if config.target != "reward-sum" else {}
    planner = for_profile(ValuePlannerConfig, profile, **{**discount, **VALUE_VARIANTS.changes(chosen.name, "planner")})
    references = {"human": human(GAME), "thesis PlaNet (around 30)": THESIS_PLANET_BOXING_SCORE}
    return fit_and_compare("planet-boxing-value", GAME, planet_run, work, out, config, planner,
                           {"random": agent["random"], "planet": agent["agent"]}, agent["bouts"], profile=profile,
                           seed=seed, progress=progress, references=references, variant=variant, started=started)


def value_plan_choices(profile: str | None = None, seed: int = 0, progress: bool = True,
                       variant: str | None = None) -> dict:
    """Where the value changes the plan on Boxing (:func:`~wmthesis.experiments.planet_value.compare_plans`
    on the run of :func:`planet_boxing_value` with ``variant``, run first if need be; cached)."""
    profile = profile_name(profile)
    metrics = planet_boxing_value(profile, seed, progress, variant)
    return compare_plans(GAME, data_dir(profile, "planet-boxing-agent", f"seed{seed}"), value_folder(profile, seed, variant),
                         results_folder(profile, seed, variant),
                         metrics, PLAN_STEPS[profile], seed)


# Levers on CEM with the value, each measured on the value's validation bouts (never on the
# evaluation bouts), stated against the default planner (``{}``: the value seeding CEM); the first
# lever played is the row the others are paired against. H1 is the value agent's own choice. The
# lever chosen became ``lean-value-rewards-0.7``'s planner; the levers that lost, with their
# numbers: docs/findings/planet-boxing-value.md.
PLANNER_LEVERS = {"value seeds CEM": {}, "the value's rewards": dict(rewards="value"),
                  "the value's rewards, discount 0.5": dict(rewards="value", discount=0.5),
                  "the value's rewards, discount 0.7": dict(rewards="value", discount=0.7),
                  "the value's rewards, discount 0.5, prior's mean": dict(rewards="value", discount=0.5, imagine="mean"),
                  "H1: the value agent": dict(horizon=1)}
LEVER_BOUTS = {"smoke": 1, "quick": 10, "thesis": 10}  # validation bouts per lever


def validate_planners(profile: str | None = None, seed: int = 0, levers: tuple[str, ...] | None = None,
                      bouts: int | None = None, progress: bool = True, variant: str | None = None,
                      executor=None, metrics: dict | None = None) -> dict[str, dict]:
    """CEM with the value agent of ``variant``'s run (:func:`planet_boxing_value`, run first if
    need be) under each of ``levers`` (names in :data:`PLANNER_LEVERS`; all by default), on
    ``bouts`` (the profile's :data:`LEVER_BOUTS` by default) of the value's validation bouts
    (:func:`~wmthesis.planet.value.validation_seeds`: apart from the evaluation bouts), each
    lever cached in the value's folder (a variant that changes the planner alone plays on the
    value of the run it copies, in that run's folder). All levers' bouts are played in one pool,
    lever by lever: ``executor`` (:func:`~wmthesis.utils.process_pool`), two at a time by
    default; a machine with more cores plays them that many at a time. ``metrics``: the value
    run's, where it was read from its ``metrics.json`` (a machine that holds only the models,
    ``tools/validate_levers.py``). Returns lever -> the
    planner's ``config`` and its ``full`` and ``first``-500-step :func:`~wmthesis.metrics.score_summary`."""
    from wmthesis.config import ValuePlannerConfig, for_profile
    from wmthesis.planet.value import validation_seeds

    profile = profile_name(profile)
    levers, bouts = checked_levers("planner lever", levers, PLANNER_LEVERS, bouts, LEVER_BOUTS[profile])
    metrics = planet_boxing_value(profile, seed, progress, variant) if metrics is None else metrics
    planet_run = data_dir(profile, "planet-boxing-agent", f"seed{seed}")
    work = value_folder(profile, seed, value_run(variant))  # the run that fitted its value
    planners = {lever: for_profile(ValuePlannerConfig, profile, **PLANNER_LEVERS[lever]) for lever in levers}
    return lever_scores(planet_run, work, metrics, planners, [validation_seeds(seed, k) for k in range(bouts)],
                        progress, executor=executor)


# Which fitted values make the value agent (``LatentValueConfig.agent_rounds``), each measured on
# validation bouts of a run's own that did not choose its round: the round chosen on validation
# (the default), the last round, or the mean of the last rounds' values (a snapshot ensemble).
AGENT_RULES = {"round chosen on validation": 0, "last round": 1, "mean of the last 3": 3, "mean of the last 5": 5}


def validate_agents(profile: str | None = None, seed: int = 0, variant: str | None = "rounds-10",
                    rules: tuple[str, ...] | None = None, bouts: int | None = None, progress: bool = True) -> dict[str, dict]:
    """The value agent of ``variant``'s run (:func:`planet_boxing_value`, run first if need be;
    its rounds' values refitted once if they were not kept, :func:`~wmthesis.planet.value.round_values`)
    under each of ``rules`` (names in :data:`AGENT_RULES`; all by default) on ``bouts`` (the
    profile's :data:`LEVER_BOUTS` by default) greedy validation bouts that follow those that chose
    its round (:func:`~wmthesis.planet.value.validation_seeds` from ``validation_bouts`` on: apart
    from the choice among rounds and from the evaluation bouts). Each bout is saved as it ends.
    Returns rule -> its ``rounds`` and their ``full`` and ``first``-500-step scores."""
    from wmthesis.config import LatentValueConfig
    from wmthesis.experiments.planet_boxing import bout_scores
    from wmthesis.experiments.planet_value import played_bouts, value_bout
    from wmthesis.planet.train import load_planet
    from wmthesis.planet.value import agent_rounds, round_values, validation_seeds

    profile = profile_name(profile)
    rules, bouts = checked_levers("agent rule", rules, AGENT_RULES, bouts, LEVER_BOUTS[profile])
    metrics = planet_boxing_value(profile, seed, progress, variant)
    planet_run = data_dir(profile, "planet-boxing-agent", f"seed{seed}")
    work = value_folder(profile, seed, folder_variant(variant))
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


def agent_rows(results: dict[str, dict]) -> list[list[str]]:
    """:func:`validate_agents`' results as :func:`planner_lever_rows`, each rule's rounds in place
    of a planner's changes, paired against the first rule."""
    def rounds(r: list[int]) -> str:
        return f"round {r[0]}" if len(r) == 1 else f"rounds {r[0]}-{r[-1]}"

    return planner_lever_rows(results, {rule: rounds(scores["rounds"]) for rule, scores in results.items()})


def planner_lever_rows(results: dict[str, dict], changes: dict[str, str] | None = None) -> list[list[str]]:
    """:func:`validate_planners`' (or :func:`validate_agents`') results as table rows: lever, its
    changes to the planner (``changes``, by default those of :data:`PLANNER_LEVERS`),
    full-bout mean ± std, first-500-step mean, and the difference from the first lever's
    full-bout scores with its standard error (the same bouts: paired,
    :func:`~wmthesis.metrics.paired_difference`)."""
    from wmthesis.metrics import paired_difference

    if changes is None:
        changes = {lever: ", ".join(f"{k}={v}" for k, v in PLANNER_LEVERS.get(lever, {}).items()) or "(the default)"
                   for lever in results}
    first = next(iter(results.values()))
    rows = []
    for lever, scores in results.items():
        diff = paired_difference(scores["returns"], first["returns"])
        rows.append([lever, changes[lever], f"{scores['full']['mean']:.1f} ± {scores['full']['std']:.1f}",
                     f"{scores['first']['mean']:.1f}", f"{diff['difference']:+.1f} ± {diff['standard_error']:.1f}"])
    return rows


def planner_rows(by_seed: dict[int, dict], beside: dict[str, dict[int, dict]] | None = None) -> list[list[str]]:
    """The planners over seeds (``by_seed``: seed -> :func:`planet_boxing_value`'s metrics), one
    row each: every seed's mean over its bouts, then the mean over seeds with its 95% t-interval
    (:func:`~wmthesis.experiments.summary.aggregate`). ``beside``: label -> the same seeds' runs of
    another variant, whose CEM with the value is added as rows named with the label."""
    from wmthesis.experiments.summary import aggregate

    def planner(part, runs):
        return lambda seed: runs[seed]["value_planner"][part]["mean"]

    players = {"random play": lambda seed: by_seed[seed]["random"]["mean"],
               "PlaNet's CEM (thesis), full bouts": lambda seed: by_seed[seed]["planet"]["mean"],
               "value alone, full bouts": lambda seed: by_seed[seed]["value"]["mean"],
               "value alone, first 500 steps": lambda seed: by_seed[seed].get("value_first", {}).get("mean"),  # since 2026-11-24
               "CEM with the value, full bouts": planner("full", by_seed),
               "CEM with the value, first 500 steps": planner("first", by_seed)}
    for label, runs in (beside or {}).items():
        if set(runs) != set(by_seed):
            raise ValueError(f"{label!r} has seeds {sorted(runs)}, not the seeds {sorted(by_seed)}")
        players |= {f"CEM with the value ({label}), full bouts": planner("full", runs),
                    f"CEM with the value ({label}), first 500 steps": planner("first", runs)}
    rows = []
    for name, score in players.items():
        scores = [score(seed) for seed in by_seed]
        if None in scores:  # not measured in an older run
            continue
        summary = aggregate(scores)
        interval = "" if summary["ci_low"] is None else f" [{summary['ci_low']:.1f}, {summary['ci_high']:.1f}]"
        rows.append([name, *(f"{x:.1f}" for x in scores), f"{summary['mean']:.1f}{interval}"])
    return rows


def value_table(metrics: dict) -> str:
    """The value agent's chosen round beside random play and the CEM planner on the same bouts (markdown)."""
    diff, rounds = metrics["difference"], metrics.get("agent_rounds", [metrics["best_round"]])
    chosen = metrics["curve"][rounds[-1]]
    agent = (f"round {chosen['round']}, {chosen['episodes']} bouts of its own; chosen on {len(chosen['validation'])} "
             f"validation bouts" if len(rounds) == 1 else
             f"the mean of the values of rounds {rounds[0]}-{rounds[-1]}, up to {chosen['episodes']} bouts of its own")
    return "\n".join([
        "| player | full bout |", "|---|---|",
        f"| latent value on the PlaNet model ({agent}) | {score_cell(metrics['value'])} |",
        f"| PlaNet (CEM planner), same model | {score_cell(metrics['planet'])} |",
        *([f"| CEM with the value at the end of its {metrics['value_planner']['config']['horizon']} steps, same model "
           f"| {score_cell(metrics['value_planner']['full'])} |"] if "value_planner" in metrics else []),
        f"| random play, same bouts | {score_cell(metrics['random'])} |",
        f"| value - random | {diff['difference']:.1f} ± {diff['standard_error']:.1f} (s.e.) |",
        f"| human ({HUMAN[GAME].source}) | {human(GAME)} |"])


__all__ = ["planet_boxing_value", "results_folder", "value_plan_choices", "validate_planners", "planner_lever_rows", "PLANNER_LEVERS", "LEVER_BOUTS", "planner_rows", "value_table",
           "VALUE_VARIANTS", "folder_variant", "value_run", "AGENT_RULES", "validate_agents", "agent_rows"]
