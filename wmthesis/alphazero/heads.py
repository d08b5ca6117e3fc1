"""AlphaZero's heads and their training (thesis 4.3.3): linear policy and value heads on
``[z h]``, the evaluator the search calls, value targets and the loss."""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from wmthesis.alphazero.latent_mdp import State
from wmthesis.alphazero.replay import Game
from wmthesis.training import gradient_step
from wmthesis.utils import check_choice

VALUE_TARGETS = ("monte-carlo", "n-step")


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
    update = 0
    for _ in range(config.epochs):
        order = torch.from_numpy(rng.permutation(len(targets)))
        for batch in order.split(config.batch_size):
            terms = alphazero_loss(heads, features[batch], policies[batch], targets[batch], config.l2)
            update += 1
            gradient_step("AlphaZero heads", update, terms, optimiser, heads.parameters(),
                          kept="the last checkpoint of the self-play run is kept")
    with torch.no_grad():
        after = alphazero_loss(heads, features, policies, targets, config.l2)
    return {"samples": len(targets), "loss_before": float(before["loss"]),
            **{k: float(v) for k, v in after.items()}}


def make_optimiser(heads: AlphaZeroHeads, config) -> torch.optim.Optimizer:
    """SGD with Nesterov momentum (the L2 term is in :func:`alphazero_loss`)."""
    return torch.optim.SGD(heads.parameters(), lr=config.lr, momentum=config.momentum, nesterov=True)
