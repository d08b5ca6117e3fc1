"""A short-horizon action value on a trained RSSM's latent (beyond the thesis).

CEM's imagined returns need the reward model to tell which action lands a reward. In Boxing
a punch thrown at step t scores at t + 2, and a model trained on 32x32 frames ranks the action
that landed a hit barely above the others (``docs/findings/planet-boxing-value.md``). This module
keeps the trained RSSM frozen and learns, on its features, the reward that an action brings
over the next few steps:

    Q(h_t, s_t, a) = value(h_{t+1}, mean of p(s_{t+1} | h_{t+1})),   h_{t+1} = f(h_t, s_t, a)
    target: r_t + r_{t+1} + ... + r_{t+n-1}   (n = ``reward_steps``, within the episode)

(or each reward discounted, ``gamma^k r_{t+k}``: the ``discounted-sum`` target, for games whose
rewards lie far apart, such as Freeway's crossings; its logarithm, ``log-discounted-sum``, fitted
as ``log(sum + gamma^n)`` so that a step nearer a far reward weighs as much as one near it: one
step is a factor of 1/gamma on any scale; or temporal differences, ``td``)

where ``r_t`` is the reward of taking ``a_t``. The features are the one-step prior of the
planner's first imagined step, so the action enters through the RSSM's own transition. The
agent (:class:`ValueMind`) filters ``(h_t, s_t)`` with the posterior mean and takes the argmax
of Q over all actions: one transition per action, no CEM. It learns like a fitted-Q iteration
on its own play: the value is fitted on random bouts, then each round adds ``bouts_per_round``
epsilon-greedy bouts of the value agent to its store and refits on all of it. Fitted Q swings
from round to round (its own bouts change its data), so the agent is the round whose value
scored best on greedy validation bouts of their own; Q is the mean of an ensemble of heads.
"""
from __future__ import annotations


import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from wmthesis.envs.preprocessing import to_float
from wmthesis.value.config import LatentValueConfig
from wmthesis.planet.rssm import RSSM, one_hot_previous
from wmthesis.planet.agent import BeliefFilter
from wmthesis.training import gradient_step

TARGETS = ("reward-sum", "discounted-sum", "log-discounted-sum", "td")


def reward_sums(rewards: np.ndarray, steps: int, discount: float = 1.0) -> np.ndarray:
    """(T,) -> (T,): ``r_t + discount r_{t+1} + ... + discount^(steps-1) r_{t+steps-1}`` of one
    episode, cut at its end."""
    if steps < 1:
        raise ValueError(f"reward_steps must be >= 1, got {steps}")
    padded = np.concatenate([np.asarray(rewards, np.float32), np.zeros(steps - 1, np.float32)])
    weights = (discount ** np.arange(steps)).astype(np.float32)
    return np.correlate(padded, weights, mode="valid")


def td_targets(sums: torch.Tensor, values: torch.Tensor, steps: int, discount: float) -> torch.Tensor:
    """One episode's temporal-difference targets (T,): ``sums[t] + discount^steps values[t + steps]``,
    with nothing after the episode's end (``values`` (T,): max_a Q of each step's belief)."""
    boot = torch.zeros_like(sums)
    boot[:max(len(sums) - steps, 0)] = values[steps:]
    return sums + discount ** steps * boot


@torch.inference_mode()
def best_values(model: RSSM, value: nn.Module, beliefs: torch.Tensor, states: torch.Tensor,
                chunk: int = 4096) -> torch.Tensor:
    """``max_a Q(h, s, a)`` (T,) of beliefs (T, H) and states (T, S), every action through the
    model's transition (:func:`after_action`), ``chunk`` beliefs at a time."""
    return torch.cat([action_values(model, value, beliefs[start:start + chunk], states[start:start + chunk]).amax(-1)
                      for start in range(0, len(beliefs), chunk)])


def action_values(model: RSSM, value: nn.Module, beliefs: torch.Tensor, states: torch.Tensor) -> torch.Tensor:
    """Q of every action (T, A) from beliefs (T, H) and states (T, S), each action through the
    model's transition (:func:`after_action`)."""
    count = model.n_actions
    every = torch.arange(count, device=beliefs.device)
    features = after_action(model, beliefs.repeat_interleave(count, 0), states.repeat_interleave(count, 0),
                            every.repeat(len(beliefs)))
    return value(features).reshape(len(beliefs), count)


