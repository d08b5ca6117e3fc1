"""Vectorised games for batched evaluation (a whole CMA-ES population at once).

:class:`AtariGame` steps ale-py's C++ vector env and preprocesses as the World Models frames;
:class:`ListGame` steps a list of gymnasium envs (Sokoban). :func:`make_game` picks one by name.
Both share one interface: ``reset(seeds) -> observations``, ``step(actions) -> (observations,
rewards, done)``, ``noops`` (leading no-op actions per env), ``timings``.
"""
from __future__ import annotations

import os
from collections import defaultdict
from typing import Callable

import numpy as np

from wmthesis.envs import ATARI_GAMES, make_env
from wmthesis.envs.actions import check_actions
from wmthesis.envs.preprocessing import CROPS, crop_resize
from wmthesis.utils import check_choice, check_count, check_seed, timed

MAX_GAMES = 4096  # games one batch steps at once: 64 candidates x 64 episodes; more would not fit in memory


class AtariGame:
    """``num_envs`` Atari games in ale-py's C++ vector env with World Models frames.

    Same dynamics as :func:`wmthesis.envs.atari.make_atari` (frame skip 4, sticky actions off,
    no max-pooling, no fire on reset, unclipped rewards), raw frames cropped and resized to
    (64, 64, 3) uint8 here with the same :func:`crop_resize`. The games are deterministic, so
    ``reset(seeds)`` only draws, from each episode's seed, its number of leading no-op actions
    in ``[0, noop_max)`` (``noops``, (N,)), which the evaluator plays before the controller
    takes over (a seeded reset of ale-py reloads the ROM: ~0.15 s an env). ``step(actions)``
    returns ``(frames, rewards, done)``; once an env's episode ended, its rewards are 0 and its
    frames stale. ``timings`` accumulates seconds under ``env`` and ``preprocess``.
    """

    def __init__(self, game: str, num_envs: int, *, noop_max: int = 30, action_repeat: int = 4,
                 num_threads: int | None = None):
        from ale_py.vector_env import AtariVectorEnv

        from wmthesis.envs.atari import quiet_emulator

        quiet_emulator()
        self.num_envs, self.crop = num_envs, CROPS[game]
        self.env = AtariVectorEnv(
            game.lower(), num_envs, num_threads=num_threads or min(num_envs, os.cpu_count() or 1),
            img_height=210, img_width=160, grayscale=False, stack_num=1, frameskip=action_repeat,
            maxpool=False, repeat_action_probability=0.0, noop_max=0, reward_clipping=False,
            episodic_life=False, use_fire_reset=False)
        self.n_actions, self.noop_max = int(self.env.single_action_space.n), noop_max
        self.noops = np.zeros(num_envs, np.int64)
        self.frames = np.zeros((num_envs, 64, 64, 3), np.uint8)
        self.done = np.ones(num_envs, bool)
        self.timings: dict = defaultdict(float)

    def reset(self, seeds: np.ndarray) -> np.ndarray:
        seeds = check_episode_seeds(seeds, self.num_envs)
        with timed(self.timings, "env"):
            raw, _ = self.env.reset()
        self.noops = np.array([np.random.default_rng(s).integers(max(self.noop_max, 1)) for s in seeds])
        self.done[:] = False
        return self._preprocess(raw)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        with timed(self.timings, "env"):
            raw, rewards, terminated, truncated, _ = self.env.step(check_actions(actions, self.n_actions, self.num_envs))
        rewards = np.where(self.done, 0.0, rewards.astype(np.float64))
        self.done |= terminated | truncated
        return self._preprocess(raw), rewards, self.done.copy()

    def _preprocess(self, raw: np.ndarray) -> np.ndarray:
        """(N, 1, 210, 160, 3) raw frames -> (N, 64, 64, 3) World Models frames (live envs only)."""
        with timed(self.timings, "preprocess"):
            for i in np.flatnonzero(~self.done):
                self.frames[i] = crop_resize(raw[i, 0], self.crop, 64)
        return self.frames

    def close(self) -> None:
        self.env.close()


class ListGame:
    """``num_envs`` gymnasium envs from ``make()`` stepped in a list (Sokoban); same interface
    as :class:`AtariGame`. Observations are as the envs return them; ``reset(seeds)`` seeds
    each env's episode (a new Sokoban level per seed); no leading no-ops."""

    def __init__(self, make: Callable, num_envs: int):
        self.envs = [make() for _ in range(num_envs)]
        self.num_envs, self.n_actions = num_envs, int(self.envs[0].action_space.n)
        self.noops = np.zeros(num_envs, np.int64)  # Sokoban has no no-op action
        self.observations: np.ndarray | None = None
        self.done = np.ones(num_envs, bool)
        self.timings: dict = defaultdict(float)

    def reset(self, seeds: np.ndarray) -> np.ndarray:
        seeds = check_episode_seeds(seeds, self.num_envs)
        with timed(self.timings, "env"):
            self.observations = np.stack([env.reset(seed=s)[0] for env, s in zip(self.envs, seeds)])
        self.done[:] = False
        return self.observations

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rewards, actions = np.zeros(self.num_envs), check_actions(actions, self.n_actions, self.num_envs)
        with timed(self.timings, "env"):
            for i in np.flatnonzero(~self.done):
                observation, rewards[i], terminated, truncated, _ = self.envs[i].step(int(actions[i]))
                self.observations[i] = observation
                self.done[i] = terminated or truncated
        return self.observations, rewards, self.done.copy()

    def close(self) -> None:
        for env in self.envs:
            env.close()


def check_episode_seeds(seeds, num_envs: int) -> list[int]:
    """``seeds``, one whole number from 0 to 2**31 - 1 per game, as ints; ValueError in one line otherwise
    (the emulator and the level generator are never reached with a seed they cannot take)."""
    seeds = list(np.asarray(seeds).reshape(-1)) if not isinstance(seeds, (list, tuple)) else list(seeds)
    if len(seeds) != num_envs:
        raise ValueError(f"reset needs one seed per game: {num_envs} games, {len(seeds)} seeds")
    return [check_seed(s) for s in seeds]


def make_game(name: str, num_envs: int, *, noop_max: int = 30, num_threads: int | None = None, **options):
    """``num_envs`` copies of game ``name`` for batched evaluation.

    Atari games (``boxing``, ``freeway``): :class:`AtariGame` (options: ``action_repeat``).
    Sokoban: :class:`ListGame` of ``make_env(name, **options)`` (``noop_max`` is unused).
    """
    check_choice("environment", name, tuple(ATARI_GAMES) + ("sokoban", "sokoban-small"))
    num_envs = check_count(num_envs, "num_envs (games played at once)", MAX_GAMES)
    if name in ATARI_GAMES:
        unknown = sorted(set(options) - {"action_repeat"})
        if unknown:
            raise TypeError(f"unknown option(s) {unknown} for the batched {name!r}; valid: action_repeat")
        return AtariGame(ATARI_GAMES[name], num_envs, noop_max=noop_max, num_threads=num_threads, **options)
    return ListGame(lambda: make_env(name, **options), num_envs)
