"""The Boxing value's variants (beyond the thesis, on PlaNet's frozen Boxing model: notebooks 09
and 10) and their folders: each variant fits its value in a folder of its own, on the same model
and bouts (``planet-boxing-value``'s recipe, and what builds on its runs, find them here)."""
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


def value_folder(profile: str, seed: int, variant: str | None = None):
    """The work folder of the value run of ``variant`` (None: the default) and ``seed``."""
    return run_store.work_folder(profile, NAMES.planet_boxing_value, seed, VALUE_VARIANTS.folder_name(variant))


def results_folder(profile: str, seed: int, variant: str | None = None):
    """Where the value run of ``variant`` (None: the default) and ``seed`` writes its ``metrics.json`` and figures."""
    return run_store.results_folder(NAMES.planet_boxing_value, profile, seed, VALUE_VARIANTS.folder_name(variant))


__all__ = ["GAME", "LEAN", "VALUE_VARIANTS", "ROOT", "value_folder", "results_folder"]
