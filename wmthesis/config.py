"""The three profiles, and the collection's config. Each wing keeps its configs as dataclasses
with the thesis defaults written once (``wmthesis/world_models/config.py``, ``planet/config.py``,
``alphazero/config.py``, ``sokoban_search/config.py``).

A config's defaults ARE the thesis's values (the `thesis` profile). The `smoke` and `quick`
profiles override a few fields (:data:`OVERRIDES`, by config class name):

- ``smoke``: seconds per step; proves the plumbing in CI.
- ``quick``: a 2-core CPU in under an hour per experiment, with meaningful results.
- ``thesis``: the thesis's hyperparameters exactly; meant for a GPU.

    >>> cfg = for_profile(CollectConfig, "smoke")
    >>> cfg.episodes
    4

Notebooks pick the profile in their parameters cell with :func:`profile_name`, which reads
``WMTHESIS_PROFILE`` when it is set.
"""
from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass

from wmthesis.declarations import EXPERIMENTS as DECLARED_EXPERIMENTS
from wmthesis.utils import check_choice, masked

PROFILES = ("smoke", "quick", "thesis")
PLANNERS = ("sokoban-search", "mcts", "cem")  # the planners of a budget curve, in the order a run measures them
# The names a command checks before anything heavy loads: the environments and the experiments
# (:mod:`wmthesis.envs` and :mod:`wmthesis.experiments` are built on them).
ATARI_ENVIRONMENTS = ("boxing", "freeway")
SOKOBAN_ENVIRONMENTS = ("sokoban", "sokoban-small")
ENVIRONMENTS = ATARI_ENVIRONMENTS + SOKOBAN_ENVIRONMENTS
EXPERIMENTS = DECLARED_EXPERIMENTS  # one declaration each: wmthesis.declarations
DEFAULT_PROFILE = "quick"


@dataclass(frozen=True)
class CollectConfig:
    """Random-rollout collection (thesis 4.2.3: 10,000 random rollouts)."""

    episodes: int = 10_000
    max_steps: int | None = None  # None: full-length episodes
    workers: int = 2


