"""One bout (a full episode) of PlaNet on an Atari game, and bouts summed up: a bout's return,
the return of its first :data:`FIRST_STEPS` agent steps (the author's PlaNet runs capped episodes
at 2,000 frames, 500 agent steps: like is compared with like) and its length."""
from __future__ import annotations

from pathlib import Path

from wmthesis.core import ConstantMind, RandomMind, loop
from wmthesis.rollouts import EpisodeBuffer
from wmthesis.metrics import score_cell, score_summary
from wmthesis.references import HUMAN, THESIS_PLANET_BOXING, human
from wmthesis.planet.config import PlaNetConfig
from wmthesis.planet.train import load_planet
from wmthesis.planet.frames import make_planet_env
from wmthesis.planet.agent import play_greedy

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
    (:func:`~wmthesis.metrics.score_summary`) with their ``returns`` and ``first_returns``, and the
    ``ms_per_action`` where every play was timed."""
    timed = all("seconds" in p for p in plays)
    return {"full": score_summary([p["return"] for p in plays]), "first": score_summary([p["first"] for p in plays]),
            "returns": [p["return"] for p in plays], "first_returns": [p["first"] for p in plays],
            **({"ms_per_action": 1000 * sum(p["seconds"] for p in plays) / max(1, sum(p["steps"] for p in plays))}
               if timed else {})}


def agent_table(metrics: dict) -> str:
    """The agent's bouts beside random play on the same bouts and the references (markdown)."""
    diff, first = metrics["difference"], metrics["difference_first"]
    return "\n".join([
        "| player | full bout | first 500 agent steps |", "|---|---|---|",
        f"| PlaNet (KL scale 0.03, free nats 12), {metrics['env_steps']:,} agent steps, {metrics['updates']:,} updates "
        f"| {score_cell(metrics['agent']['full'])} | {score_cell(metrics['agent']['first'])} |",
        f"| random play, same bouts | {score_cell(metrics['random']['full'])} | {score_cell(metrics['random']['first'])} |",
        f"| agent - random | {diff['difference']:.1f} ± {diff['standard_error']:.1f} (s.e.) "
        f"| {first['difference']:.1f} ± {first['standard_error']:.1f} (s.e.) |",
        f"| human ({HUMAN['boxing'].source}) | {human('boxing')} | |",
        f"| thesis PlaNet ({THESIS_PLANET_BOXING.source}) | {THESIS_PLANET_BOXING.value} | |"])


__all__ = ["agent_table", "FIRST_STEPS", "play_bout", "bout_result", "bout_scores"]