def after_action(model: RSSM, belief: torch.Tensor, state: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
    """Features of taking ``actions`` (...,) long from ``(h_t, s_t)``, (..., H) and (..., S):
    ``(h_{t+1}, mean of p(s_{t+1} | h_{t+1}))``, (..., H + S)."""
    belief, prior = model.transition(belief, state, F.one_hot(actions, model.n_actions).float())
    return torch.cat([belief, prior.mean], -1)


class LatentValue(nn.Module):
    """An ensemble of ``heads`` two-layer heads of width ``hidden``: features (..., F) -> Q (...,),
    the mean of the heads (:meth:`each` gives them apart, (..., heads)). With ``log``, the heads
    fit the logarithm of Q (the ``log-discounted-sum`` target) and Q is the exponential of their
    mean, on the scale of rewards."""

    def __init__(self, features: int, hidden: int, heads: int = 1, log: bool = False):
        super().__init__()
        if heads < 1:
            raise ValueError(f"heads must be >= 1, got {heads}")
        self.heads = nn.ModuleList(nn.Sequential(nn.Linear(features, hidden), nn.ReLU(), nn.Linear(hidden, hidden),
                                                 nn.ReLU(), nn.Linear(hidden, 1)) for _ in range(heads))
        self.log = log

    def each(self, features: torch.Tensor) -> torch.Tensor:
        return torch.cat([head(features) for head in self.heads], -1)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        q = self.each(features).mean(-1)
        return q.exp() if self.log else q


def log_scaled(config: LatentValueConfig | dict) -> bool:
    """Whether a value of ``config`` (or its saved dict) fits the logarithm of its target."""
    target = config.get("target") if isinstance(config, dict) else config.target
    return target == "log-discounted-sum"


@torch.inference_mode()
def episode_features(model: RSSM, episode: dict[str, np.ndarray], bits: int, seed: int,
                     beliefs: bool = False):
    """Features of each taken action of a stored episode (observations (T, H, W, 3) uint8,
    actions (T,)), filtering with the posterior as in training: (T, H + S); with ``beliefs``,
    also each step's belief (T, H) and posterior mean (T, S) before its action."""
    generator = torch.Generator(next(model.parameters()).device).manual_seed(seed)
    frames = to_float(torch.as_tensor(episode["observations"], device=generator.device)[None], bits, noise=generator)
    actions = torch.as_tensor(episode["actions"], device=generator.device)
    trajectory = model.observe(model.encode(frames), one_hot_previous(actions[None], model.n_actions), generator)
    h, s = trajectory.beliefs[0], trajectory.posterior.mean[0]
    features = after_action(model, h, s, actions)
    return (features, h, s) if beliefs else features


class ValueMind(BeliefFilter):
    """The value agent for :func:`~wmthesis.core.loop`, passed as the mind and among the
    callbacks (:class:`~wmthesis.planet.agent.BeliefFilter`). :meth:`plan` filters
    ``(h_t, s_t)`` with the frame (the posterior's mean) and returns Q of every action."""

    def __init__(self, model: RSSM, value: LatentValue, bits: int = 5, seed: int = 0):
        super().__init__(model, bits, torch.Generator(next(model.parameters()).device).manual_seed(int(seed)))
        self.value = value

    observe_options = {"sample": False}  # as plan() observes

    @torch.inference_mode()
    def plan(self, frame: np.ndarray, train_mode: bool = True, debug_mode: bool = False) -> np.ndarray:
        self.observe(frame, sample=False)
        return action_values(self.model, self.value, self.belief, self.state)[0].cpu().numpy()


def fit_value(value: LatentValue, features: torch.Tensor, targets: torch.Tensor,
              config: LatentValueConfig, seed: int) -> float:
    """``config.fit_updates`` Adam steps of mean squared error on (features (N, F), targets (N,)),
    each head on its own random batches, through the shared guarded step (a NaN stops the fit
    with :class:`~wmthesis.training.NonFiniteLoss` before that update); returns the last step's
    loss, averaged over the heads."""
    optimizer = torch.optim.Adam(value.parameters(), lr=config.lr)
    rng = np.random.default_rng(seed)
    loss = torch.zeros(())
    for update in range(1, config.fit_updates + 1):
        batches = torch.as_tensor(rng.integers(len(targets), size=(len(value.heads), config.batch_size)),
                                  device=targets.device)
        loss = sum(F.mse_loss(head(features[batch]).squeeze(-1), targets[batch])
                   for head, batch in zip(value.heads, batches)) / len(value.heads)
        gradient_step("latent value", update, {"loss": loss}, optimizer, value.parameters(),
                      kept="the value of the last finished round is kept in value.pt")
    return float(loss.detach())


def round_ensemble(states: list[dict], hidden: int, log: bool = False) -> LatentValue:
    """One value whose heads are those of several rounds' values (state dicts of
    :class:`LatentValue`, the same number of heads each): Q is the mean over the rounds (a
    snapshot ensemble, which averages out fitted Q's swings from round to round; with ``log``,
    the values' logarithms are averaged)."""
    if not states:
        raise ValueError("round_ensemble needs at least one round's value")
    heads = 1 + max(int(key.split(".")[1]) for key in states[0])
    features = states[0]["heads.0.0.weight"].shape[1]
    value = LatentValue(features, hidden, heads * len(states), log).to(states[0]["heads.0.0.weight"].device)
    value.load_state_dict({f"heads.{i * heads + int(key.split('.')[1])}.{key.split('.', 2)[2]}": tensor
                           for i, state in enumerate(states) for key, tensor in state.items()})
    return value.eval()


__all__ = ["LatentValue", "ValueMind", "after_action", "episode_features", "fit_value", "reward_sums", "log_scaled",
           "td_targets", "best_values", "action_values", "round_ensemble", "TARGETS"]
