"""Atari games through ale-py's gymnasium environments (thesis 5.1.1).

Deterministic settings as in the thesis: sticky actions off (``repeat_action_probability=0``),
frame skip = action repeat (4 by default), the game's own (minimal) action set, full-length
episodes (ALE's own limit only). Preprocessing is an observation wrapper:

- ``none``: raw frames, (210, 160, 3) uint8;
- ``world_models``: crop the border (:data:`~wmthesis.envs.preprocessing.CROPS`), resize to
  64x64, RGB, (64, 64, 3) uint8;
- ``planet``: resize the whole frame to 64x64 and keep 5 bits, (64, 64, 3) uint8 with values
  that are multiples of 8 (turn into floats with :func:`~wmthesis.envs.preprocessing.to_float`
  with ``bits=5``).
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np

from wmthesis.envs.actions import EpisodeGuard, check_positive
from wmthesis.envs.preprocessing import CROPS, crop_resize, quantize
from wmthesis.utils import check_choice

PREPROCESSING = ("none", "world_models", "planet")
FRAME_SIZE = 64


class FramePreprocessing(gym.ObservationWrapper):
    """Observation wrapper applying one of :data:`PREPROCESSING` to raw Atari frames."""

    def __init__(self, env: gym.Env, mode: str, crop: tuple[int, int, int, int] | None = None):
        check_choice("preprocessing", mode, PREPROCESSING)
        super().__init__(env)
        self.mode = mode
        self.crop = crop
        if mode != "none":
            channels = env.observation_space.shape[-1]
            self.observation_space = gym.spaces.Box(
                0, 255, (FRAME_SIZE, FRAME_SIZE, channels), np.uint8)

    def observation(self, frame: np.ndarray) -> np.ndarray:
        """(210, 160, 3) uint8 -> the mode's observation (see the module docstring)."""
        if self.mode == "world_models":
            return crop_resize(frame, self.crop, FRAME_SIZE)
        if self.mode == "planet":
            return quantize(crop_resize(frame, None, FRAME_SIZE), bits=5)
        return frame


def quiet_emulator() -> None:
    """The emulator's errors only: no banner on stderr each time a game loads."""
    import ale_py

    ale_py.ALEInterface.setLoggerMode(ale_py.LoggerMode.Error)


def make_atari(game: str, preprocessing: str = "none", action_repeat: int = 4,
               max_steps: int | None = None, render_mode: str | None = None) -> gym.Env:
    """ale-py's ``ALE/{game}-v5`` with the thesis's deterministic settings.

    `game` is ``"Boxing"`` (18 actions) or ``"Freeway"`` (3 actions); `preprocessing` one of
    :data:`PREPROCESSING`; `action_repeat` frames per agent step; `max_steps` truncates episodes
    (``truncated=True``) after that many agent steps.
    """
    check_choice("Atari game", game, tuple(CROPS))
    check_choice("preprocessing", preprocessing, PREPROCESSING)
    check_positive("action_repeat", action_repeat)
    if max_steps is not None:
        check_positive("max_steps", max_steps)
    import ale_py

    quiet_emulator()
    gym.register_envs(ale_py)
    env = gym.make(f"ALE/{game}-v5", frameskip=action_repeat, repeat_action_probability=0.0,
                   full_action_space=False, render_mode=render_mode)
    if preprocessing != "none":
        env = FramePreprocessing(env, preprocessing, CROPS[game])
    if max_steps is not None:
        env = gym.wrappers.TimeLimit(env, max_episode_steps=max_steps)
    return EpisodeGuard(env)


class NoopStart(gym.Wrapper):
    """Starts each episode with ``k`` no-op actions (action 0), ``k`` in ``[0, noop_max)``
    drawn from the reset's seed (the controller's evaluation does the same): Boxing without
    sticky actions is deterministic, so greedy test games would otherwise all be one game."""

    def __init__(self, env, noop_max: int = 30):
        super().__init__(env)
        self.noop_max, self.rng = noop_max, np.random.default_rng()

    def reset(self, *, seed=None, options=None):
        observation, info = self.env.reset(seed=seed, options=options)
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        for _ in range(int(self.rng.integers(max(self.noop_max, 1)))):  # noop_count(seed, noop_max) when seeded
            observation, _, terminated, truncated, info = self.env.step(0)
            if terminated or truncated:
                observation, info = self.env.reset()
        return observation, info


class ScoredStart(gym.Wrapper):
    """No-op starts the agent sees, as the World Models controller was scored (the batched
    :class:`~wmthesis.envs.vector.AtariGame`): after a reset with ``seed``, the first
    :func:`noop_count` steps play action 0 whatever the agent asks, and every step's
    ``info["action"]`` is the action played (a mind that steps a memory steps it with that one).
    Unlike :class:`NoopStart`, the no-op frames are the agent's, so its memory sees them."""

    def __init__(self, env, noop_max: int = 30):
        super().__init__(env)
        self.noop_max, self.noops, self.t = noop_max, 0, 0

    def reset(self, *, seed=None, options=None):
        observation, info = self.env.reset(seed=seed, options=options)
        self.noops = noop_count(seed, self.noop_max) if seed is not None else 0
        self.t = 0
        return observation, {**info, "noops": self.noops}

    def step(self, action):
        played = 0 if self.t < self.noops else action
        self.t += 1
        observation, reward, terminated, truncated, info = self.env.step(played)
        return observation, reward, terminated, truncated, {**info, "action": int(played)}


def noop_count(seed: int, noop_max: int = 30) -> int:
    """The number of no-ops :class:`NoopStart` plays after a reset with ``seed``."""
    return int(np.random.default_rng(seed).integers(max(noop_max, 1)))


def boxing_env(noop_max: int = 30) -> gym.Env:
    """Boxing with World Models frames (64, 64, 3) uint8 and no-op starts."""
    return NoopStart(make_atari("Boxing", preprocessing="world_models"), noop_max)
