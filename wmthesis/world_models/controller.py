"""Controller: the linear policy of World Models (thesis 4.2.2, 4.2.5).

    scores_t = W [z_t h_t] + b,    a_t = argmax(scores_t)

``z_t`` (L) is the vision's latent of the current frame, ``h_t`` (H) the memory's LSTM output
before acting (H = 0 for a controller on ``z`` alone); W is (A, L + H), b is (A,). The action is
greedy in training and testing: CMA-ES explores in parameter space, not in action space.

CMA-ES sees the controller as one flat vector of ``A * (L + H) + A`` numbers: W row by row, then
b (the order of ``torch.nn.utils.parameters_to_vector`` on an ``nn.Linear``).
:func:`population_scores` scores a whole population at once without building modules.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import torch
from torch import nn

from wmthesis.core import Callback, Mind
from wmthesis.utils import check_finite


class Controller(nn.Module):
    """``scores = W [z h] + b``: ``z`` (B, L), ``h`` (B, H) -> scores (B, A)."""

    def __init__(self, latent_size: int, hidden_size: int, n_actions: int):
        super().__init__()
        self.latent_size, self.hidden_size, self.n_actions = latent_size, hidden_size, n_actions
        self.linear = nn.Linear(latent_size + hidden_size, n_actions)

    def forward(self, z: torch.Tensor, h: torch.Tensor | None = None) -> torch.Tensor:
        """Scores; ValueError for NaN or infinite latents or memory state (not action 0)."""
        check_finite("the controller's latents z", z)
        if h is not None:
            check_finite("the controller's memory state h", h)
        return self.linear(features(z, h))

    def act(self, z: torch.Tensor, h: torch.Tensor | None = None) -> torch.Tensor:
        """Greedy actions (B,) long."""
        return self(z, h).argmax(-1)

    @property
    def num_parameters(self) -> int:
        return num_parameters(self.latent_size + self.hidden_size, self.n_actions)

    def get_flat(self) -> np.ndarray:
        """The parameters as one float64 vector (D,), W row by row then b."""
        return nn.utils.parameters_to_vector(self.parameters()).detach().double().cpu().numpy()

    def set_flat(self, params) -> "Controller":
        """Load a flat vector (D,) as written by :meth:`get_flat`; returns self."""
        params = torch.as_tensor(np.asarray(params), dtype=torch.float32)
        if params.shape != (self.num_parameters,):
            raise ValueError(f"expected {self.num_parameters} parameters, got shape {tuple(params.shape)}")
        check_finite("the controller's parameters", params)
        nn.utils.vector_to_parameters(params, self.parameters())
        return self

    @classmethod
    def from_flat(cls, params, latent_size: int, hidden_size: int, n_actions: int) -> "Controller":
        return cls(latent_size, hidden_size, n_actions).set_flat(params)


def features(z: torch.Tensor, h: torch.Tensor | None) -> torch.Tensor:
    """The controller's input ``[z h]``: (..., L) and (..., H) -> (..., L + H)."""
    return z if h is None or h.shape[-1] == 0 else torch.cat([z, h], dim=-1)


def num_parameters(in_features: int, n_actions: int) -> int:
    """D = A * (L + H) + A."""
    return n_actions * in_features + n_actions


def unflatten(params: torch.Tensor, in_features: int, n_actions: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A population of flat vectors (P, D) -> weights (P, A, F) and biases (P, A)."""
    P, D = params.shape
    if D != num_parameters(in_features, n_actions):
        raise ValueError(f"expected {num_parameters(in_features, n_actions)} parameters per candidate "
                         f"(A={n_actions}, F={in_features}), got {D}")
    weight = params[:, : n_actions * in_features].reshape(P, n_actions, in_features)
    return weight, params[:, n_actions * in_features:]


def population_scores(weight: torch.Tensor, bias: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Every candidate scores its own episodes: W (P, A, F), b (P, A), x (P, E, F) -> (P, E, A)."""
    return torch.baddbmm(bias[:, None, :], x, weight.transpose(1, 2))


class ControllerMind(Mind, Callback):
    """Vision + memory + controller as a HumbleRL mind, for :func:`wmthesis.core.loop`.

    It is also a callback that advances the memory with the action actually taken and resets
    it at each episode start, so pass it both ways::

        loop(env, mind, callbacks=[mind], policy="deterministic")

    ``plan(state)``: the observation (e.g. (64, 64, 3) uint8) -> action scores (A,).
    """

    def __init__(self, vision: Callable, memory, controller: Controller):
        self.vision, self.memory, self.controller = vision, memory, controller
        if memory is not None:
            memory.eval()
        self.reset()

    def reset(self) -> None:
        self.state = None if self.memory is None else self.memory.initial_state(1)
        self.h = None if self.memory is None else torch.zeros(1, self.memory.hidden_size)
        self.z = None

    @torch.inference_mode()
    def plan(self, state, train_mode: bool = True, debug_mode: bool = False) -> np.ndarray:
        if self.z is not None:
            raise RuntimeError("ControllerMind.plan was called twice without a step: pass the mind "
                               "as a callback too, loop(env, mind, callbacks=[mind])")
        self.z = self.vision(torch.as_tensor(np.asarray(state))[None])
        h = None if self.h is None else self.h.to(self.z.device)
        return self.controller.to(self.z.device)(self.z, h)[0].cpu().numpy()

    def on_episode_start(self, episode: int, train_mode: bool) -> None:
        self.reset()

    @torch.inference_mode()
    def observe_step(self, frame, action: int) -> None:
        """One step of an episode seen and taken: ``frame`` encoded, the memory stepped on it and
        ``action`` (what :func:`~wmthesis.core.loop` does through :meth:`plan` and the callback)."""
        self.z = self.vision(torch.as_tensor(np.asarray(frame))[None])
        if self.memory is not None:
            out = self.memory.step(self.z, torch.tensor([int(action)], device=self.z.device), self.state)
            self.h, self.state = out.hidden, out.state
        self.z = None

    @torch.inference_mode()
    def on_step_taken(self, step, transition, info) -> None:
        if self.memory is not None:
            played = info.get("action", transition.action) if info else transition.action  # ScoredStart's no-ops
            action = torch.tensor([played], device=self.z.device)
            out = self.memory.step(self.z, action, self.state)
            self.h, self.state = out.hidden, out.state
        self.z = None
