"""The value agent at play (:mod:`~wmthesis.value.latent_value`): greedy and epsilon-greedy bouts of a
value on a frozen PlaNet model, alone or in a pool of processes, on the seeded evaluation and
validation bouts (apart from each other and from training's)."""
from __future__ import annotations

from contextlib import contextmanager, nullcontext

import numpy as np

from wmthesis.core import loop
from wmthesis.rollouts import EpisodeBuffer
from wmthesis.planet.rssm import RSSM
from wmthesis.utils import derive_seeds, parallel_calls, process_pool
from wmthesis.value.latent_value import LatentValue, ValueMind


def play_value(env, model: RSSM, value: LatentValue, bits: int, env_seed: int, mind_seed: int,
               epsilon: float = 0.0) -> dict[str, np.ndarray]:
    """One episode of the value agent, greedy (``epsilon`` 0) or epsilon-greedy: the arrays of
    :meth:`~wmthesis.data.EpisodeStore.append_episode`."""
    mind, record = ValueMind(model, value, bits, mind_seed), EpisodeBuffer()
    policy = "epsilon-greedy" if epsilon else "deterministic"
    loop(env, mind, policy=policy, policy_options={"epsilon": epsilon} if epsilon else None,
         callbacks=[mind, record], seed=int(env_seed), train_mode=False)
    return record.episode


def _play_made(make_env: tuple, model: RSSM, value: LatentValue, bits: int, env_seed: int, mind_seed: int,
               epsilon: float) -> dict[str, np.ndarray]:
    """:func:`play_value` in an environment of its own, ``make_env`` = ``(fn, *args)``."""
    fn, *args = make_env
    env = fn(*args)
    try:
        return play_value(env, model, value, bits, env_seed, mind_seed, epsilon)
    finally:
        env.close()


def play_values(env, model: RSSM, value: LatentValue, bits: int, seeds, epsilon: float = 0.0,
                pool: tuple | None = None, on_done=None) -> list[dict[str, np.ndarray]]:
    """:func:`play_value` on each (environment, mind) pair of ``seeds``, in order. With ``pool``
    (``(executor, make_env)``, :func:`bout_pool`), in its processes, two bouts at a time: the
    same bouts, each seeded by its pair. ``on_done(index, episode)`` is called in the order of
    ``seeds``, as soon as each bout and those before it have ended (to store them in order)."""
    seeds = [tuple(int(v) for v in pair) for pair in seeds]
    on_done = on_done or (lambda index, episode: None)
    if pool is None:
        episodes = []
        for index, pair in enumerate(seeds):
            episodes.append(play_value(env, model, value, bits, *pair, epsilon))
            on_done(index, episodes[-1])
        return episodes
    executor, make_env = pool
    ended, given = {}, [0]

    def in_order(index: int, episode: dict) -> None:
        ended[index] = episode
        while given[0] in ended:
            on_done(given[0], ended.pop(given[0]))
            given[0] += 1

    calls = [(_play_made, make_env, model, value, bits, *pair, epsilon) for pair in seeds]
    return parallel_calls(calls, progress=False, on_done=in_order, executor=executor)


@contextmanager
def bout_pool(model: RSSM, make_env: tuple | None):
    """The ``pool`` of :func:`play_values` for a run: processes of their own (:func:`~wmthesis.utils.process_pool`)
    that build the game with ``make_env`` (``(fn, *args)``, module-level); None (bouts in this
    process) without ``make_env``, on one core, or for a model on a GPU."""
    on_cpu = next(model.parameters()).device.type == "cpu"
    with process_pool() if make_env is not None and on_cpu else nullcontext(None) as executor:
        yield None if executor is None else (executor, make_env)


def evaluation_seeds(seed: int, k: int) -> tuple[int, int]:
    """The (environment, mind) seeds of greedy test bout ``k``: those of the PlaNet agent's
    evaluation bouts (:func:`~wmthesis.experiments.planet_boxing.planet_boxing_agent`)."""
    env_seed, mind_seed = derive_seeds(seed, 3, k, n=2)
    return int(env_seed), int(mind_seed)


def validation_seeds(seed: int, k: int) -> tuple[int, int]:
    """The (environment, mind) seeds of greedy validation bout ``k``, apart from the test bouts
    and from the bouts it learns on: the bouts that choose among the rounds' values."""
    env_seed, mind_seed = derive_seeds(seed, 6, k, n=2)
    return int(env_seed), int(mind_seed)


def greedy_returns(env, model: RSSM, value: LatentValue, bits: int, seeds, first_steps: int = 0,
                    pool: tuple | None = None):
    """The greedy bouts' returns (:func:`play_values`); with ``first_steps``, also the returns of
    their first steps."""
    rewards = [episode["rewards"] for episode in play_values(env, model, value, bits, seeds, pool=pool)]
    full = [float(r.sum()) for r in rewards]
    return (full, [float(r[:first_steps].sum()) for r in rewards]) if first_steps else full


__all__ = ["play_value", "play_values", "bout_pool", "evaluation_seeds", "validation_seeds", "greedy_returns"]
