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
head barely predicts held-out rewards (:mod:`~wmthesis.agents.alphazero_diagnosis`). ``learned-reward`` is
improved plus a :class:`RewardModel` for the search's rewards: a class-weighted MLP classifier
on ``[z h a]`` that credits each action with the reward two steps later (when Boxing's punches
land), pretrained on the random rollouts and trained again on them and the self-play games
after every round. It detects the steps before hits far better than chance, but not whose hit
they will be, nor which action makes the difference
(:func:`~wmthesis.agents.alphazero_diagnosis.action_predictability`).
``imitation`` is improved with the heads pretrained, before self-play, on greedy games of an
expert (notebook 02's evolved controller), as AlphaGo's policy started from expert games
(:mod:`wmthesis.agents.imitation`): the search then starts from priors that already box.

Diagnosis (5.4.2 asks "why") and figures: :mod:`wmthesis.agents.alphazero_diagnosis`.
"""
from __future__ import annotations

import dataclasses
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
from wmthesis.utils import atomic_path, check_choice, derive_seeds, read_pickle

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


def _corr(x, y) -> float:
    """Pearson correlation of two (N,) arrays; nan when either is constant or N < 2."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    return float(np.corrcoef(x, y)[0, 1]) if len(x) > 1 and x.std() > 0 and y.std() > 0 else float("nan")


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
    with the expert's actions before and after pretraining (with the pretraining's losses), and
    ``pretrained``, the heads' weights then (:meth:`pretrained_heads`).
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
    pretrained: dict | None = None

    def pretrained_heads(self) -> AlphaZeroHeads | None:
        """The heads as they were after imitation, before self-play (None without it)."""
        if self.pretrained is None:
            return None
        heads = AlphaZeroHeads(self.task["latent_size"], self.task["hidden_size"], self.task["n_actions"])
        heads.load_state_dict(self.pretrained)
        return heads

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
    if config.expert_games < 0 or config.expert_epochs < 0:
        raise ValueError(f"need expert_games and expert_epochs >= 0, got {config.expert_games}, {config.expert_epochs}")
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
    run.pretrained = {k: v.clone() for k, v in run.heads.state_dict().items()}


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
    if run.pretrained is not None:
        saved["pretrained"] = run.pretrained
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
    saved = read_pickle(path)
    if not isinstance(saved, dict) or saved.get("format") != FORMAT or saved.get("version") != FORMAT_VERSION:
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
                       expert=saved.get("expert", {}), pretrained=saved.get("pretrained"))
    if "reward_model" in saved:
        run.reward_model = RewardModel(t["latent_size"] + t["hidden_size"], t["n_actions"], config.reward_hidden,
                                       config.reward_range)
        run.reward_model.load_state_dict(saved["reward_model"])
        run.reward_optimiser = make_reward_optimiser(run.reward_model, config)
        run.reward_optimiser.load_state_dict(saved["reward_optimiser"])
    return run
