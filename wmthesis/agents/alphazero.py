"""World Models + AlphaZero (thesis 4.3, 5.4.2): tree search inside the deterministic memory.

One real step, top to bottom (:class:`AlphaZeroMind`)::

    frame --vision--> z_t ─┐
    memory state (h_{t-1}, c_{t-1}) ─┴─> root State --MCTS(LatentMDP, Evaluator)--> visit counts N(root, .)
    policy(visit counts) -> a_t;  the memory reads (z_t, a_t) -> (h_t, c_t) for the next root

- :class:`LatentMDP` wraps a deterministic :class:`~wmthesis.models.memory.Memory` (thesis
  4.3.1) as the :class:`~wmthesis.core.MDP` the search expands: a :class:`State` is the latent z,
  the LSTM's (h, c) and a terminal flag; one transition is one LSTM step, whose output h gives
  the next z, the reward and the done flag through the memory's linear heads. Nodes are objects:
  states are never hashed (the author's ``query_tree`` hashed them).
- :class:`AlphaZeroHeads`: linear policy and value heads on ``[z h]`` (thesis 4.3.3);
  :class:`Evaluator` hands the search ``(priors, value)``.
- Self-play (:func:`train_alphazero`): games follow the visit counts in proportion for 12
  warm-up steps, then greedily; the latest 1,000 games are kept; after every 10 games, 5 epochs of
  value MSE + policy cross-entropy (to the visit distribution) + L2 1e-4, SGD Nesterov lr 1e-2,
  momentum 0.9, batch 256. Value targets are the discounted returns (:func:`value_targets`).
  A checkpoint (heads, optimiser, replay, counters, curves) after every training round lets a
  killed run resume and reach the same heads.

Variants (:data:`VARIANTS`): ``unchanged`` is the thesis's recipe, which "did not train to
properly plan". ``improved`` changes what the diagnosis points at in the search (beyond the
thesis): min-max normalised Q (MuZero: Boxing's rewards are rare and small, so raw Q differences
drown under the prior bonus and the search only follows its priors), equal visit counts broken
by the higher Q (``np.argmax`` gives them to action 0, the no-op), n-step bootstrapped value
targets (lower variance than whole-game returns, no bias at a game cut by ``max_steps``) and no
tree reuse (with concentrated visits a reused tree grows into one ever deeper line, slower at
every step). What it cannot change is the memory: trained on few random rollouts, its reward
head barely predicts held-out rewards (:func:`value_predictability`). ``learned-reward`` is
improved plus a :class:`RewardModel` for the search's rewards: a class-weighted MLP classifier
on ``[z h a]`` that credits each action with the reward two steps later (when Boxing's punches
land), pretrained on the random rollouts and trained again on them and the self-play games
after every round. It detects the steps before hits far better than chance, but not whose hit
they will be, nor which action makes the difference (:func:`action_predictability`).
``imitation`` is improved with the heads pretrained, before self-play, on greedy games of an
expert (notebook 02's evolved controller), as AlphaGo's policy started from expert games
(:mod:`wmthesis.agents.imitation`): the search then starts from priors that already box.

Diagnosis (5.4.2 asks "why"): :func:`reward_error_by_depth` (the memory's reward error k steps
into the search along real action sequences), :func:`value_predictability` (whether a linear
value on ``[z h]`` can predict returns at all), :func:`action_predictability` (whether ``[z h]``
says which action earns more over the next steps: what any planner needs), :func:`reward_fit`
(the reward model on held-out episodes) and :func:`search_statistics` (the value scale:
search values against the returns that followed; the spread of the root Q against the prior
bonus; ties and visit entropy), plotted by the figure functions at the end of this module.
"""
from __future__ import annotations

import dataclasses
import math
import os
import pickle
import time
from collections import deque
from pathlib import Path
from typing import Callable, NamedTuple

import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from tqdm import tqdm

from wmthesis.core import Callback, Mind, Proportional, loop
from wmthesis.training import check_resumable
from wmthesis.utils import atomic_path, check_choice, derive_seeds

VARIANTS = {
    "unchanged": {},  # thesis 4.3 as written
    "improved": dict(normalize_q=True, tie_break="q", value_target="n-step", reuse_tree=False),  # ours
    "learned-reward": dict(normalize_q=True, tie_break="q", value_target="n-step", reuse_tree=False,
                           reward_model=True),  # ours: improved + a reward model trained on self-play data
    "imitation": dict(normalize_q=True, tie_break="q", value_target="n-step", reuse_tree=False,
                      expert_games=8),  # ours: improved + heads pretrained on the World Models controller's games
}
VALUE_TARGETS = ("monte-carlo", "n-step")
FORMAT, FORMAT_VERSION = "wmthesis-alphazero", 1
CHECKPOINT_NAME = "alphazero.pkl"
RESUMABLE_FIELDS = ("games", "eval_episodes", "eval_max_steps")  # config fields that may change when resuming


# ----------------------------------------------------------------------------- the latent MDP
def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 0.5 * np.tanh(0.5 * x) + 0.5


class State(NamedTuple):
    """A state of the latent model: ``z`` (L,), the LSTM's ``h`` and ``c`` (H,), float32, and
    ``terminal`` (the done head's verdict on the step into it). ``h`` is the memory's output
    after reading the previous step, so the search's features are ``[z h]``, as the controller's."""

    z: np.ndarray
    h: np.ndarray
    c: np.ndarray
    terminal: bool = False


class LatentMDP:
    """A deterministic memory as an :class:`~wmthesis.core.MDP` (thesis 4.3.1).

    ``transition(State(z_t, h_{t-1}, c_{t-1}), a_t)``: the LSTM reads ``[z_t, one_hot(a_t)]``,
    ``(h_t, c_t) = LSTM(...)``; then ``z_{t+1} = W_z h_t + b_z``, ``r_{t+1} = w_r h_t + b_r`` and
    terminal iff ``sigmoid(w_d h_t + b_d) > 0.5``. Returns ``(State(z_{t+1}, h_t, c_t, done),
    r_{t+1})``.

    The weights are copied into numpy at construction (a snapshot: the memory is frozen while
    planning). One step is one (L+H) x 4H matrix-vector product (the one-hot input becomes a
    row of per-action biases) plus one H x (L+2) product for the heads: ~50 us on one core,
    against ~400 us through ``nn.LSTM`` for a batch of one. :meth:`step` takes batches too.
    """

    def __init__(self, memory, reward_model: "RewardModel | None" = None):
        if memory.kind != "deterministic":
            raise ValueError(f"the search needs a deterministic memory (thesis 4.3.1), got kind {memory.kind!r}")
        L, H, A = memory.latent_size, memory.hidden_size, memory.n_actions
        lstm = memory.lstm
        with torch.no_grad():
            w_ih = lstm.weight_ih_l0.detach().cpu().float().numpy()  # (4H, L + A), gates i, f, g, o
            w_hh = lstm.weight_hh_l0.detach().cpu().float().numpy()  # (4H, H)
            bias = (lstm.bias_ih_l0 + lstm.bias_hh_l0).detach().cpu().float().numpy()
            heads = [memory.next_latent, memory.reward, memory.done]
            w_out = torch.cat([head.weight for head in heads]).detach().cpu().float().numpy()  # (L + 2, H)
            b_out = torch.cat([head.bias for head in heads]).detach().cpu().float().numpy()
        self.latent_size, self.hidden_size, self.n_actions = L, H, A
        self.w_gates = np.ascontiguousarray(np.concatenate([w_ih[:, :L], w_hh], axis=1).T)  # (L + H, 4H)
        self.action_gates = np.ascontiguousarray(w_ih[:, L:].T + bias)                      # (A, 4H)
        self.w_out, self.b_out = np.ascontiguousarray(w_out.T), b_out                       # (H, L + 2), (L + 2,)
        self.action_space = gym.spaces.Discrete(A)
        self.reward_model = None if reward_model is None else RewardView(reward_model)

    def initial_state(self, z: np.ndarray) -> State:
        """The state of a game's first frame: ``z`` (L,) with a zero LSTM state."""
        zeros = np.zeros(self.hidden_size, np.float32)
        return State(np.asarray(z, np.float32), zeros, zeros.copy())

    def step(self, z: np.ndarray, h: np.ndarray, c: np.ndarray, action) -> tuple[np.ndarray, ...]:
        """One LSTM step and the heads, batched or not: ``z`` (..., L), ``h``, ``c`` (..., H),
        ``action`` int or (...,) -> next z (..., L), h, c (..., H), reward and done logit (...)."""
        H, L = self.hidden_size, self.latent_size
        gates = np.concatenate([z, h], axis=-1) @ self.w_gates + self.action_gates[action]
        i, f, o = _sigmoid(gates[..., :H]), _sigmoid(gates[..., H:2 * H]), _sigmoid(gates[..., 3 * H:])
        c = f * c + i * np.tanh(gates[..., 2 * H:3 * H])
        h = o * np.tanh(c)
        out = h @ self.w_out + self.b_out
        return out[..., :L], h, c, out[..., L], out[..., L + 1]

    def transition(self, state: State, action: int) -> tuple[State, float]:
        """With a ``reward_model``, the reward is its expected reward for ``(state, action)``
        (the reward the action earns ``delay`` steps later), not the memory's reward head."""
        z, h, c, reward, done_logit = self.step(state.z, state.h, state.c, action)
        if self.reward_model is not None:
            reward = self.reward_model(np.concatenate([state.z, state.h]), action)
        return State(z, h, c, bool(done_logit > 0)), float(reward)

    def is_terminal(self, state: State) -> bool:
        return state.terminal


