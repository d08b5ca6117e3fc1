"""The Sokoban search agent's levers (beyond the thesis, notebook 07): each a change to its config,
measured on the validation files only (``python -m wmthesis validate sokoban-search LEVER``). Light
(no torch): the command line checks a lever's name against these before anything heavy loads."""
from __future__ import annotations

from wmthesis.declarations import NAMES
from wmthesis.variants import Variant, Variants

GENERATED = ("sokoban-small", "sokoban")  # our generator's variants: each evaluated on unseen levels

# Levers of the pixel agent, each a change to its config, trained in a folder of its own (one that
# changes the search alone searches the baseline's run) and measured on the validation files only
# (``validate``), never on the report files. The levers that left the code, with their numbers:
# docs/findings/sokoban-search.md.
THREE_ROUNDS = dict(rounds=3, model_updates=3000, round_updates=500)  # quick's rounds before the curriculum
LEVERS = Variants(
    NAMES.sokoban_search,
    Variant("baseline", "the pixel run of sokoban_search itself: the curriculum, two rounds a variant in quick",
            default=True),
    Variant("no-backups", "its value from solved levels alone: the baseline before backed-up values", dict(backups=0)),
    Variant("generated", "our 5x5 and 10x10 levels, not Boxoban's (three rounds a variant, as measured)",
            dict(variants=GENERATED, **THREE_ROUNDS)),
    Variant("small-model", "a quarter of the model's arithmetic: faster searches (three rounds a variant, as measured)",
            dict(channels=32, **THREE_ROUNDS)),
    Variant("strong-expert", "three times the rounds' search budget, 1.5 times the evaluation's",
            dict(round_budget=60_000)),
    Variant("prior-afterwards", "a policy prior fitted once on the baseline's own solutions orders the expansions",
            dict(prior_weight=1.0)),
)

__all__ = ["GENERATED", "LEVERS", "THREE_ROUNDS"]
