"""Memory: the MDN-RNN of World Models (thesis 4.2.1, 4.2.5) and its variants.

An LSTM with 256 units reads ``[z_t, one_hot(a_t)]`` and its hidden state ``h_t`` predicts
the next latent ``z_{t+1}``:

- ``mdn`` (stochastic, thesis 4.2): a mixture of K = 5 diagonal Gaussians of dimension L,
  ``p(z_{t+1} | h_t) = sum_k pi_k(h_t) N(z_{t+1}; mu_k(h_t), sigma_k(h_t)^2 I)``, each parameter
  a linear function of ``h_t``. Sampling with temperature tau uses ``logits / tau`` and
  ``sigma * sqrt(tau)``.
- ``deterministic`` (thesis 4.3.1): a linear head predicts ``z_{t+1}`` directly (MSE).

Both have linear ``reward`` and ``done`` heads on ``h_t`` (reward of the step, whether it
ended the episode); ``auxiliary=True`` (thesis 5.3.3) adds a ``value`` head predicting the
Monte-Carlo return from ``h_t``.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from wmthesis.utils import check_choice

KINDS = ("mdn", "deterministic")


class Mixture(NamedTuple):
    """Mixture parameters over the next latent: ``log_pi`` (..., K), ``mu`` and ``log_sigma`` (..., K, L)."""

    log_pi: torch.Tensor
    mu: torch.Tensor
    log_sigma: torch.Tensor


class MemoryOutput(NamedTuple):
    """One pass over a sequence. ``hidden``: (B, T, H); ``next_latent``: a :class:`Mixture`
    (``mdn``) or a (B, T, L) tensor (``deterministic``); ``reward``, ``done_logit``: (B, T);
    ``value``: (B, T) or None; ``state``: the LSTM's ``(h, c)``, each (1, B, H)."""

    hidden: torch.Tensor
    next_latent: Mixture | torch.Tensor
    reward: torch.Tensor
    done_logit: torch.Tensor
    value: torch.Tensor | None
    state: tuple[torch.Tensor, torch.Tensor]


class Memory(nn.Module):
    """LSTM over ``[z_t, one_hot(a_t)]`` with heads on its hidden state (module docstring)."""

    def __init__(self, latent_size: int, n_actions: int, kind: str = "mdn", hidden_size: int = 256,
                 n_gaussians: int = 5, auxiliary: bool = False):
        super().__init__()
        check_choice("memory kind", kind, KINDS)
        self.latent_size, self.n_actions, self.kind = latent_size, n_actions, kind
        self.hidden_size, self.n_gaussians = hidden_size, n_gaussians
        self.lstm = nn.LSTM(latent_size + n_actions, hidden_size, batch_first=True)
        if kind == "mdn":
            self.mixture = nn.Linear(hidden_size, n_gaussians * (1 + 2 * latent_size))
        else:
            self.next_latent = nn.Linear(hidden_size, latent_size)
        self.reward = nn.Linear(hidden_size, 1)
        self.done = nn.Linear(hidden_size, 1)
        self.value = nn.Linear(hidden_size, 1) if auxiliary else None

    def forward(self, z: torch.Tensor, actions: torch.Tensor, state=None) -> MemoryOutput:
        """``z``: (B, T, L) latents, ``actions``: (B, T) long; ``state``: LSTM state or None."""
        inputs = torch.cat([z, F.one_hot(actions, self.n_actions).to(z.dtype)], dim=-1)
        hidden, state = self.lstm(inputs, state)
        return MemoryOutput(hidden, self.predict_latent(hidden), self.reward(hidden).squeeze(-1),
                            self.done(hidden).squeeze(-1),
                            None if self.value is None else self.value(hidden).squeeze(-1), state)

    def predict_latent(self, hidden: torch.Tensor) -> Mixture | torch.Tensor:
        """(..., H) -> the next-latent prediction: a :class:`Mixture` or (..., L)."""
        if self.kind == "deterministic":
            return self.next_latent(hidden)
        K, L = self.n_gaussians, self.latent_size
        out = self.mixture(hidden)
        log_pi = F.log_softmax(out[..., :K], dim=-1)
        mu, log_sigma = out[..., K:].unflatten(-1, (2, K, L)).unbind(-3)
        return Mixture(log_pi, mu, log_sigma)

    def step(self, z: torch.Tensor, action: torch.Tensor, state=None) -> MemoryOutput:
        """One time step: ``z`` (B, L), ``action`` (B,) -> outputs with T = 1 squeezed out."""
        out = self(z[:, None], action[:, None], state)
        next_latent = (Mixture(*(p[:, 0] for p in out.next_latent)) if isinstance(out.next_latent, Mixture)
                       else out.next_latent[:, 0])
        return MemoryOutput(out.hidden[:, 0], next_latent, out.reward[:, 0], out.done_logit[:, 0],
                            None if out.value is None else out.value[:, 0], out.state)

    def initial_state(self, batch: int, device=None) -> tuple[torch.Tensor, torch.Tensor]:
        zeros = torch.zeros(1, batch, self.hidden_size, device=device)
        return zeros, zeros.clone()