# Per profile, per config class name: the fields that differ from the thesis defaults.
OVERRIDES: dict[str, dict[str, dict]] = {
    "smoke": {
        "CollectConfig": dict(episodes=4, max_steps=50, workers=1),
        "VisionConfig": dict(batch_size=16, steps=6, eval_every=3),
        "MemoryConfig": dict(hidden_size=32, batch_size=4, sequence_length=16, steps=6, eval_every=3),
        "ControllerConfig": dict(population=8, episodes=2, generations=2, max_steps=50,
                                 dream_max_steps=50, eval_every=1, eval_episodes=2),
        "PlaNetConfig": dict(belief_size=32, state_size=4, hidden_size=32, reward_hidden_size=16,
                             batch_size=4, chunk_length=8, overshooting_distance=3, seed_episodes=2,
                             update_steps=2, max_episode_steps=16, env_steps=80, horizon=3,
                             candidates=16, top_k=4, iterations=2, test_interval=1, test_episodes=1),
        "LatentValueConfig": dict(hidden_size=16, random_bouts=2, fit_updates=5, batch_size=16, rounds=1,
                                  bouts_per_round=1, validation_bouts=1, test_bouts=2),
        "ValuePlannerConfig": dict(horizon=2),
        "ValueEvaluationConfig": dict(plan_steps=5, lever_bouts=1, freeway_episodes=2, freeway_lever_episodes=1,
                                      lookahead_episodes=1),
        "SearchConfig": dict(trials=2, workers=1, env_steps=48, open_loop_sequences=2, open_loop_length=10,
                             held_out_episodes=1,
                             heartbeat_interval=1, grace_period=3),
        "AlphaZeroConfig": dict(simulations=4, games=4, train_every=2, epochs=2, batch_size=16, max_steps=20,
                                noop_max=3, test_every=2, test_episodes=1, eval_episodes=2, eval_max_steps=20),
        "SokobanSearchConfig": dict(random_levels=20, rounds=1, levels_per_round=4, channels=16, model_updates=20,
                                    round_updates=5, batch_size=32, value_channels=8, value_updates=5,
                                    budget=300, eval_levels=4),
        "SokobanEvaluationConfig": dict(report_levels=2, reference_levels=2, validation_levels=2),
        "DiagnosisConfig": dict(depth=5),
        "BoxingEvaluationConfig": dict(bouts=2, context=10, horizon=10),
        "DreamConfig": dict(budget=400, random_bouts=2, bouts=2, memory_updates=3, generations=2, population=8,
                            starts=4, warmup=4, dream_length=8),
        "SokobanWorldModelsConfig": dict(sequence_length=None, levels=4, episodes=2, context=10, horizon=10, cutoff=5),
        "PlanetEvaluationConfig": dict(episodes=2, sokoban_open_loop=(4, 8, 4), atari_open_loop=(4, 8, 4), study_held_out=2,
                                       study_sequences=4, study_context=4, study_horizon=4, agent_bouts=2, figure_sequences=1),
        "BudgetCurveConfig": dict(sokoban_budgets=(50, 300), sokoban_levels=4, mcts_budgets=(2, 4), boxing_bouts=2,
                                  cem_budgets=((2, 16, 2), (3, 16, 2))),
    },
    "quick": {
        "CollectConfig": dict(episodes=20),
        "VisionConfig": dict(batch_size=64, steps=1500, eval_every=100),
        "MemoryConfig": dict(batch_size=16, sequence_length=100, steps=1500, eval_every=100),
        # Fitness over full bouts: scores over the first 400 steps did not carry over to full bouts.
        "ControllerConfig": dict(population=16, episodes=2, generations=45, dream_max_steps=400, eval_every=15,
                                 eval_episodes=3),
        # Sokoban: an episode is 120 steps (a Boxing bout ~1,780), so the store holds 400 random
        # episodes, 48,000 frames and as many new levels (Boxing's quick: 20 bouts, ~36,000 frames);
        # the rest is the profile's, as for Boxing (about 25 minutes end to end on two idle cores).
        "SokobanWorldModelsConfig": dict(collect_episodes=400, sequence_length=None, levels=50, episodes=40),
        "PlaNetConfig": dict(batch_size=12, chunk_length=24, update_steps=100, env_steps=20_000,
                             candidates=100, top_k=10, iterations=3, test_interval=3, test_episodes=1),
        # Trials measured by their models alone: the profile's PlaNet on the game's random seed
        # episodes (Boxing: 50 bouts, 3,000 updates; ~8 CPU-minutes each), no planner episodes;
        # the error on 32 held-out sequences, 5 context frames + 15 predicted.
        "SearchConfig": dict(trials=6, objective="error", env_steps=0, open_loop_sequences=32, open_loop_length=20,
                             heartbeat_interval=10, grace_period=600),
        # Self-play games of 400 agent steps (a bout is ~1,780), 100 per variant; full-bout evaluation.
        "AlphaZeroConfig": dict(games=100, max_steps=400, test_every=10, test_episodes=1, eval_episodes=5),
        # One run from pixels through the curriculum, two rounds a variant, 20,000 nodes a search
        # in the rounds and twice as many at evaluation, then 500 unseen levels of each evaluation
        # set (chosen on the validation files: docs/findings/sokoban-search.md).
        "SokobanSearchConfig": dict(random_levels=1000, rounds=2, levels_per_round=250, model_updates=1500,
                                    round_updates=250, value_updates=1000, budget=20_000, eval_budget=40_000),
        # fewer reference levels keep the run in its time (on 500 they take about 20 CPU-minutes)
        "SokobanEvaluationConfig": dict(report_levels=500, reference_levels=100, validation_levels=200),
        # CEM: quick's J and I are its PlaNet's; no H12 (its bouts cost more than the rest; its 12th step weighs 2%)
        "PlanetEvaluationConfig": dict(episodes=3, study_held_out=3, study_sequences=48),
        "ValueEvaluationConfig": dict(plan_steps=300, freeway_lever_episodes=5, lookahead_episodes=2),
        "BudgetCurveConfig": dict(sokoban_levels=500, cem_budgets=((2, 100, 3), (3, 100, 3), (6, 100, 3))),
    },
    "thesis": {},
}

SIZES_KEPT = ("smoke",)  # profiles whose sizes a variant's changes do not replace (:func:`for_variant`)


STORAGE_SCHEMES = ("sqlite", "postgresql", "mysql")  # the databases optuna's RDB storage speaks


def check_storage(url: str | None) -> None:
    """A ``--storage`` URL of a database optuna stores studies in; ValueError naming those otherwise."""
    scheme = url.split("://", 1)[0].split("+", 1)[0] if url and "://" in url else None
    if url is not None and scheme not in STORAGE_SCHEMES:
        raise ValueError(f"--storage {masked(url)!r}: name a database URL of {', '.join(s + '://...' for s in STORAGE_SCHEMES)} "
                         "(e.g. sqlite:///data/search/mine.db)")


def profile_name(name: str | None = None) -> str:
    """The profile to use: `name` if given, else ``$WMTHESIS_PROFILE``, else ``quick``."""
    name = name or os.environ.get("WMTHESIS_PROFILE") or DEFAULT_PROFILE
    check_choice("profile", name, PROFILES)
    return name


def for_variant(cls, profile: str | None, variant_changes: dict, **changes):
    """An instance of `cls` for `profile` with a variant's changes on top, then `changes`; a profile
    of :data:`SIZES_KEPT` keeps the fields it sets (a smoke run stays small whatever the variant)."""
    kept = OVERRIDES[profile_name(profile)].get(cls.__name__, {}) if profile_name(profile) in SIZES_KEPT else {}
    return for_profile(cls, profile, **{**{k: v for k, v in variant_changes.items() if k not in kept}, **changes})


def for_profile(cls, profile: str | None = None, **changes):
    """An instance of config class `cls` for `profile`, with explicit `changes` on top."""
    profile = profile_name(profile)
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = set(changes) - fields
    if unknown:
        raise TypeError(f"{cls.__name__} has no field(s) {sorted(unknown)}; valid: {sorted(fields)}")
    values = {**OVERRIDES[profile].get(cls.__name__, {}), **changes}
    return cls(**values)