# ----------------------------------------------------------------------------- reward model
class RewardModel(nn.Module):
    """A reward model for Boxing's rare hits (the ``learned-reward`` variant, beyond the thesis).

    An MLP classifier over the integer rewards ``-R..R`` (``R = reward_range``) of the reward
    that action ``a_t`` earns ``delay`` steps later, from the search state's features and the
    action: ``[z_t h_{t-1}]`` (B, F) and actions (B,) -> logits (B, 2R + 1). In Boxing a punch
    lands two agent steps after FIRE, so the memory's reward head, which sees ``(z_t, a_t)``
    and predicts ``r_t``, cannot tell what an action earns; crediting ``r_{t+delay}`` to
    ``a_t`` can. A classifier with class weights (:func:`train_reward_model`) does not
    collapse to predicting 0 the way an MSE head does on a ~3% hit rate. ``mean``/``std``
    (F,) standardise the features (set from the first training data).
    """

    def __init__(self, features: int, n_actions: int, hidden: int = 64, reward_range: int = 2):
        super().__init__()
        self.n_actions = n_actions
        self.register_buffer("mean", torch.zeros(features))
        self.register_buffer("std", torch.ones(features))
        self.register_buffer("values", torch.arange(-reward_range, reward_range + 1, dtype=torch.float32))
        self.net = nn.Sequential(nn.Linear(features + n_actions, hidden), nn.ReLU(), nn.Linear(hidden, hidden),
                                 nn.ReLU(), nn.Linear(hidden, 2 * reward_range + 1))

    def forward(self, features: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        x = (features - self.mean) / self.std
        return self.net(torch.cat([x, F.one_hot(actions, self.n_actions).to(x.dtype)], dim=-1))

    def expected(self, features: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """Expected reward (B,): softmax of the logits times the reward values."""
        return F.softmax(self(features, actions), dim=-1) @ self.values

    def classes(self, rewards) -> torch.Tensor:
        """Rewards (N,) -> class indices (N,) long (rounded, clipped to -R..R)."""
        R = (len(self.values) - 1) // 2
        return torch.as_tensor(np.clip(np.round(np.asarray(rewards)), -R, R) + R, dtype=torch.long)


class RewardView:
    """``view(features (F,), action) -> expected reward`` of a :class:`RewardModel` in numpy,
    for the search (~15 us a call); reads the weights through numpy views, so it follows
    training in place (as :class:`Evaluator`)."""

    def __init__(self, model: RewardModel):
        layers = [m for m in model.net if isinstance(m, nn.Linear)]
        self.weights = [(m.weight.detach().numpy(), m.bias.detach().numpy()) for m in layers]
        self.mean, self.std, self.values = (b.detach().numpy() for b in (model.mean, model.std, model.values))
        self.n_features = len(self.mean)

    def __call__(self, features: np.ndarray, action: int) -> float:
        (w0, b0), *rest = self.weights
        x = w0[:, :self.n_features] @ ((features - self.mean) / self.std) + w0[:, self.n_features + action] + b0
        for w, b in rest:
            x = w @ np.maximum(x, 0) + b
        p = np.exp(x - x.max())
        return float(p @ self.values / p.sum())


def reward_rows(features: np.ndarray, actions: np.ndarray, rewards: np.ndarray, delay: int) -> tuple:
    """One game's training rows for :class:`RewardModel`: features (T, F), actions, rewards
    (T,) -> ``(features[:T-d], actions[:T-d], rewards[d:])``, ``d = delay``."""
    n = max(len(rewards) - delay, 0)
    return features[:n], np.asarray(actions[:n], np.int64), np.asarray(rewards[delay:delay + n], np.float32)


def rollout_rows(mdp: LatentMDP, latents, delay: int, val_fraction: float = 0.1) -> dict:
    """The random rollouts (a :class:`~wmthesis.agents.world_models.LatentStore`) as reward
    rows, ``{"train": (X, a, r), "val": (X, a, r)}``: features ``[z_t h_{t-1}]`` with h from
    the memory reading each episode; the last ``val_fraction`` of episodes held out."""
    games = [reward_rows(*episode, delay) for episode in rollout_episodes(mdp, latents)]
    train, val = _split_episodes(games, val_fraction)
    return {"train": _stack_rows(train), "val": _stack_rows(val)}


def rollout_episodes(mdp: LatentMDP, latents) -> list[tuple]:
    """Per episode of the random rollouts: features ``[z_t h_{t-1}]`` (T, F) float32 (h from
    the memory reading the episode), actions (T,) and rewards (T,)."""
    mu, actions, rewards = (latents.data[k].numpy() for k in ("mu", "actions", "rewards"))
    episodes = []
    for start, end in zip(latents.starts, latents.ends):
        h = np.zeros(mdp.hidden_size, np.float32)
        c = np.zeros_like(h)
        features = np.zeros((end - start, mdp.latent_size + mdp.hidden_size), np.float32)
        for t in range(start, end):
            features[t - start] = np.concatenate([mu[t], h])
            _, h, c, _, _ = mdp.step(mu[t], h, c, int(actions[t]))
        episodes.append((features, actions[start:end], rewards[start:end]))
    return episodes


def _split_episodes(items: list, val_fraction: float) -> tuple[list, list]:
    """The first and the last ``val_fraction`` of ``items`` (all of them twice if only one)."""
    n_val = max(1, int(round(len(items) * val_fraction))) if len(items) > 1 else 0
    return items[:len(items) - n_val], items[len(items) - n_val:] or items


def _stack_rows(rows) -> tuple:
    return tuple(np.concatenate(parts) for parts in zip(*rows))


def train_reward_model(model: RewardModel, optimiser, rows: tuple, epochs: int, batch_size: int,
                       rng: np.random.Generator) -> float:
    """``epochs`` of class-weighted cross-entropy (weights ``sqrt(N / (K N_k))``: rare rewards
    count more) on ``rows = (features (N, F), actions (N,), rewards (N,))``; the first call sets
    the feature standardisation. Returns the last epoch's mean loss."""
    features, actions = torch.as_tensor(rows[0], dtype=torch.float32), torch.as_tensor(rows[1], dtype=torch.long)
    targets = model.classes(rows[2])
    if bool((model.std == 1).all() and (model.mean == 0).all()):
        model.mean.copy_(features.mean(0))
        model.std.copy_(features.std(0) + 1e-3)
    counts = torch.bincount(targets, minlength=len(model.values)).float()
    weight = torch.where(counts > 0, (counts.sum() / (len(counts) * counts.clamp(min=1))).sqrt(), torch.ones(1))
    for _ in range(epochs):
        total = 0.0
        for batch in torch.from_numpy(rng.permutation(len(targets))).split(batch_size):
            loss = F.cross_entropy(model(features[batch], actions[batch]), targets[batch], weight=weight)
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            total += float(loss.detach()) * len(batch)
    return total / max(len(targets), 1)


def reward_fit(model: RewardModel, rows: tuple) -> dict:
    """How well ``model`` predicts held-out ``rows``: the correlation of its expected reward
    with the reward, and the AUC of telling a positive (negative) reward from the rest by
    P(reward > 0) (P(reward < 0)); nan where a class is missing."""
    with torch.no_grad():
        logits = model(torch.as_tensor(rows[0], dtype=torch.float32), torch.as_tensor(rows[1], dtype=torch.long))
        p = F.softmax(logits, -1).numpy()
    values, truth = model.values.numpy(), np.asarray(rows[2])
    return {"corr": _corr(p @ values, truth), "auc_positive": _auc(truth > 0, p[:, values > 0].sum(1)),
            "auc_negative": _auc(truth < 0, p[:, values < 0].sum(1)), "rows": int(len(truth))}


def _auc(labels: np.ndarray, scores: np.ndarray) -> float:
    """Area under the ROC curve (ties count half); nan without both classes."""
    labels = np.asarray(labels, bool)
    n1, n0 = int(labels.sum()), int((~labels).sum())
    if n1 == 0 or n0 == 0:
        return float("nan")
    _, inverse, counts = np.unique(scores, return_inverse=True, return_counts=True)
    rank_of = np.cumsum(counts) - (counts - 1) / 2  # the mean rank of each distinct score
    ranks = rank_of[inverse]
    return float((ranks[labels].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


# ----------------------------------------------------------------------------- evaluator
class AlphaZeroHeads(nn.Module):
    """Linear policy and value heads on ``[z h]`` (thesis 4.3.3): features (B, L + H) ->
    policy logits (B, A) and values (B,). The policy head starts as PyTorch initialises it
    (slightly uneven priors, so equal priors do not send every first expansion to action 0);
    the value head starts at zero (no random values in the first searches)."""

    def __init__(self, latent_size: int, hidden_size: int, n_actions: int):
        super().__init__()
        features = latent_size + hidden_size
        self.policy = nn.Linear(features, n_actions)
        self.value = nn.Linear(features, 1)
        nn.init.zeros_(self.value.weight)
        nn.init.zeros_(self.value.bias)

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.policy(features), self.value(features).squeeze(-1)


class Evaluator:
    """``evaluator(state) -> (priors (A,), value)`` for the search: softmax of the policy head
    and the value head on ``[z h]``. Reads the heads' weights through numpy views, so it always
    sees the latest weights (training updates them in place) at ~10 us a call."""

    def __init__(self, heads: AlphaZeroHeads):
        self.heads = heads
        self.w_policy, self.b_policy = (p.detach().numpy() for p in (heads.policy.weight, heads.policy.bias))
        self.w_value, self.b_value = (p.detach().numpy() for p in (heads.value.weight, heads.value.bias))

    def __call__(self, state: State) -> tuple[np.ndarray, float]:
        x = np.concatenate([state.z, state.h])
        logits = self.w_policy @ x + self.b_policy
        priors = np.exp(logits - logits.max())
        return priors / priors.sum(), float(self.w_value[0] @ x + self.b_value[0])


# ----------------------------------------------------------------------------- games
@dataclasses.dataclass
class Game:
    """One played game, for training and diagnosis; T steps, F = L + H features, A actions.

    ``features`` (T, F): the roots' ``[z_t h_{t-1}]``; ``policies`` (T, A): root visit
    distributions (the policy targets); ``actions``, ``rewards`` (T,): what happened in the real
    game; ``predicted_rewards`` (T,): the memory's reward for each real step; ``root_values``,
    ``depths`` (T,) and ``q`` (T, A): search statistics (``q`` nan where unvisited);
    ``terminated``: the game ended (not cut by ``max_steps``); ``last_features`` (F,): the state
    after the last step (bootstraps a cut game); ``frames``: the observations, when kept.
    """

    index: int
    features: np.ndarray
    policies: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    predicted_rewards: np.ndarray
    root_values: np.ndarray
    depths: np.ndarray
    q: np.ndarray
    terminated: bool
    last_features: np.ndarray
    seconds: float
    frames: np.ndarray | None = None

    @property
    def score(self) -> float:
        return float(self.rewards.sum())

    def __len__(self) -> int:
        return len(self.rewards)


class AlphaZeroMind(Mind, Callback):
    """Vision + memory + MCTS as a HumbleRL mind; also the callback that steps the memory on
    the real action and keeps the search tree, so pass it both ways::

        mind.new_search(seed)
        loop(env, mind, callbacks=[mind], policy="proportional", policy_options={"warmup": 12})

    ``plan(frame)`` encodes the frame, searches from ``State(z, h, c)`` and returns the root
    visit counts (A,). Each finished game is left in :attr:`game` (a :class:`Game`).
    ``vision``: uint8 frames (N, ...) tensor -> latents (N, L) tensor.
    """

    def __init__(self, vision: Callable, mdp: LatentMDP, evaluator: Evaluator, config, keep_frames: bool = False):
        self.vision, self.mdp, self.evaluator, self.config = vision, mdp, evaluator, config
        self.keep_frames = keep_frames
        self.mcts = None
        self.game: Game | None = None
        self.index = 0
        self._root: State | None = None

    def new_search(self, seed: int, index: int = 0) -> None:
        """A fresh search tree with its own noise seed, for game number ``index``."""
        from wmthesis.planning.mcts import MCTS

        cfg = self.config
        self.mcts = MCTS(self.mdp, self.evaluator, c=cfg.c, n_simulations=cfg.simulations, timeout=cfg.timeout,
                         gamma=cfg.gamma, dirichlet_alpha=cfg.dirichlet_alpha, noise_ratio=cfg.noise_ratio,
                         normalize_q=cfg.normalize_q, reuse_tree=cfg.reuse_tree, seed=seed)
        self.index = index

    @torch.inference_mode()
    def encode(self, frame) -> np.ndarray:
        """One observation -> z (L,) float32."""
        return self.vision(torch.as_tensor(np.asarray(frame))[None])[0].float().cpu().numpy()

    def plan(self, state, train_mode: bool = True, debug_mode: bool = False):
        if self.mcts is None:
            raise RuntimeError("call new_search(seed) before playing")
        if self._root is not None:
            raise RuntimeError("AlphaZeroMind.plan was called twice without a step: pass the mind "
                               "as a callback too, loop(env, mind, callbacks=[mind])")
        self._root = State(self.encode(state), self.h, self.c)
        counts, info = self.mcts.plan(self._root, train_mode=train_mode, debug_mode=True)
        record = self._steps
        record["features"].append(np.concatenate([self._root.z, self._root.h]))
        record["policies"].append(counts / counts.sum() if counts.sum() > 0 else np.full(len(counts), 1 / len(counts)))
        record["root_values"].append(info["root_value"])
        record["depths"].append(info["max_depth"])
        record["q"].append(info["q"])
        if self.keep_frames:
            record["frames"].append(np.asarray(state))
        scores = counts + tie_breaker(info["q"]) if self.config.tie_break == "q" else counts
        return (scores, info) if debug_mode else scores

    def on_episode_start(self, episode: int, train_mode: bool) -> None:
        self.h = np.zeros(self.mdp.hidden_size, np.float32)
        self.c = np.zeros(self.mdp.hidden_size, np.float32)
        self._root, self._started = None, time.perf_counter()
        self._steps = {key: [] for key in ("features", "policies", "actions", "rewards", "predicted_rewards",
                                           "root_values", "depths", "q", "frames")}
        self._last, self._terminated = None, False
        if self.mcts is not None:
            self.mcts.reset()

    def on_step_taken(self, step, transition, info) -> None:
        next_state, predicted = self.mdp.transition(self._root, transition.action)
        self.h, self.c = next_state.h, next_state.c
        for key, value in (("actions", transition.action), ("rewards", transition.reward),
                           ("predicted_rewards", predicted)):
            self._steps[key].append(value)
        self.mcts.advance(transition.action)
        self._root = None
        self._terminated = transition.is_terminal
        if transition.is_terminal or info.get("truncated"):
            self._last = np.concatenate([self.encode(transition.next_state), self.h])

    def on_episode_end(self, episode: int, train_mode: bool) -> None:
        s = self._steps
        self.game = Game(
            index=self.index, features=np.stack(s["features"]).astype(np.float32),
            policies=np.stack(s["policies"]).astype(np.float32), actions=np.array(s["actions"], np.int64),
            rewards=np.array(s["rewards"], np.float32), predicted_rewards=np.array(s["predicted_rewards"], np.float32),
            root_values=np.array(s["root_values"], np.float32), depths=np.array(s["depths"], np.int16),
            q=np.stack(s["q"]).astype(np.float32), terminated=self._terminated,
            last_features=self._last if self._last is not None else s["features"][-1],
            seconds=time.perf_counter() - self._started,
            frames=np.stack(s["frames"]) if s["frames"] else None)

    def on_loop_end(self, is_aborted: bool) -> None:
        self._root = None


def tie_breaker(q: np.ndarray) -> np.ndarray:
    """Added to visit counts so that equal counts go to the higher root Q: the rank of each
    visited action's Q, scaled into [0, 0.5) (below one visit: counts keep their order); 0 for
    unvisited actions (``q`` nan). (A,) -> (A,)."""
    visited = np.isfinite(q)
    ranks = np.argsort(np.argsort(np.where(visited, q, -np.inf)))
    return np.where(visited, 0.5 * ranks / len(q), 0.0)


def game_seeds(seed: int) -> tuple[int, int]:
    """The seeds of the game seeded with ``seed``: the env's reset (and the policy's sampling),
    and the search's noise; non-negative 31-bit ints."""
    env_seed, search_seed = (int(s) >> 1 for s in derive_seeds(seed, n=2))
    return env_seed, search_seed


def play(env, mind: AlphaZeroMind, seed: int, index: int, *, train_mode: bool, max_steps: int | None) -> Game:
    """One game of ``mind`` in ``env`` with the seeds :func:`game_seeds` derives from ``seed``.
    Training games follow the visit counts in proportion for ``warmup`` steps, then greedily;
    test games are greedy."""
    env_seed, search_seed = game_seeds(seed)
    mind.new_search(search_seed, index)
    policy = Proportional(warmup=mind.config.warmup) if train_mode else "deterministic"
    loop(env, mind, policy=policy, callbacks=[mind], max_steps=max_steps, seed=env_seed, train_mode=train_mode)
    return mind.game


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


def noop_count(seed: int, noop_max: int = 30) -> int:
    """The number of no-ops :class:`NoopStart` plays after a reset with ``seed``."""
    return int(np.random.default_rng(seed).integers(max(noop_max, 1)))


def boxing_env(noop_max: int = 30) -> gym.Env:
    """Boxing with World Models frames (64, 64, 3) uint8 and no-op starts."""
    from wmthesis.envs import make_env

    return NoopStart(make_env("boxing", preprocessing="world_models"), noop_max)


# ----------------------------------------------------------------------------- training
def value_targets(rewards, gamma: float, n: int | None = None, values=None, bootstrap: float = 0.0) -> np.ndarray:
    """Value targets of one game's T steps, (T,) float32.

    ``n=None``: the discounted returns ``G_t = sum_{k=t}^{T-1} gamma^(k-t) r_k + gamma^(T-t) b``
    (the thesis's "returns", ``b = bootstrap``). With ``n``: the n-step targets
    ``sum_{k<n} gamma^k r_{t+k} + gamma^n v_{t+n}``, ``values`` (T,) the value head on each step
    and ``v_T = b``; steps closer than n to the end use ``G_t``. ``b`` is V(last state) for a
    game cut by ``max_steps``, 0 for one that ended.
    """
    rewards = np.asarray(rewards, np.float64)
    T = len(rewards)
    returns = np.empty(T + 1)
    returns[T] = bootstrap
    for t in range(T - 1, -1, -1):
        returns[t] = rewards[t] + gamma * returns[t + 1]
    if n is None:
        return returns[:T].astype(np.float32)
    if values is None or len(values) != T:
        raise ValueError("n-step targets need the value of every step, (T,)")
    v = np.append(np.asarray(values, np.float64), bootstrap)
    targets = returns[:T].copy()
    t = np.arange(max(T - n + 1, 0))  # steps with t + n <= T
    targets[t] = returns[t] - gamma ** n * returns[t + n] + gamma ** n * v[t + n]
    return targets.astype(np.float32)


def game_targets(game: Game, heads: AlphaZeroHeads, config) -> np.ndarray:
    """:func:`value_targets` of ``game`` for ``config.value_target`` (n-step targets use the
    current value head, so they are recomputed before every training round)."""
    check_choice("value target", config.value_target, VALUE_TARGETS)
    rewards = game.rewards
    if config.reward_model and config.reward_delay:  # the search credits r_{t+d} to step t
        rewards = np.append(rewards[config.reward_delay:], np.zeros(min(config.reward_delay, len(rewards)), np.float32))
    if config.value_target == "monte-carlo":
        return value_targets(rewards, config.gamma)
    with torch.no_grad():
        _, values = heads(torch.from_numpy(np.vstack([game.features, game.last_features[None]])))
    values = values.numpy()
    bootstrap = 0.0 if game.terminated else float(values[-1])
    return value_targets(rewards, config.gamma, config.n_step, values[:-1], bootstrap)


def alphazero_loss(heads: AlphaZeroHeads, features: torch.Tensor, policies: torch.Tensor, targets: torch.Tensor,
                   l2: float) -> dict:
    """AlphaZero's loss on a batch: ``(v - G)^2`` + ``-sum_a pi_a log p_a`` + ``l2 * |theta|^2``.

    ``features`` (B, F), ``policies`` (B, A) visit distributions, ``targets`` (B,) value
    targets; the first two terms are batch means, the L2 term sums over every weight and bias.
    """
    logits, values = heads(features)
    terms = {"value": F.mse_loss(values, targets),
             "policy": -(policies * F.log_softmax(logits, dim=-1)).sum(-1).mean(),
             "l2": l2 * sum(p.pow(2).sum() for p in heads.parameters())}
    terms["loss"] = terms["value"] + terms["policy"] + terms["l2"]
    return terms


def train_round(heads: AlphaZeroHeads, optimiser, games, config, rng: np.random.Generator) -> dict:
    """``config.epochs`` epochs over every step of ``games`` in shuffled batches of
    ``config.batch_size``; returns the losses on all of them before and after (floats)."""
    features = torch.from_numpy(np.concatenate([g.features for g in games]))
    policies = torch.from_numpy(np.concatenate([g.policies for g in games]))
    targets = torch.from_numpy(np.concatenate([game_targets(g, heads, config) for g in games]))
    with torch.no_grad():
        before = alphazero_loss(heads, features, policies, targets, config.l2)
    for _ in range(config.epochs):
        order = torch.from_numpy(rng.permutation(len(targets)))
        for batch in order.split(config.batch_size):
            terms = alphazero_loss(heads, features[batch], policies[batch], targets[batch], config.l2)
            optimiser.zero_grad(set_to_none=True)
            terms["loss"].backward()
            optimiser.step()
    with torch.no_grad():
        after = alphazero_loss(heads, features, policies, targets, config.l2)
    return {"samples": len(targets), "loss_before": float(before["loss"]),
            **{k: float(v) for k, v in after.items()}}


def make_optimiser(heads: AlphaZeroHeads, config) -> torch.optim.Optimizer:
    """SGD with Nesterov momentum (the L2 term is in :func:`alphazero_loss`)."""
    return torch.optim.SGD(heads.parameters(), lr=config.lr, momentum=config.momentum, nesterov=True)


@dataclasses.dataclass
class AlphaZeroRun:
    """A self-play run (what :func:`train_alphazero` returns and its checkpoint holds).

    ``curve``: per self-play game ``game``, ``return``, ``steps``, ``seconds``; ``tests``: per
    test point ``game``, ``mean``, ``std``, ``returns`` of greedy games; ``rounds``: per
    training round ``game`` and the losses of :func:`train_round`; ``replay``: the latest
    ``replay_games`` :class:`Game` records; ``task``: sizes and a fingerprint of the memory.
    With ``config["reward_model"]``: the :class:`RewardModel`, its optimiser, and
    ``reward_fits``, per training of it ``game`` (0: on the random rollouts only), ``loss`` and
    its :func:`reward_fit` on the held-out random episodes. With ``config["expert_games"]``:
    ``expert``, the expert games' ``scores`` and ``steps``, and the policy head's ``agreement``
    with the expert's actions before and after pretraining (with the pretraining's losses).
    """

    config: dict
    task: dict
    heads: AlphaZeroHeads
    optimiser: torch.optim.Optimizer
    games: int = 0
    replay: deque = dataclasses.field(default_factory=deque)
    curve: list = dataclasses.field(default_factory=list)
    tests: list = dataclasses.field(default_factory=list)
    rounds: list = dataclasses.field(default_factory=list)
    reward_model: RewardModel | None = None
    reward_optimiser: torch.optim.Optimizer | None = None
    reward_fits: list = dataclasses.field(default_factory=list)
    expert: dict = dataclasses.field(default_factory=dict)

    def summary(self) -> dict:
        """Everything but the replay and the modules, for ``metrics.json``."""
        return {"config": self.config, "task": self.task, "games": self.games, "curve": self.curve,
                "tests": self.tests, "rounds": self.rounds, "reward_fits": self.reward_fits, "expert": self.expert}

    def mdp(self, memory) -> LatentMDP:
        """The model this run searches: the memory, with the run's reward model if it has one."""
        return LatentMDP(memory, self.reward_model)


def train_alphazero(make_env: Callable, vision: Callable, memory, config, *, out_dir: str | os.PathLike | None = None,
                    seed: int = 0, progress: bool = True, rollouts=None,
                    expert: Callable[[int], Mind] | None = None) -> AlphaZeroRun:
    """Self-play training of the heads for ``config.games`` games (the module docstring).

    ``make_env()``: the real game (observations the ``vision`` encodes); ``memory``: a trained
    deterministic memory, frozen. Game ``g`` is seeded from ``(seed, 0, g)``, test ``k`` of a
    test point from ``(seed, 1, k)`` (the same test games each time), training round ``r``
    shuffles with ``(seed, 2, r)``. With ``out_dir``, a checkpoint is written after every
    training round and at the end, and an existing one is resumed (only ``games`` may differ
    from its config; anything else raises :class:`~wmthesis.training.ConfigMismatch`).
    ``config.reward_model``: the search's rewards come from a :class:`RewardModel`, pretrained
    on ``rollouts`` (the random rollouts' :class:`~wmthesis.agents.world_models.LatentStore`)
    and trained again on them and the replay after every training round of the heads.
    ``config.expert_games``: before self-play, ``expert(agent_seed)`` (a fresh
    :class:`~wmthesis.core.Mind` per game, e.g. the World Models controller) plays that many
    greedy games of ``config.eval_max_steps`` steps, seeded from ``(seed, 6, k)``; they join
    the replay and the heads train on them for ``config.expert_epochs`` epochs
    (:mod:`wmthesis.agents.imitation`).
    """
    from wmthesis.agents.controller_training import _fingerprint

    check_choice("value target", config.value_target, VALUE_TARGETS)
    if config.reward_model and rollouts is None:
        raise ValueError("reward_model=True needs the random rollouts (rollouts=LatentStore) to pretrain it")
    if config.expert_games and expert is None:
        raise ValueError(f"expert_games={config.expert_games} needs an expert (expert=lambda seed: Mind) to imitate")
    mdp = LatentMDP(memory)
    task = {"latent_size": mdp.latent_size, "hidden_size": mdp.hidden_size, "n_actions": mdp.n_actions,
            "memory": _fingerprint(memory)}
    checkpoint = None if out_dir is None else Path(out_dir) / CHECKPOINT_NAME
    run = _resume(checkpoint, config, task) if checkpoint is not None and checkpoint.exists() else None
    if run is None:
        with torch.random.fork_rng():  # the same initial heads for the same seed, whatever ran before
            torch.manual_seed(int(derive_seeds(seed, 5, 0)[0]))
            heads = AlphaZeroHeads(mdp.latent_size, mdp.hidden_size, mdp.n_actions)
        run = AlphaZeroRun(dataclasses.asdict(config), task, heads, make_optimiser(heads, config))
    run.config = dataclasses.asdict(config)
    run.replay = deque(run.replay, maxlen=config.replay_games)
    rows = rollout_rows(mdp, rollouts, config.reward_delay) if config.reward_model else None
    if config.reward_model and run.reward_model is None:
        with torch.random.fork_rng():
            torch.manual_seed(int(derive_seeds(seed, 4, 0)[0]))
            run.reward_model = RewardModel(mdp.latent_size + mdp.hidden_size, mdp.n_actions, config.reward_hidden,
                                           config.reward_range)
        run.reward_optimiser = make_reward_optimiser(run.reward_model, config)
        _train_reward(run, rows, config, config.reward_pretrain_epochs, seed)
    mdp = run.mdp(memory)
    mind = AlphaZeroMind(vision, mdp, Evaluator(run.heads), config)
    env = make_env()
    try:
        if config.expert_games and not run.expert:
            _imitate(run, env, expert, vision, mdp, config, seed, progress)
            if checkpoint is not None:
                save_run(run, checkpoint)
        with tqdm(total=config.games, initial=run.games, desc="self-play", disable=not progress) as bar:
            while run.games < config.games:
                g = run.games
                game = play(env, mind, int(derive_seeds(seed, 0, g)[0]), g, train_mode=True,
                            max_steps=config.max_steps)
                run.replay.append(game)
                run.curve.append({"game": g + 1, "return": game.score, "steps": len(game), "seconds": game.seconds})
                run.games = g + 1
                trained = run.games % config.train_every == 0
                if trained:
                    rng = np.random.default_rng(derive_seeds(seed, 2, run.games // config.train_every))
                    run.rounds.append({"game": run.games, **train_round(run.heads, run.optimiser, run.replay,
                                                                         config, rng)})
                    if config.reward_model:
                        _train_reward(run, rows, config, config.reward_epochs, seed)
                if config.test_every and run.games % config.test_every == 0:
                    returns = [play(env, mind, int(derive_seeds(seed, 1, k)[0]), k, train_mode=False,
                                    max_steps=config.max_steps).score for k in range(config.test_episodes)]
                    run.tests.append({"game": run.games, "mean": float(np.mean(returns)),
                                      "std": float(np.std(returns)), "returns": returns})
                if checkpoint is not None and (trained or run.games == config.games):
                    save_run(run, checkpoint)
                bar.update(1)
                bar.set_postfix(score=f"{game.score:.0f}")
    finally:
        env.close()
    return run


def _imitate(run: AlphaZeroRun, env, expert: Callable, vision: Callable, mdp: LatentMDP, config, seed: int,
             progress: bool) -> None:
    """Play ``config.expert_games`` expert games into the replay and pretrain the heads on them;
    ``run.expert`` keeps their scores and the heads' agreement with the expert's actions."""
    from wmthesis.agents.imitation import agreement, expert_games

    seeds = [int(derive_seeds(seed, 6, k)[0]) for k in range(config.expert_games)]
    games = expert_games(env, expert, vision, mdp, seeds, max_steps=config.eval_max_steps, progress=progress)
    run.replay.extend(games)
    before = agreement(run.heads, games)
    rng = np.random.default_rng(derive_seeds(seed, 2, 0))
    losses = train_round(run.heads, run.optimiser, games, dataclasses.replace(config, epochs=config.expert_epochs), rng)
    run.expert = {"games": len(games), "scores": [g.score for g in games], "steps": int(sum(map(len, games))),
                  "agreement_before": before, "agreement": agreement(run.heads, games), **losses}


def make_reward_optimiser(model: RewardModel, config) -> torch.optim.Optimizer:
    """Adam for the reward model (weight decay 1e-4 against fitting 20 bouts' hits by heart)."""
    return torch.optim.Adam(model.parameters(), lr=config.reward_lr, weight_decay=1e-4)


def _train_reward(run: AlphaZeroRun, rows: dict, config, epochs: int, seed: int) -> None:
    """Train the run's reward model on the random rollouts' training episodes and every step of
    the replay (self-play data: the states and actions the search actually visits), then
    record its fit on the held-out random episodes in ``run.reward_fits``."""
    games = [reward_rows(g.features, g.actions, g.rewards, config.reward_delay) for g in run.replay]
    data = _stack_rows([rows["train"], *games])
    rng = np.random.default_rng(derive_seeds(seed, 4, len(run.reward_fits) + 1))
    loss = train_reward_model(run.reward_model, run.reward_optimiser, data, epochs, config.batch_size, rng)
    run.reward_fits.append({"game": run.games, "loss": loss, **reward_fit(run.reward_model, rows["val"])})


def _resume(path: Path, config, task: dict) -> AlphaZeroRun:
    run = load_run(path)
    check_resumable(path, (run.config, run.task), (dataclasses.asdict(config), task), RESUMABLE_FIELDS)
    return run


def save_run(run: AlphaZeroRun, path: str | os.PathLike) -> None:
    """Write the whole run (heads, optimiser, replay, counters, curves) atomically."""
    saved = {"format": FORMAT, "version": FORMAT_VERSION, **run.summary(), "replay": list(run.replay),
             "heads": run.heads.state_dict(), "optimiser": run.optimiser.state_dict()}
    if run.reward_model is not None:
        saved["reward_model"] = run.reward_model.state_dict()
        saved["reward_optimiser"] = run.reward_optimiser.state_dict()
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        pickle.dump(saved, f, protocol=pickle.HIGHEST_PROTOCOL)


def load_run(path: str | os.PathLike) -> AlphaZeroRun:
    """An :class:`AlphaZeroRun` from its checkpoint (or the folder holding it)."""
    from wmthesis.config import AlphaZeroConfig

    path = Path(path)
    path = path / CHECKPOINT_NAME if path.is_dir() else path
    with open(path, "rb") as f:
        saved = pickle.load(f)
    if saved.get("format") != FORMAT or saved.get("version") != FORMAT_VERSION:
        raise ValueError(f"{path} is not a {FORMAT} checkpoint of version {FORMAT_VERSION}")
    # fields added to AlphaZeroConfig later take their defaults, which keep the older behaviour
    saved["config"] = {**dataclasses.asdict(AlphaZeroConfig()), **saved["config"]}
    t = saved["task"]
    heads = AlphaZeroHeads(t["latent_size"], t["hidden_size"], t["n_actions"])
    heads.load_state_dict(saved["heads"])
    config = AlphaZeroConfig(**saved["config"])
    optimiser = make_optimiser(heads, config)
    optimiser.load_state_dict(saved["optimiser"])
    run = AlphaZeroRun(saved["config"], t, heads, optimiser, saved["games"], deque(saved["replay"]),
                       saved["curve"], saved["tests"], saved["rounds"], reward_fits=saved.get("reward_fits", []),
                       expert=saved.get("expert", {}))
    if "reward_model" in saved:
        run.reward_model = RewardModel(t["latent_size"] + t["hidden_size"], t["n_actions"], config.reward_hidden,
                                       config.reward_range)
        run.reward_model.load_state_dict(saved["reward_model"])
        run.reward_optimiser = make_reward_optimiser(run.reward_model, config)
        run.reward_optimiser.load_state_dict(saved["reward_optimiser"])
    return run


# ----------------------------------------------------------------------------- diagnosis
def reward_error_by_depth(mdp: LatentMDP, games, depth: int) -> dict:
    """How wrong the memory's rewards are k = 1..``depth`` steps into a search.

    For every step t of each game, the memory is warmed on the real latents and actions up to
    t, then rolled out from the real ``z_t`` along the *real* actions ``a_t..a_{t+k-1}`` on its
    own predicted latents; its k-th reward is compared with the true ``r_{t+k-1}``. Returns
    per depth (D,): ``reward_mse``, ``zero_mse`` (the error of always predicting 0: the rewards'
    second moment), ``hit_mse`` (the error on steps whose true reward is not 0) and
    ``latent_mse`` (squared error summed over L, against the encoded real latents), and the
    number of ``starts``.
    """
    L = mdp.latent_size
    sums = {key: np.zeros(depth) for key in ("reward", "zero", "hit", "latent")}
    counts = {key: np.zeros(depth) for key in ("reward", "hit", "latent")}
    for game in games:
        T = len(game)
        if T < depth:
            continue
        z_real = game.features[:, :L]
        h = np.zeros((T, mdp.hidden_size), np.float32)
        c = np.zeros_like(h)
        for t in range(T - 1):  # the warm state before each step t
            _, h[t + 1], c[t + 1], _, _ = mdp.step(z_real[t], h[t], c[t], int(game.actions[t]))
        t0 = np.arange(T - depth + 1)  # starts with depth real steps ahead
        z, hb, cb = z_real[t0], h[t0], c[t0]
        for k in range(depth):
            z, hb, cb, reward, _ = mdp.step(z, hb, cb, game.actions[t0 + k])
            truth = game.rewards[t0 + k]
            hit = truth != 0
            sums["reward"][k] += ((reward - truth) ** 2).sum()
            sums["zero"][k] += (truth ** 2).sum()
            sums["hit"][k] += ((reward - truth)[hit] ** 2).sum()
            valid = t0 + k + 1 < T  # the real latent that z predicts exists
            sums["latent"][k] += ((z[valid] - z_real[t0[valid] + k + 1]) ** 2).sum()
            counts["reward"][k] += len(t0)
            counts["hit"][k] += hit.sum()
            counts["latent"][k] += valid.sum()
    if not counts["reward"].any():
        raise ValueError(f"no game has {depth} steps")
    mean = lambda key, count: (sums[key] / np.maximum(counts[count], 1)).tolist()  # noqa: E731
    return {"depth": list(range(1, depth + 1)), "starts": int(counts["reward"][0]),
            "reward_mse": mean("reward", "reward"), "zero_mse": mean("zero", "reward"),
            "hit_mse": mean("hit", "hit"), "latent_mse": mean("latent", "latent")}


def value_predictability(mdp: LatentMDP, latents, gamma: float, n_step: int, val_fraction: float = 0.1,
                         ridge: float = 1.0) -> dict:
    """Can a linear value on ``[z h]`` predict returns at all? Fits one by ridge regression to
    the random rollouts (``latents``: a :class:`~wmthesis.agents.world_models.LatentStore`;
    h from the memory reading each episode) and reports the correlation of its predictions with
    the targets on the training episodes and on the last ``val_fraction`` of episodes, for the
    ``monte-carlo`` returns and the ``n-step`` discounted reward sums (the bootstrap term
    needs a value, so here it is 0). ``reward``: the same for the memory's own reward head (the
    reward of each step against its prediction after reading the action)."""
    mu, actions, rewards = (latents.data[k].numpy() for k in ("mu", "actions", "rewards"))
    features, predicted = np.zeros((len(mu), mdp.latent_size + mdp.hidden_size)), np.zeros(len(mu))
    targets = {"monte-carlo": [], "n-step": []}
    for start, end in zip(latents.starts, latents.ends):
        h = np.zeros(mdp.hidden_size, np.float32)
        c = np.zeros_like(h)
        for t in range(start, end):
            features[t, :mdp.latent_size], features[t, mdp.latent_size:] = mu[t], h
            _, h, c, predicted[t], _ = mdp.step(mu[t], h, c, int(actions[t]))
        targets["monte-carlo"].append(value_targets(rewards[start:end], gamma))
        targets["n-step"].append(value_targets(rewards[start:end], gamma, n_step, np.zeros(end - start)))
    n_val = max(1, int(round(len(latents) * val_fraction))) if len(latents) > 1 else 0
    split = int(latents.starts[len(latents) - n_val]) if n_val else len(mu)
    train, val = slice(0, split), slice(split if n_val else 0, len(mu))
    x = np.hstack([features, np.ones((len(mu), 1))])
    result = {}
    for name, parts in targets.items():
        y = np.concatenate(parts)
        w = np.linalg.solve(x[train].T @ x[train] + ridge * np.eye(x.shape[1]), x[train].T @ y[train])
        result[name] = {"train_corr": _corr(x[train] @ w, y[train]), "val_corr": _corr(x[val] @ w, y[val])}
    result["reward"] = {"train_corr": _corr(predicted[train], rewards[train]),
                        "val_corr": _corr(predicted[val], rewards[val])}
    return result


def action_predictability(mdp: LatentMDP, latents, horizons=(3, 8), val_fraction: float = 0.15, epochs: int = 6,
                          hidden: int = 64, seed: int = 0) -> dict:
    """Does ``[z h]`` say *which action* is better? (What any planner on this model needs.)

    On the random rollouts (a :class:`~wmthesis.agents.world_models.LatentStore`; h from the
    memory), fits an MLP ``Q(z, h, a)`` by MSE to the sum of the next k rewards
    ``r_t + ... + r_{t+k-1}`` (for each k in ``horizons``; the actions after a_t are random, so
    this is the random policy's Q) and reports on the last ``val_fraction`` of the episodes:
    ``q_corr`` (Q of the action taken against the sum), ``v_corr`` (its mean over the actions,
    V, against the sum) and ``advantage_corr``: ``Q(s, a_t) - V(s)`` against ``sum - V(s)``,
    the part of the outcome that the action explains. Near 0, no search in this model can choose
    better than at random. Also ``advantage_std``, the spread of Q over the actions.
    """
    episodes = rollout_episodes(mdp, latents)
    result = {}
    for k in horizons:
        windows = [(x[:len(x) - k + 1], a[:len(x) - k + 1], np.convolve(r, np.ones(k))[k - 1:len(x)].astype(np.float32))
                   for x, a, r in episodes if len(x) >= k]  # sums r_t + ... + r_{t+k-1}
        train, val = (_stack_rows(part) for part in _split_episodes(windows, val_fraction))
        result[str(k)] = _fit_q(train, val, mdp.n_actions, epochs, hidden, seed)
    return result


def _fit_q(train: tuple, val: tuple, n_actions: int, epochs: int, hidden: int, seed: int) -> dict:
    torch.manual_seed(seed)
    x, a, y = (torch.as_tensor(v) for v in train)
    mean, std = x.mean(0), x.std(0) + 1e-3
    net = nn.Sequential(nn.Linear(x.shape[1] + n_actions, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                        nn.Linear(hidden, 1))

    def q(features, actions):
        inputs = torch.cat([(features - mean) / std, F.one_hot(actions, n_actions).float()], -1)
        return net(inputs).squeeze(-1)

    optimiser = torch.optim.Adam(net.parameters(), lr=1e-3, weight_decay=1e-4)
    rng = np.random.default_rng(seed)
    for _ in range(epochs):
        for batch in torch.from_numpy(rng.permutation(len(y))).split(256):
            loss = F.mse_loss(q(x[batch], a[batch]), y[batch])
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
    xv, av, yv = (torch.as_tensor(v) for v in val)  # Q of every action on the held-out rows
    with torch.no_grad():
        every = torch.stack([q(xv, torch.full_like(av, j)) for j in range(n_actions)], 1).numpy()
    taken, v, yv = every[np.arange(len(yv)), av.numpy()], every.mean(1), yv.numpy()
    return {"q_corr": _corr(taken, yv), "v_corr": _corr(v, yv), "advantage_corr": _corr(taken - v, yv - v),
            "advantage_std": float((every - v[:, None]).std()), "val_rows": int(len(yv))}


def search_statistics(games, gamma: float, c: float, simulations: int) -> dict:
    """Value scale and Q spread of the searches in ``games``.

    ``root_value``/``returns``: the searches' root values and the discounted returns that
    followed them (each (N,)); ``q_spread`` (N,): max - min of the root Q over visited actions;
    ``prior_bonus``: the PUCT bonus ``c * P * sqrt(N(s)) / (1 + N(s, a))`` of an action with a
    uniform prior visited once when the root has had all ``simulations`` (the scale that Q
    differences must beat to steer the search); ``visit_entropy`` (N,) of the root visit
    distributions; ``tied``: the fraction of steps whose highest visit count was shared by
    several actions; ``value_return_corr``: the correlation of root values and returns.
    """
    root_values = np.concatenate([g.root_values for g in games])
    returns = np.concatenate([value_targets(g.rewards, gamma) for g in games])
    q = np.concatenate([g.q for g in games])
    visited = np.isfinite(q)
    spread = np.where(visited.sum(-1) > 1, np.nanmax(np.where(visited, q, -np.inf), -1)
                      - np.nanmin(np.where(visited, q, np.inf), -1), 0.0)
    policies = np.concatenate([g.policies for g in games])
    entropy = -(policies * np.log(np.where(policies > 0, policies, 1))).sum(-1)
    A = q.shape[1]
    tied = float(np.mean((policies == policies.max(-1, keepdims=True)).sum(-1) > 1))
    return {"root_value": root_values, "returns": returns, "q_spread": spread, "visit_entropy": entropy, "tied": tied,
            "prior_bonus": c / A * math.sqrt(simulations) / 2, "value_return_corr": _corr(root_values, returns)}


def _corr(x, y) -> float:
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    return float(np.corrcoef(x, y)[0, 1]) if len(x) > 1 and x.std() > 0 and y.std() > 0 else float("nan")


# ----------------------------------------------------------------------------- figures
def plot_self_play(runs: dict, references: dict | None = None, ax=None):
    """Self-play return per game (thin; thick: moving mean over 10 games) and the greedy test
    scores (mean +- std) of each run in ``runs`` (name -> :meth:`AlphaZeroRun.summary`)."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(6.5, 3.5))
    for index, (name, run) in enumerate(runs.items()):
        colour = f"C{index}"
        games = np.array([e["game"] for e in run["curve"]])
        returns = np.array([e["return"] for e in run["curve"]])
        ax.plot(games, returns, color=colour, lw=0.6, alpha=0.4)
        window = min(10, len(returns))
        if window > 1:
            smooth = np.convolve(returns, np.ones(window) / window, mode="valid")
            ax.plot(games[window - 1:], smooth, color=colour, lw=1.8, label=f"{name}: self-play (mean of {window})")
        if run["tests"]:
            ax.errorbar([t["game"] for t in run["tests"]], [t["mean"] for t in run["tests"]],
                        [t["std"] for t in run["tests"]], fmt="o", ms=4, capsize=2, color=colour,
                        label=f"{name}: greedy test")
    for index, (name, value) in enumerate((references or {}).items()):
        ax.axhline(value, color="0.4", ls=["--", ":", "-."][index % 3], lw=1, label=name)
    ax.set_xlabel("self-play game")
    ax.set_ylabel("game score")
    ax.set_title("AlphaZero self-play in the memory's latent space")
    ax.legend(fontsize=7)
    ax.figure.tight_layout()
    return ax.figure


def plot_search(games_by_variant: dict, gamma: float, c: float, simulations: int):
    """Search statistics and diagnosis per variant (``games_by_variant``: name -> games): value
    scale, root value along the first game against the return that followed, Q spread against
    the prior bonus, visit entropy, the actions taken, the search depth."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(13, 6.4))
    axes = axes.ravel()
    width = 0.8 / max(len(games_by_variant), 1)
    for index, (name, games) in enumerate(games_by_variant.items()):
        colour = f"C{index}"
        stats = search_statistics(games, gamma, c, simulations)
        axes[0].scatter(stats["returns"], stats["root_value"], s=3, alpha=0.3, color=colour,
                        label=f"{name} (r={stats['value_return_corr']:.2f})")
        axes[1].plot(games[0].root_values, color=colour, lw=1, label=f"{name}: root value")
        axes[1].plot(value_targets(games[0].rewards, gamma), color=colour, lw=1, ls="--",
                     label=f"{name}: return that followed")
        spread = np.maximum(stats["q_spread"], 1e-5)
        axes[2].hist(spread, bins=np.geomspace(1e-5, max(spread.max(), 1e-3) * 1.5, 30), alpha=0.5, color=colour,
                     label=name)
        axes[3].hist(stats["visit_entropy"], bins=30, alpha=0.5, color=colour,
                     label=f"{name} (top count tied: {stats['tied']:.0%})")
        actions = np.bincount(np.concatenate([g.actions for g in games]), minlength=games[0].q.shape[1])
        axes[4].bar(np.arange(len(actions)) + index * width, actions / actions.sum(), width, color=colour, label=name)
        depths = np.concatenate([g.depths for g in games])
        axes[5].hist(depths, bins=np.arange(depths.max() + 2) - 0.5, alpha=0.5, color=colour, label=name)
    lims = axes[0].get_xlim()
    axes[0].plot(lims, lims, color="0.5", lw=0.8)
    axes[0].set(xlabel="discounted return that followed", ylabel="root value", title="value scale")
    axes[1].set(xlabel="step of the first evaluation game", ylabel="value", title="root value vs return")
    axes[2].axvline(stats["prior_bonus"], color="k", ls="--", lw=1, label="prior bonus (uniform P)")
    axes[2].set(xscale="log", xlabel="max - min root Q (visited actions)", ylabel="steps", title="spread of root Q")
    axes[3].axvline(math.log(games[0].q.shape[1]), color="k", ls="--", lw=1, label="uniform")
    axes[3].set(xlabel="entropy of root visits (nats)", ylabel="steps", title="visit distributions")
    axes[4].set(xlabel="action (0 = no-op)", ylabel="fraction of steps", title="actions taken")
    axes[5].set(xlabel="longest path in the search (edges)", ylabel="steps", title="search depth")
    for ax in axes:
        ax.legend(fontsize=6)
    fig.tight_layout()
    return fig


def plot_reward_error(errors: dict, search_depths=None, ax=None):
    """The memory's reward error against the depth into the search (:func:`reward_error_by_depth`),
    beside the error of always predicting 0; ``search_depths``: the searches' max depths."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(5, 3.2))
    d = errors["depth"]
    ax.plot(d, errors["reward_mse"], "o-", ms=3, label="memory's reward, all steps")
    ax.plot(d, errors["zero_mse"], "--", color="0.4", label="predicting 0, all steps")
    ax.plot(d, errors["hit_mse"], "s-", ms=3, label="memory's reward, steps with a hit")
    if search_depths is not None and len(search_depths):
        ax.axvline(float(np.median(search_depths)), color="k", ls=":", lw=1, label="median search depth")
    ax.set(xlabel="steps into the search (k)", ylabel="reward MSE", yscale="log",
           title="reward-model error along the search depth")
    ax.legend(fontsize=7)
    ax.figure.tight_layout()
    return ax.figure


def plot_visits(game: Game, steps: int = 60, ax=None):
    """The root visit distribution (actions x steps) over the first ``steps`` steps of a game,
    with the action taken marked."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(7, 2.8))
    policies = game.policies[:steps].T
    image = ax.imshow(policies, aspect="auto", cmap="viridis", interpolation="nearest")
    ax.scatter(np.arange(policies.shape[1]), game.actions[:steps], s=4, color="r", label="action taken")
    ax.set(xlabel="step", ylabel="action", title="root visit distributions")
    ax.figure.colorbar(image, ax=ax, fraction=0.03)
    ax.legend(fontsize=7, loc="upper right")
    ax.figure.tight_layout()
    return ax.figure
