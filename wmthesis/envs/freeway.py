"""Freeway planned with a perfect model: the emulator itself, its state cloned and restored.

Not an agent (it reads the game's memory and rewinds it); a ceiling for the planners that imagine
Freeway in a learned model (:mod:`wmthesis.planet`), as A* is for Sokoban. At every step it tries,
for each ``w`` in ``0 .. horizon - 1``, waiting ``w`` steps (NOOP) then pressing UP until the
horizon, each from a copy of the current state, and takes the first action of the candidate that
ends with the most crossings, then with the chicken highest on the road (the earliest of ties:
UP when nothing is gained by waiting). With a horizon of 1 it is UP at every step.

With the thesis's settings Freeway is deterministic (no sticky actions, no no-op starts): its
cars follow the same pattern whatever the seed, so UP at every step scores the same on every
episode.
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np

from wmthesis.envs.actions import check_positive

# Player 1's height on the road (it rises as the chicken crosses), from AtariARI's RAM
# annotations (Anand et al. 2019, mila-iqia/atari-representation-learning).
CHICKEN_Y = 14
NOOP, UP = 0, 1  # Freeway's minimal action set: NOOP, UP, DOWN


def lookahead_action(env: gym.Env, horizon: int) -> int:
    """The first action (NOOP or UP, as indices of ``env``'s action space) of the best
    "wait, then UP" plan of ``horizon`` steps, each played from a copy of ``env``'s emulator
    state; the state is the same afterwards. ``env``: Freeway from :func:`~wmthesis.envs.make_env`
    (any wrappers), its frame skip the action repeat."""
    check_positive("horizon", horizon)
    game = env.unwrapped
    if getattr(game, "_game", None) != "freeway":
        raise ValueError(f"lookahead_action plays Freeway, got {getattr(game, '_game', type(game).__name__)!r}")
    ale, actions, repeat = game.ale, game._action_set, game._frameskip
    start = ale.cloneState()
    best, best_score = 0, None
    for wait in range(horizon):
        reward = 0
        for step in range(horizon):
            action = actions[NOOP] if step < wait else actions[UP]
            reward += sum(ale.act(action) for _ in range(repeat))
        score = (int(reward), int(ale.getRAM()[CHICKEN_Y]))
        if best_score is None or score > best_score:
            best, best_score = wait, score
        ale.restoreState(start)
    return NOOP if best > 0 else UP


def play_lookahead(env: gym.Env, horizon: int, seed: int) -> dict[str, np.ndarray]:
    """One episode of ``env`` (reset with ``seed``) played by :func:`lookahead_action`:
    ``observations`` (T, ...) each seen before its step's action, ``actions`` (T,) int64 and
    ``rewards`` (T,) float32."""
    observation, _ = env.reset(seed=seed)
    observations, actions, rewards, done = [], [], [], False
    while not done:
        action = lookahead_action(env, horizon)
        observations.append(observation)
        actions.append(action)
        observation, reward, terminated, truncated, _ = env.step(action)
        rewards.append(reward)
        done = terminated or truncated
    return {"observations": np.stack(observations), "actions": np.asarray(actions, np.int64),
            "rewards": np.asarray(rewards, np.float32)}


__all__ = ["CHICKEN_Y", "lookahead_action", "play_lookahead"]
