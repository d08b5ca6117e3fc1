"""Discrete cross-entropy method planner (thesis 4.4.2, Fig. 47).

The belief over plans is a time-dependent diagonal Gaussian over *action-score vectors*,
mean and std of shape (H, A). Each of I iterations samples J score sequences (J, H, A), turns
each step's scores into the one-hot of their argmax, evaluates all J action sequences at once
with ``rollout_fn`` (one batched model pass per horizon step, no loop over candidates) and
refits mean and std (the standard deviation, as the official code) to the score vectors of
the top K sequences. The plan's first action is the argmax of the final mean's first row.
Every call starts again from zero mean and unit std (the belief is reset after every step).

Thesis sizes: H = 12, J = 1000, K = 100, I = 10.
"""
from __future__ import annotations

from typing import Callable, NamedTuple

import torch
import torch.nn.functional as F

RolloutFn = Callable[[torch.Tensor], torch.Tensor]


class Belief(NamedTuple):
    """The final belief of a plan: ``mean`` and ``std`` (H, A) over action scores, the
    returns (J,) of the last iteration's candidates, and ``elites`` (I,): the mean return of each
    iteration's top K."""

    mean: torch.Tensor
    std: torch.Tensor
    returns: torch.Tensor
    elites: torch.Tensor


def cem_belief(rollout_fn: RolloutFn, n_actions: int, horizon: int, candidates: int,
               top_k: int, iterations: int, generator: torch.Generator | None = None,
               mean: torch.Tensor | None = None) -> Belief:
    """Run the discrete CEM and return its final :class:`Belief`.

    ``rollout_fn`` maps one-hot action sequences (J, H, A) float to returns (J,). Sampling
    happens on ``generator``'s device (the CPU without one); the one-hot batch is passed on
    that device. ``mean`` (H, A): the first belief's mean (beyond the thesis: a prior that seeds
    the search); zeros without one, the thesis's.
    """
    _check_sizes(n_actions, horizon, candidates, top_k, iterations)
    device = generator.device if generator is not None else torch.device("cpu")
    if mean is None:
        mean = torch.zeros(horizon, n_actions, device=device)
    elif mean.shape != (horizon, n_actions):
        raise ValueError(f"the first mean must have shape (horizon, n_actions) = ({horizon}, {n_actions}), "
                         f"got {tuple(mean.shape)}")
    std = torch.ones(horizon, n_actions, device=device)
    elites = []
    for _ in range(iterations):
        noise = torch.randn((candidates, horizon, n_actions), generator=generator, device=device)
        scores = mean + std * noise
        actions = F.one_hot(scores.argmax(-1), n_actions).float()
        returns = rollout_fn(actions).reshape(candidates).to(device)
        top = returns.topk(top_k)
        best = scores[top.indices]
        mean, std = best.mean(0), best.std(0, unbiased=False)
        elites.append(top.values.mean())
    return Belief(mean, std, returns, torch.stack(elites))


def cem_plan(rollout_fn: RolloutFn, n_actions: int, horizon: int, candidates: int,
             top_k: int, iterations: int, generator: torch.Generator | None = None) -> int:
    """The index of the action to take now: argmax of the final belief's first mean row.

    ``rollout_fn`` maps one-hot action sequences of shape (J, H, A) to returns of shape (J,),
    with J = ``candidates``, H = ``horizon``, A = ``n_actions``; K = ``top_k`` sequences refit
    the belief in each of I = ``iterations``.
    """
    belief = cem_belief(rollout_fn, n_actions, horizon, candidates, top_k, iterations, generator)
    return int(belief.mean[0].argmax())


def _check_sizes(n_actions, horizon, candidates, top_k, iterations) -> None:
    if min(n_actions, horizon, candidates, top_k, iterations) < 1:
        raise ValueError("n_actions, horizon, candidates, top_k and iterations must be >= 1, got "
                         f"{n_actions}, {horizon}, {candidates}, {top_k}, {iterations}")
    if top_k > candidates:
        raise ValueError(f"top_k ({top_k}) cannot exceed candidates ({candidates})")


__all__ = ["cem_plan", "cem_belief", "Belief"]
