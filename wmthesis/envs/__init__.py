"""Environments by name: ``make_env("boxing" | "freeway" | "sokoban" | "sokoban-small", ...)``.

Atari games come from ale-py (frame skip 4, sticky actions off, full-length episodes);
Sokoban is this package's own procedurally generated, seeded implementation.
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np

from wmthesis.config import ATARI_ENVIRONMENTS, ENVIRONMENTS, SOKOBAN_ENVIRONMENTS
from wmthesis.utils import check_choice

ATARI_GAMES = {name: name.capitalize() for name in ATARI_ENVIRONMENTS}  # name -> ale-py's game
SOKOBAN_VARIANTS = dict(zip(SOKOBAN_ENVIRONMENTS, (dict(dim_room=(10, 10), num_boxes=4),
                                                   dict(dim_room=(7, 7), num_boxes=2))))
ENV_NAMES = ENVIRONMENTS

ATARI_OPTIONS = ("preprocessing", "action_repeat", "max_steps", "render_mode")
SOKOBAN_OPTIONS = ("observation", "max_steps", "render_mode", "tile_size", "frame_size", "levels")


def make_env(name: str, **options) -> gym.Env:
    """Make environment `name` with game-specific `options`.

    Atari (``boxing``, ``freeway``): ``preprocessing`` in ``none`` (raw 210x160 RGB),
    ``world_models`` (crop, 64x64 RGB) or ``planet`` (64x64, 5 bits); ``action_repeat``
    (frame skip, default 4); ``max_steps`` (truncate earlier); ``render_mode``.

    Sokoban (``sokoban``: 10x10 with 4 boxes, ``sokoban-small``: 7x7 with 2 boxes):
    ``observation`` in ``rgb`` or ``grid``; ``max_steps`` (default 120); ``render_mode``;
    ``tile_size`` (pixels per cell); ``frame_size`` (World Models frames: the outer wall ring
    cropped, resized to ``frame_size`` x ``frame_size``); ``levels``: a level source instead of
    generated levels, e.g. ``"boxoban-unfiltered-valid:005-009"`` (DeepMind's Boxoban levels,
    :mod:`wmthesis.envs.boxoban`), a text file's path or a list of boards
    (:func:`wmthesis.envs.boxoban.load_levels`).

    Unknown names and options fail at once with the valid ones listed.
    """
    check_choice("environment", name, ENV_NAMES)
    if name in ATARI_GAMES:
        _check_options(name, options, ATARI_OPTIONS)
        from wmthesis.envs.atari import make_atari

        return make_atari(ATARI_GAMES[name], **options)
    _check_options(name, options, SOKOBAN_OPTIONS)
    from wmthesis.envs.sokoban import SokobanEnv

    return SokobanEnv(**SOKOBAN_VARIANTS[name], **options)


def random_frames(name: str, n: int, every: int = 1, seed: int = 0, **options) -> np.ndarray:
    """``n`` observations along one seeded random rollout of ``make_env(name, **options)``.

    Every ``every``-th observation is kept; the episode restarts (same seed stream) if it ends.
    Returns (n, *observation_shape).
    """
    env = make_env(name, **options)
    env.action_space.seed(seed)
    observation, _ = env.reset(seed=seed)
    frames, step = [], 0
    while len(frames) < n:
        if step % every == 0:
            frames.append(observation)
        observation, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            observation, _ = env.reset()
        step += 1
    env.close()
    return np.stack(frames)


def _check_options(name: str, options: dict, valid: tuple) -> None:
    unknown = sorted(set(options) - set(valid))
    if unknown:
        raise TypeError(f"unknown option(s) {unknown} for {name!r}; valid: {', '.join(valid)}")


def _register() -> None:
    """Register Sokoban under gymnasium ids ``wmthesis/Sokoban-v0`` and ``wmthesis/SokobanSmall-v0``."""
    for env_id, variant in (("wmthesis/Sokoban-v0", "sokoban"), ("wmthesis/SokobanSmall-v0", "sokoban-small")):
        if env_id not in gym.registry:
            gym.register(env_id, entry_point="wmthesis.envs.sokoban:SokobanEnv",
                         kwargs=dict(SOKOBAN_VARIANTS[variant]))


_register()

__all__ = ["make_env", "random_frames", "ENV_NAMES", "ATARI_GAMES", "SOKOBAN_VARIANTS"]
