"""Expert games for World Models + AlphaZero (the ``imitation`` variant, beyond the thesis).

AlphaGo started its policy network from expert games before self-play; here the expert is
notebook 02's evolved controller (any :class:`~wmthesis.core.Mind` will do). While it plays real
bouts, :class:`ExpertRecorder` runs the search's own deterministic memory beside it on the same
frames and actions, so each step becomes a training sample of the AlphaZero heads:
features ``[z_t h_{t-1}]`` (the memory's h, not the expert's), the expert's action as a one-hot
policy target, and the real reward for the value targets. :func:`expert_games` returns them as
:class:`~wmthesis.alphazero.replay.Game` records; :func:`~wmthesis.alphazero.selfplay.train_alphazero`
puts them in the replay and pretrains the heads on them before the first self-play game.
"""
from __future__ import annotations

import time
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from wmthesis.alphazero.latent_mdp import State
from wmthesis.alphazero.replay import Game, game_seeds
from wmthesis.core import Callback, Mind, loop


class ExpertRecorder(Callback):
    """Records one game of another mind as a :class:`~wmthesis.alphazero.replay.Game`.

    ``vision``: uint8 frames (N, ...) -> latents (N, L); ``mdp``: the
    :class:`~wmthesis.alphazero.latent_mdp.LatentMDP` whose LSTM state gives the features, stepped
    with every real action as :class:`~wmthesis.alphazero.selfplay.AlphaZeroMind` steps it. Pass it
    to :func:`~wmthesis.core.loop` as a callback; the finished game is in :attr:`game`.
    """

    def __init__(self, vision: Callable, mdp):
        self.vision, self.mdp = vision, mdp
        self.index, self.game = 0, None

    @torch.inference_mode()
    def encode(self, frame) -> np.ndarray:
        return self.vision(torch.as_tensor(np.asarray(frame))[None])[0].float().cpu().numpy()

    def on_episode_start(self, episode: int, train_mode: bool) -> None:
        self.h = np.zeros(self.mdp.hidden_size, np.float32)
        self.c = np.zeros(self.mdp.hidden_size, np.float32)
        self._steps = {key: [] for key in ("features", "actions", "rewards", "predicted_rewards")}
        self._last, self._terminated, self._started = None, False, time.perf_counter()

    def on_step_taken(self, step, transition, info) -> None:
        z = self.encode(transition.state)
        next_state, predicted = self.mdp.transition(State(z, self.h, self.c), transition.action)
        for key, value in (("features", np.concatenate([z, self.h])), ("actions", transition.action),
                           ("rewards", transition.reward), ("predicted_rewards", predicted)):
            self._steps[key].append(value)
        self.h, self.c = next_state.h, next_state.c
        self._terminated = transition.is_terminal
        if transition.is_terminal or info.get("truncated"):
            self._last = np.concatenate([self.encode(transition.next_state), self.h])

    def on_episode_end(self, episode: int, train_mode: bool) -> None:
        s, A = self._steps, self.mdp.n_actions
        actions = np.array(s["actions"], np.int64)
        T = len(actions)
        features = np.stack(s["features"]).astype(np.float32)
        self.game = Game(
            index=self.index, features=features, policies=np.eye(A, dtype=np.float32)[actions], actions=actions,
            rewards=np.array(s["rewards"], np.float32), predicted_rewards=np.array(s["predicted_rewards"], np.float32),
            root_values=np.full(T, np.nan, np.float32), depths=np.zeros(T, np.int16),
            q=np.full((T, A), np.nan, np.float32), terminated=self._terminated,
            last_features=self._last if self._last is not None else features[-1],
            seconds=time.perf_counter() - self._started)


def expert_games(env, make_expert: Callable[[int], object], vision: Callable, mdp, seeds, *,
                 max_steps: int | None = None, progress: bool = True) -> list:
    """One greedy game of the expert per seed in ``seeds``, recorded by :class:`ExpertRecorder`.

    ``make_expert(agent_seed)``: a fresh :class:`~wmthesis.core.Mind` for one game; when it is
    also a :class:`~wmthesis.core.Callback` (as the World Models controller, whose memory must
    follow the real actions), it gets the loop's callbacks too. The game of seed ``s`` resets
    the env with and seeds the expert from :func:`~wmthesis.alphazero.replay.game_seeds` of ``s``.
    """
    recorder, games = ExpertRecorder(vision, mdp), []
    for index, seed in enumerate(tqdm(list(seeds), desc="expert games", disable=not progress)):
        env_seed, agent_seed = game_seeds(int(seed))
        expert = make_expert(agent_seed)
        callbacks = [recorder] + ([expert] if isinstance(expert, Callback) else [])
        recorder.index = index
        loop(env, expert, policy="deterministic", callbacks=callbacks, max_steps=max_steps, seed=env_seed,
             train_mode=False)
        games.append(recorder.game)
    return games


def agreement(heads, games) -> float:
    """The fraction of the games' steps where the policy head's most likely action is the one
    played (for expert games: how well the heads imitate the expert)."""
    features = torch.from_numpy(np.concatenate([g.features for g in games]))
    actions = torch.from_numpy(np.concatenate([g.actions for g in games]))
    with torch.no_grad():
        logits, _ = heads(features)
    return float((logits.argmax(-1) == actions).float().mean())


class PolicyHeadMind(Mind, Callback):
    """The AlphaZero policy head played without search: ``plan(frame)`` returns its logits
    (A,) on ``[z_t h_{t-1}]``, with ``h`` from ``mdp`` stepped on the real actions (pass the
    mind as a callback too); :attr:`recorder` ``.game`` holds the last game played. How much
    the search adds to what the heads learned."""

    def __init__(self, vision: Callable, mdp, heads):
        self.recorder, self.heads = ExpertRecorder(vision, mdp), heads

    def on_episode_start(self, episode: int, train_mode: bool) -> None:
        self.recorder.on_episode_start(episode, train_mode)

    def plan(self, state, train_mode: bool = True, debug_mode: bool = False) -> np.ndarray:
        features = np.concatenate([self.recorder.encode(state), self.recorder.h])
        with torch.no_grad():
            logits, _ = self.heads(torch.from_numpy(features)[None])
        return logits[0].numpy()

    def on_step_taken(self, step, transition, info) -> None:
        self.recorder.on_step_taken(step, transition, info)

    def on_episode_end(self, episode: int, train_mode: bool) -> None:
        self.recorder.on_episode_end(episode, train_mode)
