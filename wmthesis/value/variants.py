"""The value's variants and planner levers (beyond the thesis, on PlaNet's frozen models): Boxing's
(notebooks 09 and 10) and their folders, each variant fitting its value in a folder of its own on
the same model and bouts (``planet-boxing-value``'s recipe, and what builds on its runs, find them
here); Freeway's (notebook 08). Light (no torch): the command line checks names against these
before anything heavy loads."""
from __future__ import annotations

from wmthesis import runs as run_store
from wmthesis.declarations import NAMES
from wmthesis.variants import Variant, Variants

# Each variant fits its value on the same frozen model and bouts, in a folder of its own; one that
# builds on another starts from a copy of that run's bouts and values (the same seeds give the same
# first rounds), and one that changes the planner alone plays on that run's value. The numbers of
# the variants and levers that left the code: docs/findings/planet-boxing-value.md.
GAME = "boxing"
LEAN = dict(rounds=10, agent_rounds=3, score_rounds=False)
VALUE_VARIANTS = Variants(
    NAMES.planet_boxing_value,
    Variant("scored-rounds", "the value of the round chosen on validation bouts, every round scored (notebook 09)"),
    Variant("rounds-10", "ten rounds, each scored", dict(value=dict(rounds=10)), builds_on="scored-rounds"),
    Variant("rounds-10-mean-3", "rounds-10's agent as the mean of its last 3 rounds' values (chosen by validate_agents)",
            dict(value=dict(agent_rounds=3)), builds_on="rounds-10"),
    Variant("lean", "that agent from scratch, no greedy bouts after each round: an hour", dict(value=LEAN)),
    Variant("lean-value-rewards-0.7", "lean's value; CEM scores every imagined step by the value's Q, discount 0.7 "
            "(chosen on two seeds' validation bouts)", dict(planner=dict(rewards="value", discount=0.7)),
            builds_on="lean", default=True),
    Variant("own-rewards", "lean's value; CEM's imagined rewards from the reward head refit on the run's own bouts "
            "(the model taught the fights the planner plans)", dict(planner=dict(reward_head="own")),
            builds_on="lean"),
    root="scored-rounds")  # the first recipe: its runs keep the experiment's own folders (``seedS``, ``PROFILE-seedS``)
ROOT = VALUE_VARIANTS.root

# Levers on CEM with the value, each measured on the value's validation bouts (never on the
# evaluation bouts), stated against the default planner (``{}``: the value seeding CEM); the first
# lever played is the row the others are paired against. H1 is the value agent's own choice. The
# lever chosen became ``lean-value-rewards-0.7``'s planner; the levers that lost, with their
# numbers: docs/findings/planet-boxing-value.md.
BOXING_PLANNER_LEVERS = {"value seeds CEM": {}, "the value's rewards, discount 0.7": dict(rewards="value", discount=0.7),
                         "the value's rewards, discount 0.7, shared noise": dict(rewards="value", discount=0.7, imagine="shared"),
                         "the value's rewards, discount 0.7, pessimism 1": dict(rewards="value", discount=0.7, pessimism=1.0),
                         "the value's rewards, discount 0.7, 4 particles of 25": dict(rewards="value", discount=0.7, candidates=25, particles=4),
                         "H1: the value agent": dict(horizon=1), "the reward head refit on own bouts": dict(reward_head="own"),
                         "the reward head refit on own bouts, H6": dict(reward_head="own", horizon=6)}


FREEWAY_MODEL = "freeway-tuned"  # planet-freeway's variant whose model the default Freeway value is fitted on
# What would make the planner dodge cars? Each variant is measured against UP at every step, in a
# folder of its own, on the same model and episodes. A variant with a ``model`` of its own plays its
# baselines on it; one that builds on another copies that run's baselines, and its value unless it
# fits one of its own. The numbers of those that left the code: docs/findings/planet-freeway-value.md.
TD = dict(target="td", reward_steps=30, discount=0.99)
FREEWAY_VALUE_VARIANTS = Variants(
    NAMES.planet_freeway_value,
    Variant("default", "the discounted sum of the next 150 rewards on freeway-tuned's model, CEM 3 steps before it",
            default=True),
    # a collision's delay of 10-20 steps costs 10-20% of the value at 0.99
    Variant("td", "the time to the next crossing, bootstrapped through the model", dict(value=TD), builds_on="default"),
    Variant("horizon-12", "the default's value at the end of the thesis's 12 steps", dict(planner=dict(horizon=12)),
            builds_on="default"),
    # that agent's own episodes hold almost no crossing: the first data are freeway-tuned's
    Variant("freeway-adam", "the default on the model that sees the cars (planet-freeway's freeway-adam)",
            dict(model="freeway-adam", data=FREEWAY_MODEL)),
    Variant("adam-td", "the td value on the model that sees the cars", dict(value=TD), builds_on="freeway-adam"),
    # a step nearer the far side weighs the same at the foot of the road as at its top
    Variant("adam-log", "the discounted sum's logarithm on the model that sees the cars, CEM 12 steps before it",
            dict(planner=dict(horizon=12), value=dict(target="log-discounted-sum")), builds_on="freeway-adam"),
    root="default")  # the default's runs keep the experiment's own folders

# Which planner ends in a Freeway value, each measured on the value's validation episodes (never
# on the evaluation episodes): CEM's horizon, and its imagined states drawn or the prior's mean.
FREEWAY_PLANNER_LEVERS = {"H3": {}, "H12": dict(horizon=12), "H12 from the prior's mean": dict(horizon=12, imagine="mean")}


def value_folder(profile: str, seed: int, variant: str | None = None):
    """The work folder of the value run of ``variant`` (None: the default) and ``seed``."""
    return run_store.work_folder(profile, NAMES.planet_boxing_value, seed, VALUE_VARIANTS.folder_name(variant))


def results_folder(profile: str, seed: int, variant: str | None = None):
    """Where the value run of ``variant`` (None: the default) and ``seed`` writes its ``metrics.json`` and figures."""
    return run_store.results_folder(NAMES.planet_boxing_value, profile, seed, VALUE_VARIANTS.folder_name(variant))


__all__ = ["GAME", "LEAN", "VALUE_VARIANTS", "ROOT", "BOXING_PLANNER_LEVERS", "FREEWAY_MODEL", "FREEWAY_VALUE_VARIANTS",
           "FREEWAY_PLANNER_LEVERS", "value_folder", "results_folder"]
