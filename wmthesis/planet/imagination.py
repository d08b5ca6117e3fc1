"""How far a learned value reads a PlaNet model's imagination (beyond the thesis; issue 57).

CEM with the value (:mod:`~wmthesis.planet.value_planner`) scores a candidate by Q at the states
it imagines: the first step's from the real belief, every later step's from states sampled from
the model's prior. Search pays only where Q at those imagined states still tells good from bad.
This module measures it along recorded episodes: from each step's posterior ``(h_t, s_t)``,
``depth`` steps are imagined along the actions that were taken, and Q after the next taken action
is set against the rewards that really followed,

    corr( Q(f_d(t)),  r_{t+d} + ... + r_{t+d+n-1} )

where ``f_d(t)`` are the value's features after ``a_{t+d}`` from the state imagined ``d`` steps
past ``t``. Depth 0 is the value where it was fitted (the posterior); the fall with depth is what
the imagined steps of a search lose.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from wmthesis.planet.rssm import RSSM
from wmthesis.planet.value import after_action, episode_features, reward_sums


def imagined_features(model: RSSM, beliefs: torch.Tensor, states: torch.Tensor, actions: torch.Tensor, depth: int,
                      generator: torch.Generator | None = None) -> torch.Tensor:
    """From every step's posterior, beliefs (T, H) and states (T, S) before actions (T,) long,
    ``depth`` steps imagined along the actions taken, then the value's features after the next
    one: (T - depth, H + S), row t those after ``a_{t+depth}``. The imagined states are the
    prior's samples (CEM's, drawn with ``generator``) or, with ``generator`` None, its mean.
    Depth 0: the features after each action from the posterior itself."""
    if isinstance(depth, bool) or not isinstance(depth, int) or depth < 0:
        raise ValueError(f"depth must be an integer >= 0, got {depth!r}")
    count = len(actions) - depth
    belief, state = beliefs[:count], states[:count]
    for step in range(depth):
        belief, prior = model.transition(belief, state, F.one_hot(actions[step:step + count], model.n_actions).float())
        state = prior.mean if generator is None else prior.sample(generator)
    return after_action(model, belief, state, actions[depth:])


@torch.inference_mode()
def value_signal(model: RSSM, value: nn.Module, episodes: list[dict], bits: int, *, reward_steps: int = 3,
                 depths: tuple[int, ...] = (0, 1, 2, 3), seed: int = 0) -> dict[int, float]:
    """Per depth, the correlation over every step of ``episodes`` (dicts with ``observations``
    (T, size, size, 3) uint8, ``actions`` (T,), ``rewards`` (T,)) between Q at the features
    imagined that deep (:func:`imagined_features`, the prior's samples as CEM draws them, seeded
    by ``seed``) and the sum of the ``reward_steps`` real rewards that followed (module docstring)."""
    generator = torch.Generator(next(model.parameters()).device).manual_seed(int(seed))
    q, sums = {d: [] for d in depths}, {d: [] for d in depths}
    for index, episode in enumerate(episodes):
        _, beliefs, states = episode_features(model, episode, bits, int(seed) + index, beliefs=True)
        actions = torch.as_tensor(episode["actions"], device=beliefs.device)
        real = reward_sums(episode["rewards"], reward_steps)
        for depth in depths:
            q[depth].append(value(imagined_features(model, beliefs, states, actions, depth, generator)).cpu().numpy())
            sums[depth].append(real[depth:])
    return {d: float(np.corrcoef(np.concatenate(q[d]), np.concatenate(sums[d]))[0, 1]) for d in depths}


__all__ = ["imagined_features", "value_signal"]
