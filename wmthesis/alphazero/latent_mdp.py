"""The latent MDP of World Models + AlphaZero (thesis 4.3.1): a deterministic memory as the
:class:`~wmthesis.core.MDP` the search expands, and a learned reward model for it."""
from __future__ import annotations

from typing import NamedTuple

import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from wmthesis.metrics import auc, correlation
from wmthesis.training import gradient_step


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
    """The random rollouts (a :class:`~wmthesis.world_models.train.LatentStore`) as reward
    rows, ``{"train": (X, a, r), "val": (X, a, r)}``: features ``[z_t h_{t-1}]`` with h from
    the memory reading each episode; the last ``val_fraction`` of episodes held out."""
    games = [reward_rows(*episode, delay) for episode in rollout_episodes(mdp, latents)]
    train, val = split_episodes(games, val_fraction)
    return {"train": stack_rows(train), "val": stack_rows(val)}


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


def split_episodes(items: list, val_fraction: float) -> tuple[list, list]:
    """The first and the last ``val_fraction`` of ``items`` (all of them twice if only one)."""
    n_val = max(1, int(round(len(items) * val_fraction))) if len(items) > 1 else 0
    return items[:len(items) - n_val], items[len(items) - n_val:] or items


def stack_rows(rows) -> tuple:
    return tuple(np.concatenate(parts) for parts in zip(*rows))


def train_reward_model(model: RewardModel, optimiser, rows: tuple, epochs: int, batch_size: int,
                       rng: np.random.Generator, weighted: bool = True) -> float:
    """``epochs`` of cross-entropy on ``rows = (features (N, F), actions (N,), rewards (N,))``,
    class-weighted where ``weighted`` (weights ``sqrt(N / (K N_k))``: rare rewards count more,
    and the expected reward leans toward them; unweighted, it is calibrated); the first call
    sets the feature standardisation. Returns the last epoch's mean loss."""
    features, actions = torch.as_tensor(rows[0], dtype=torch.float32), torch.as_tensor(rows[1], dtype=torch.long)
    targets = model.classes(rows[2])
    if bool((model.std == 1).all() and (model.mean == 0).all()):
        model.mean.copy_(features.mean(0))
        model.std.copy_(features.std(0) + 1e-3)
    counts = torch.bincount(targets, minlength=len(model.values)).float()
    weight = torch.where(counts > 0, (counts.sum() / (len(counts) * counts.clamp(min=1))).sqrt(), torch.ones(1))
    weight = weight if weighted else None
    update = 0
    for _ in range(epochs):
        total = 0.0
        for batch in torch.from_numpy(rng.permutation(len(targets))).split(batch_size):
            loss = F.cross_entropy(model(features[batch], actions[batch]), targets[batch], weight=weight)
            update += 1
            gradient_step("reward model", update, {"loss": loss}, optimiser, model.parameters(),
                          kept="the last checkpoint of the self-play run is kept")
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
    return {"corr": correlation(p @ values, truth), "auc_positive": auc(truth > 0, p[:, values > 0].sum(1)),
            "auc_negative": auc(truth < 0, p[:, values < 0].sum(1)), "rows": int(len(truth))}
