"""Evaluation games shared by every agent compared on Boxing (thesis 5.4.2): the same seeded
no-op starts for each, greedy play, returns."""
from __future__ import annotations

from typing import Callable

from wmthesis.alphazero.replay import game_seeds
from wmthesis.core import Mind, loop
from wmthesis.envs.atari import noop_count
from wmthesis.utils import derive_seeds


def evaluation_seeds(seed: int, episodes: int, noop_max: int = 30) -> list[int]:
    """The seed of each evaluation game, shared by every agent compared (through
    :func:`~wmthesis.alphazero.replay.game_seeds`: the same no-op starts). Seeds whose no-op
    count repeats an earlier game's are skipped: Boxing is deterministic, so a greedy agent
    would replay the same game."""
    seeds, counts, k = [], set(), 0
    while len(seeds) < episodes:
        game_seed = int(derive_seeds(seed, 3, k)[0])
        count = noop_count(game_seeds(game_seed)[0], noop_max)
        if count not in counts or len(counts) >= max(noop_max, 1):
            seeds.append(game_seed)
            counts.add(count)
        k += 1
    return seeds


def greedy_returns(env, make_mind: Callable[[int], Mind], seeds, *, max_steps: int | None,
                   as_callback: bool = True) -> list[float]:
    """The return of one greedy game per seed in ``seeds``: the env is reset with the first of
    :func:`~wmthesis.alphazero.replay.game_seeds` and ``make_mind`` gets the second (the
    agent's own seed). ``as_callback``: the mind also follows each step (a mind with a memory)."""
    returns = []
    for game_seed in seeds:
        env_seed, agent_seed = game_seeds(game_seed)
        mind = make_mind(agent_seed)
        history = loop(env, mind, policy="deterministic", callbacks=[mind] if as_callback else None,
                       max_steps=max_steps, seed=env_seed, train_mode=False)
        returns.append(float(history[0]["return"]))
    return returns
