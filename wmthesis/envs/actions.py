"""Bad actions never act silently: every environment checks what it is told to play.

:func:`check_action` refuses anything but an integer in ``[0, n)`` with a ``ValueError`` that
names the action and the valid range (negative, out of range, non-integer, NaN, arrays of
the wrong shape). :class:`EpisodeGuard` adds gymnasium's order of calls: ``reset()`` before
the first ``step()``, and a new ``reset()`` after an episode ended (gymnasium leaves stepping
past the end undefined; here it is refused, saying so).
"""
from __future__ import annotations

import numbers

import gymnasium as gym
import numpy as np


def check_action(action, n: int) -> int:
    """``action`` as an int if it is an integer in ``[0, n)``; a ``ValueError`` otherwise."""
    value = action
    if isinstance(value, np.ndarray) and value.shape == ():
        value = value.item()
    valid = f"a valid action is an integer in [0, {n - 1}]"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise ValueError(f"action {action!r} is not an integer; {valid}")
    if not 0 <= value < n:
        raise ValueError(f"action {action!r} is out of range; {valid}")
    return int(value)


def check_actions(actions, n: int, count: int) -> np.ndarray:
    """``actions`` of a batch of ``count`` games as int64 (count,): one integer in ``[0, n)`` each,
    as :func:`check_action` takes one; a ``ValueError`` saying which is wrong otherwise."""
    values = np.asarray(actions)
    if values.shape != (count,):
        raise ValueError(f"pass one action per game: {count} actions, got shape {values.shape}")
    if values.dtype == bool or not np.issubdtype(values.dtype, np.integer):
        raise ValueError(f"actions {actions!r} are not integers; a valid action is an integer in [0, {n - 1}]")
    wrong = np.flatnonzero((values < 0) | (values >= n))
    if len(wrong):
        raise ValueError(f"action {values[wrong[0]]} of game {wrong[0]} is out of range; a valid action is an integer "
                         f"in [0, {n - 1}]")
    return values.astype(np.int64)


def check_order(state: str) -> None:
    """Refuse a ``step()`` in episode ``state`` ``new`` (no reset yet) or ``ended``."""
    if state == "new":
        raise RuntimeError("step() before reset(): call reset() first to start an episode")
    if state == "ended":
        raise RuntimeError("step() after the episode ended (terminated or truncated): gymnasium leaves "
                           "that undefined; call reset() to start a new episode")


class EpisodeGuard(gym.Wrapper):
    """Checks each action against the discrete ``action_space`` (:func:`check_action`) and the
    order of calls: ``step()`` before ``reset()`` and ``step()`` after the episode ended raise
    a ``RuntimeError`` saying to call ``reset()``."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self._state = "new"  # new -> running -> ended -> running ...

    def reset(self, **kwargs):
        observation, info = self.env.reset(**kwargs)
        self._state = "running"
        return observation, info

    def step(self, action):
        check_order(self._state)
        observation, reward, terminated, truncated, info = self.env.step(check_action(action, self.action_space.n))
        if terminated or truncated:
            self._state = "ended"
        return observation, reward, terminated, truncated, info


def check_positive(name: str, value) -> None:
    """Refuse ``value`` unless it is a positive integer (a bool is not), in one line naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