def mixture_nll(mixture: Mixture, target: torch.Tensor) -> torch.Tensor:
    """-log p(target) under the mixture, computed with log-sum-exp: (..., L) -> (...).

    log N(x; mu, sigma) = -sum_l [ (x - mu)^2 / (2 sigma^2) + log sigma + log(2 pi) / 2 ].
    """
    x = target.unsqueeze(-2)  # (..., 1, L)
    log_normal = -(((x - mixture.mu) * torch.exp(-mixture.log_sigma)).pow(2) / 2
                   + mixture.log_sigma + 0.5 * math.log(2 * math.pi)).sum(-1)
    return -torch.logsumexp(mixture.log_pi + log_normal, dim=-1)


def sample_mixture(mixture: Mixture, temperature: float = 1.0,
                   generator: torch.Generator | None = None) -> torch.Tensor:
    """Sample z ~ mixture with temperature tau: component from softmax(log_pi / tau), then
    N(mu, (sigma sqrt(tau))^2). Shapes (..., K, L) -> (..., L)."""
    if temperature <= 0:
        raise ValueError(f"temperature must be positive, got {temperature}")
    probs = F.softmax(mixture.log_pi / temperature, dim=-1)
    flat = probs.reshape(-1, probs.shape[-1])
    component = torch.multinomial(flat, 1, generator=generator).reshape(probs.shape[:-1])
    index = component[..., None, None].expand(*component.shape, 1, mixture.mu.shape[-1])
    mu = mixture.mu.gather(-2, index).squeeze(-2)
    sigma = mixture.log_sigma.gather(-2, index).squeeze(-2).exp() * math.sqrt(temperature)
    eps = torch.randn(mu.shape, generator=generator, device=mu.device, dtype=mu.dtype)
    return mu + sigma * eps


def _weighted_mse(prediction: torch.Tensor, target: torch.Tensor, weight: float) -> torch.Tensor:
    """Mean squared error where steps with a nonzero ``target`` weigh ``weight`` times the others."""
    if weight == 1.0:
        return F.mse_loss(prediction, target)
    weights = torch.where(target != 0, weight, 1.0)
    return (weights * (prediction - target).pow(2)).sum() / weights.sum()


def memory_loss(out: MemoryOutput, next_z: torch.Tensor, rewards: torch.Tensor, terminals: torch.Tensor,
                returns: torch.Tensor | None = None, reward_weight: float = 1.0) -> dict:
    """Training loss on a chunk, averaged over batch and time.

    ``next_z``: (B, T, L) the latents that followed; ``rewards``, ``terminals``: (B, T);
    ``returns``: (B, T) Monte-Carlo returns for the auxiliary value head. The latent term is
    the mixture NLL (``mdn``) or the squared error summed over L (``deterministic``). The
    reward term weighs a step with a reward ``reward_weight`` times one without (rare rewards
    balanced; the weights are normalised to average 1 over the chunk).
    """
    if isinstance(out.next_latent, Mixture):
        latent = mixture_nll(out.next_latent, next_z).mean()
    else:
        latent = (out.next_latent - next_z).pow(2).sum(-1).mean()
    terms = {"latent": latent,
             "reward": _weighted_mse(out.reward, rewards, reward_weight),
             "done": F.binary_cross_entropy_with_logits(out.done_logit, terminals.float())}
    if out.value is not None:
        if returns is None:
            raise ValueError("a memory with auxiliary heads needs the returns to train its value head")
        terms["value"] = F.mse_loss(out.value, returns)
    terms["loss"] = sum(terms.values())
    return terms
