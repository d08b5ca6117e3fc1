"""Exploration by ensemble disagreement during collection (beyond the thesis; Plan2Explore,
Sekar et al. 2020), for games whose random play never meets a reward.

Freeway pays only for a crossing and random play never crosses, so a model that sees the cars
(``freeway-adam``) learns from its seed episodes that no reward ever comes, and CEM over its
imagined rewards wanders. Here K one-step models each predict the next frame's
embedding from the RSSM's features and the action,

    e_hat_k(h_t, s_t, a_t) ~ e_{t+1},   k = 1..K,

trained beside the RSSM on the same chunks (on its detached features: they do not shape the
model). Where the data have been, the K predictions agree; where they have not, they part.
Their disagreement, the variance over k averaged over the embedding's features, is a bonus for
the imagined step, and while it collects the planner ranks its candidates by

    sum_t [ r_hat(h_{t+1}, s_{t+1}) + scale * disagreement(h_t, s_t, a_t) ].

Greedy test and evaluation episodes plan on the imagined rewards alone (the thesis's CEM).
"""
from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from wmthesis.envs.preprocessing import to_float
from wmthesis.planet.rssm import RSSM, one_hot_previous


class Disagreement(nn.Module):
    """K two-layer one-step models of width ``hidden``: features (N, H + S) and one-hot actions
    (N, A) -> predicted next embeddings (K, N, E); :meth:`forward` gives their disagreement (N,)."""

    def __init__(self, features: int, n_actions: int, embedding: int, hidden: int = 200, heads: int = 5):
        super().__init__()
        if heads < 2:
            raise ValueError(f"disagreement needs at least 2 heads, got {heads}")
        self.heads = nn.ModuleList(nn.Sequential(nn.Linear(features + n_actions, hidden), nn.ReLU(),
                                                 nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, embedding))
                                   for _ in range(heads))

    def predictions(self, features: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        inputs = torch.cat([features, actions], -1)
        return torch.stack([head(inputs) for head in self.heads])

    def forward(self, features: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """The heads' variance (unbiased) averaged over the embedding's features: (N,)."""
        return self.predictions(features, actions).var(0).mean(-1)


def build_disagreement(model: RSSM, hidden: int, heads: int) -> Disagreement:
    """An ensemble for ``model``'s features, actions and embedding, on its device."""
    return Disagreement(model.belief_size + model.state_size, model.n_actions, model.embedding_size, hidden,
                        heads).to(next(model.parameters()).device)


@torch.no_grad()
def one_step_batch(model: RSSM, observations: torch.Tensor, actions: torch.Tensor, bits: int = 5,
                   seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The ensemble's data from a batch of chunks, observations (B, T, H, W, 3) uint8 and actions
    (B, T) long: features ``(h_t, mean s_t)`` (B, T-1, H + S), one-hot actions ``a_t``
    (B, T-1, A) and the next embeddings ``e_{t+1}`` (B, T-1, E), all detached. The filter's
    samples come from ``seed`` alone: the RSSM's own random streams are left as they were."""
    generator = torch.Generator(observations.device).manual_seed(int(seed))
    embeddings = model.encode(to_float(observations, bits))
    trajectory = model.observe(embeddings, one_hot_previous(actions, model.n_actions), generator)
    features = torch.cat([trajectory.beliefs, trajectory.posterior.mean], -1)
    taken = F.one_hot(actions, model.n_actions).float()
    return features[:, :-1], taken[:, :-1], embeddings[:, 1:]


def disagreement_loss(ensemble: Disagreement, features: torch.Tensor, actions: torch.Tensor,
                      targets: torch.Tensor) -> torch.Tensor:
    """Mean squared error of every head on (features (..., F), actions (..., A), targets (..., E)),
    summed over the heads (each head learns on its own)."""
    return (ensemble.predictions(features, actions) - targets).pow(2).mean(tuple(range(1, targets.dim() + 1))).sum()


def imagined_bonus(model: RSSM, ensemble: Disagreement, belief: torch.Tensor, state: torch.Tensor,
                   actions: torch.Tensor, generator: torch.Generator | None = None
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """One sampled path per candidate: ``belief`` (1 or J, H), ``state`` (1 or J, S), one-hot
    ``actions`` (J, T, A) -> (imagined rewards (J,), disagreement (J,)), each summed over the T
    steps; a step's disagreement is taken at the state before its action."""
    rewards, bonus = actions.new_zeros(actions.shape[0]), actions.new_zeros(actions.shape[0])
    for step in model.imagined_steps(belief, state, actions, lambda prior: prior.sample(generator)):
        bonus = bonus + ensemble(torch.cat(step.before, -1), actions[:, step.t])
        rewards = rewards + model.reward(step.belief, step.state)
    return rewards, bonus


def explored_returns(model: RSSM, ensemble: Disagreement | None, scale: float, belief: torch.Tensor,
                     state: torch.Tensor, actions: torch.Tensor,
                     generator: torch.Generator | None = None) -> torch.Tensor:
    """CEM's objective while collecting: ``belief`` (1 or J, H), ``state`` (1 or J, S), one-hot
    ``actions`` (J, T, A) -> returns (J,), the imagined rewards plus ``scale`` x the disagreement
    of each imagined step (module docstring). With no ensemble, or ``scale`` 0, the same draws and
    returns as :meth:`~wmthesis.planet.rssm.RSSM.imagined_returns` (the thesis's)."""
    if ensemble is None or scale == 0:
        return model.imagined_returns(belief, state, actions, generator)
    rewards, bonus = imagined_bonus(model, ensemble, belief, state, actions, generator)
    return rewards + scale * bonus


@torch.no_grad()
def bonus_by_action(model: RSSM, ensemble: Disagreement, observations, actions, *, bits: int = 5,
                    horizon: int = 12, every: int = 50, seed: int = 0) -> torch.Tensor:
    """Does the bonus tell the planner where to go? From the belief filtered along a stored
    episode (observations (T, H, W, 3) uint8, actions (T,)) at every ``every``-th step, each action
    held for ``horizon`` imagined steps: the disagreement summed over those steps, (starts, A).
    Rows that barely differ leave CEM nothing to follow."""
    generator = torch.Generator(next(model.parameters()).device).manual_seed(int(seed))
    frames = to_float(torch.as_tensor(observations)[None], bits)
    taken = torch.as_tensor(actions)[None]
    trajectory = model.observe(model.encode(frames), one_hot_previous(taken, model.n_actions), generator)
    starts = torch.arange(0, frames.shape[1], every)
    belief, state = trajectory.beliefs[0, starts], trajectory.posterior.mean[0, starts]
    sums = []
    for action in range(model.n_actions):
        held = F.one_hot(torch.full((len(starts), horizon), action), model.n_actions).float().to(belief.device)
        paired = torch.Generator(belief.device).manual_seed(int(seed))  # every action meets the same draws
        sums.append(imagined_bonus(model, ensemble, belief, state, held, paired)[1])
    return torch.stack(sums, -1)


def load_explorer(run_dir, model: RSSM) -> Disagreement:
    """The disagreement ensemble of a PlaNet run trained with ``explore_scale`` > 0."""
    path = Path(run_dir) / "checkpoint.pt"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no PlaNet checkpoint here; train the run first "
                                "(python -m wmthesis reproduce planet-freeway --variant freeway-explore)")
    state = torch.load(path, map_location=next(model.parameters()).device, weights_only=False)
    if "explorer" not in state:
        raise ValueError(f"{path}: a run without exploration (explore_scale 0) has no disagreement ensemble")
    ensemble = build_disagreement(model, state["config"]["hidden_size"], state["config"]["explore_heads"])
    ensemble.load_state_dict(state["explorer"])
    return ensemble.eval()


__all__ = ["Disagreement", "build_disagreement", "one_step_batch", "disagreement_loss", "imagined_bonus",
           "explored_returns", "bonus_by_action", "load_explorer"]
