"""One bout (a full episode) of PlaNet on an Atari game, and bouts summed up: a bout's return,
the return of its first :data:`FIRST_STEPS` agent steps (the author's PlaNet runs capped episodes
at 2,000 frames, 500 agent steps: like is compared with like) and its length."""
from __future__ import annotations

from pathlib import Path

from wmthesis.config import PlaNetConfig
from wmthesis.core import ConstantMind, RandomMind, loop
from wmthesis.data import EpisodeBuffer
from wmthesis.metrics import score_summary
from wmthesis.planet.train import load_planet, make_planet_env, play_greedy

FIRST_STEPS = 500  # 2,000 frames at action repeat 4: the author's episode cap


def play_bout(env_name: str, config: PlaNetConfig, run_dir: Path | None, env_seed: int, mind_seed: int,
              action: int | None = None) -> dict:
    """One full episode, greedy PlaNet from ``run_dir`` (when None: random play, or ``action``
    at every step where given): its ``return``, the return of its first :data:`FIRST_STEPS`
    steps, and its ``steps``."""
    env = make_planet_env(env_name, config)
    try:
        if run_dir is None:
            record, n = EpisodeBuffer(), env.action_space.n
            mind = RandomMind(n, seed=mind_seed) if action is None else ConstantMind(n, action)
            loop(env, mind, policy="deterministic", callbacks=[record], seed=env_seed, train_mode=False)
            rewards = [float(r) for r in record.episode["rewards"]]
        else:
            model, trained, _ = load_planet(run_dir)
            rewards = play_greedy(env, model, trained, env_seed, mind_seed)
    finally:
        env.close()
    return bout_result(rewards)


def bout_result(rewards) -> dict:
    """One bout's rewards (T,) summed: its ``return``, the return of its first
    :data:`FIRST_STEPS` steps and its ``steps``."""
    return {"return": float(sum(rewards)), "first": float(sum(rewards[:FIRST_STEPS])), "steps": len(rewards)}


def bout_scores(plays: list[dict]) -> dict:
    """:func:`play_bout`'s plays summed up: ``full`` and ``first``-500-step scores
    (:func:`~wmthesis.metrics.score_summary`) with their ``returns`` and ``first_returns``."""
    return {"full": score_summary([p["return"] for p in plays]), "first": score_summary([p["first"] for p in plays]),
            "returns": [p["return"] for p in plays], "first_returns": [p["first"] for p in plays]}


__all__ = ["FIRST_STEPS", "play_bout", "bout_result", "bout_scores"]
