"""PlaNet's CEM with a learned value at the end of its horizon (beyond the thesis; PlaNet's
successors, TD-MPC and Dreamer, plan or act this way).

The thesis's CEM scores a candidate by its imagined rewards over H steps. Here the last step's
reward and everything after it are the learned action value of :mod:`~wmthesis.value.latent_value`:

    R(a_t .. a_{t+H-1}) = sum_{k < H-1} gamma^k r(h_{t+k+1}, s_{t+k+1})
                          + gamma^{H-1} Q(h_{t+H-1}, s_{t+H-1}, a_{t+H-1})

with ``Q = value(h_{t+H}, mean of p(s_{t+H} | h_{t+H}))`` (the value's features after an action,
:func:`~wmthesis.value.latent_value.after_action`). The imagined states ``s`` are sampled from the
prior as in the thesis's planner (``imagine="sample"``), or are the prior's mean (``"mean"``: one
deterministic imagined path per candidate, no sampling noise in its return), or samples that share
one noise draw across the candidates (``"shared"``: common random numbers; with the thesis's
independent draws, the noise of one imagined step's Q is about three times the spread of Q
between first actions on Boxing, so CEM's elites are the lucky draws). With ``particles`` K > 1
each candidate's return is the mean over K imagined paths (PETS's particles, Chua et al. 2018:
the noise of one draw shrinks by sqrt(K), at K times the imagined steps). With
``value_prior`` > 0 the value also seeds the search: CEM's first mean for the first step is
``value_prior`` times the z-scores of Q over the actions (TD-MPC seeds its search with a learned
policy in the same spirit); 0 starts from zero, the thesis's. Two ends meet the two agents it joins:

- no value (``value=None``): exactly the thesis's CEM objective
  (:meth:`~wmthesis.planet.rssm.RSSM.imagined_returns`), the same random draws included;
- H = 1: ``R(a_t) = Q(h_t, s_t, a_t)``, the value agent's own score of ``a_t``
  (:class:`~wmthesis.value.latent_value.ValueMind`).
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from wmthesis.core import loop
from wmthesis.rollouts import EpisodeBuffer
from wmthesis.planet.cem import cem_belief
from wmthesis.planet.config import PlaNetConfig
from wmthesis.value.config import ValuePlannerConfig
from wmthesis.planet.rssm import RSSM, Gaussian, randn_like
from wmthesis.planet.agent import BeliefFilter, PlanetMind
from wmthesis.value.latent_value import LatentValue, action_values


IMAGINE = ("sample", "mean", "shared")  # the imagined states: prior samples, its mean, samples with one noise for all
REWARDS = ("model", "value")  # where an imagined step's reward comes from (value_returns)


def value_returns(model: RSSM, value: LatentValue | None, belief: torch.Tensor, state: torch.Tensor,
                  actions: torch.Tensor, generator: torch.Generator | None = None,
                  discount: float = 1.0, imagine: str = "sample", rewards: str = "model",
                  pessimism: float = 0.0, particles: int = 1) -> torch.Tensor:
    """The returns R (J,) of one-hot action sequences ``actions`` (J, H, A) from ``belief``
    (1 or J, B) and ``state`` (1 or J, S): imagined rewards, the last step's (and after) from
    ``value`` (module docstring); ``value=None``: imagined rewards alone. ``imagine``: the
    imagined states are the prior's samples (the thesis's), its ``mean`` or samples of one noise
    draw for all candidates (``shared``, :func:`imagined_state`). ``rewards``: each
    imagined step's reward from the model's reward head (``model``, the thesis's), or (``value``)
    every step scored by the value, ``sum_k gamma^k Q(h_{t+k}, s_{t+k}, a_{t+k})``: the learned
    sums of real rewards in place of a reward head that barely ranks a landed punch. ``pessimism``
    beta: Q of every step after the first, from imagined states alone, is the mean of the value's
    heads less beta times their spread (:func:`pessimistic_q`); the first step's Q, from the real
    belief, is the value agent's own. ``particles`` K: each candidate's return is the mean over K
    imagined paths (its actions repeated K times; with ``shared``, K noise draws shared by all)."""
    belief, state = (x.repeat_interleave(particles, 0) if len(x) > 1 else x for x in (belief, state))
    paths = path_returns(model, value, belief, state, actions.repeat_interleave(particles, 0), generator,
                         discount, imagine, rewards, pessimism, draws=particles)  # candidate j: rows j K .. j K + K - 1
    return paths.view(-1, particles).mean(1)


def path_returns(model: RSSM, value: LatentValue | None, belief: torch.Tensor, state: torch.Tensor,
                 actions: torch.Tensor, generator: torch.Generator | None, discount: float, imagine: str,
                 rewards: str, pessimism: float, draws: int = 1) -> torch.Tensor:
    """The return (N,) of each imagined path of ``actions`` (N, H, A) (:func:`value_returns`, one
    path per row); ``draws``: the shared noise draws (:func:`imagined_state`)."""
    horizon = actions.shape[1]
    total = actions.new_zeros(actions.shape[0])
    for step in model.imagined_steps(belief, state, actions, lambda prior: imagined_state(prior, generator, imagine, draws)):
        t = step.t
        if value is not None and (t == horizon - 1 or rewards == "value"):
            total = total + discount ** t * pessimistic_q(value, torch.cat([step.belief, step.prior.mean], -1),
                                                          pessimism if t else 0.0)
            if t == horizon - 1:
                return total
        if value is None or rewards == "model":
            total = total + discount ** t * model.reward(step.belief, step.state)
    return total


def imagined_state(prior: Gaussian, generator: torch.Generator | None, imagine: str, draws: int = 1) -> torch.Tensor:
    """The imagined states (N, S) of the prior ``p(s | h)`` (N, S): a sample each (``sample``, the
    thesis's), its ``mean``, or (``shared``) samples that share ``draws`` noise draws ``mean + std * eps``,
    eps (draws, S), row n drawing ``eps[n % draws]``: common random numbers, so that candidates
    differ by their actions, not their luck."""
    if imagine == "mean":
        return prior.mean
    if imagine == "shared":
        eps = randn_like(prior.mean[:draws], generator)
        return prior.mean + prior.std * eps.repeat(len(prior.mean) // draws, 1)
    return prior.sample(generator)


def pessimistic_q(value: LatentValue, features: torch.Tensor, beta: float) -> torch.Tensor:
    """Q (N,) of ``features`` (N, F): the mean of the value's heads less ``beta`` times their
    standard deviation (their disagreement, large where the heads never saw such states; on the
    log scale for a ``log`` value); ``beta`` 0 is the value itself."""
    if not beta:
        return value(features)
    heads = value.each(features)
    if heads.shape[-1] < 2:
        raise ValueError("a pessimistic value needs at least 2 heads to disagree, got 1")
    q = heads.mean(-1) - beta * heads.std(-1)
    return q.exp() if value.log else q


def value_scores(model: RSSM, value: LatentValue, belief: torch.Tensor, state: torch.Tensor,
                 scale: float, horizon: int) -> torch.Tensor:
    """CEM's first mean (H, A) seeded by the value: the first row ``scale`` times the z-scores
    of Q(h, s, a) over the A actions from ``belief`` (1, B) and ``state`` (1, S); the later rows zero."""
    q = action_values(model, value, belief, state)[0]
    mean = q.new_zeros(horizon, model.n_actions)
    mean[0] = scale * (q - q.mean()) / q.std().clamp_min(1e-6)
    return mean


class ValuePlanetMind(PlanetMind):
    """PlaNet's agent (:class:`~wmthesis.planet.agent.PlanetMind`: the belief filtered with the
    posterior's sample, CEM's sizes) whose candidates end in ``value`` (:func:`value_returns`)."""

    def __init__(self, model: RSSM, value: LatentValue | None, *, discount: float = 1.0, imagine: str = "sample",
                 value_prior: float = 0.0, rewards: str = "model", pessimism: float = 0.0, particles: int = 1,
                 **planner):
        super().__init__(model, **planner)
        _check_planner(discount, imagine, value_prior, value, rewards, pessimism, particles)
        self.value, self.discount, self.imagine, self.value_prior = value, float(discount), imagine, float(value_prior)
        self.rewards, self.pessimism, self.particles = rewards, float(pessimism), int(particles)

    def returns(self, actions: torch.Tensor) -> torch.Tensor:
        return value_returns(self.model, self.value, self.belief, self.state, actions, self.generator, self.discount,
                             self.imagine, self.rewards, self.pessimism, self.particles)

    def first_mean(self) -> torch.Tensor | None:
        if not self.value_prior:
            return None
        return value_scores(self.model, self.value, self.belief, self.state, self.value_prior, self.sizes["horizon"])


def _check_planner(discount: float, imagine: str, value_prior: float, value, rewards: str = "model",
                   pessimism: float = 0.0, particles: int = 1) -> None:
    if isinstance(particles, bool) or not isinstance(particles, int) or particles < 1:
        raise ValueError(f"particles must be an integer >= 1, got {particles!r}")
    if not 0.0 < discount <= 1.0:
        raise ValueError(f"discount must be in (0, 1], got {discount}")
    if imagine not in IMAGINE:
        raise ValueError(f"imagine must be one of {IMAGINE}, got {imagine!r}")
    if rewards not in REWARDS or (rewards == "value" and value is None):
        raise ValueError(f"rewards must be one of {REWARDS} (value needs a value), got {rewards!r} "
                         f"with value={value is not None}")
    if value_prior < 0 or (value_prior and value is None):
        raise ValueError(f"value_prior must be >= 0 and needs a value, got {value_prior} with value={value is not None}")
    if pessimism < 0 or (pessimism and value is None):
        raise ValueError(f"pessimism must be >= 0 and needs a value, got {pessimism} with value={value is not None}")


def value_planner_mind(model: RSSM, value: LatentValue, planet: PlaNetConfig, planner: ValuePlannerConfig,
                       mind_seed: int = 0) -> "ValuePlanetMind":
    """The planner with value as its bouts played it: CEM's sizes from ``planet``, its horizon and
    levers from ``planner``, CEM's noise from ``mind_seed``."""
    return ValuePlanetMind(model, value, horizon=planner.horizon, candidates=planner.candidates or planet.candidates,
                           top_k=planet.top_k, iterations=planner.iterations or planet.iterations, bits=planet.bits,
                           discount=planner.discount,
                           imagine=planner.imagine, value_prior=planner.value_prior, rewards=planner.rewards,
                           pessimism=planner.pessimism or 0.0, particles=planner.particles or 1,
                           generator=torch.Generator(next(model.parameters()).device).manual_seed(int(mind_seed)))


def play_value_planner(env, model: RSSM, value: LatentValue, planet: PlaNetConfig, planner: ValuePlannerConfig,
                       env_seed: int, mind_seed: int, frames: list | None = None) -> list[float]:
    """One greedy episode of the planner with value in ``env`` (reset with ``env_seed``; CEM's
    noise from ``mind_seed``; CEM's sizes from ``planet``, its horizon from ``planner``): its
    rewards, one per agent step; ``frames`` (a list), where given, gets the episode's frames."""
    mind = value_planner_mind(model, value, planet, planner, mind_seed)
    record = EpisodeBuffer()
    loop(env, mind, policy="deterministic", callbacks=[mind, record], seed=int(env_seed), train_mode=False)
    if frames is not None:
        frames += list(record.episode["observations"])
    return [float(r) for r in record.episode["rewards"]]


PLANNERS = ("CEM (thesis)", "CEM with value", "value alone")


@torch.inference_mode()
def plan_choices(model: RSSM, value: LatentValue, planet: PlaNetConfig, planner: ValuePlannerConfig,
                 frames: np.ndarray, actions: np.ndarray, seed: int = 0) -> dict[str, np.ndarray]:
    """Where the value changes the plan: along a recorded episode, ``frames`` (T, size, size, 3)
    uint8 and the ``actions`` (T,) taken, the action that each of :data:`PLANNERS` would take at
    every step from one and the same belief (filtered with the posterior's mean): the thesis's
    CEM (horizon ``planet.horizon``), CEM with the value at the end of ``planner.horizon`` steps,
    and the value agent's argmax of Q. Returns each planner's actions (T,) int64 (CEM's noise
    from ``seed``)."""
    generator = torch.Generator(next(model.parameters()).device).manual_seed(int(seed))
    track = BeliefFilter(model, planet.bits, generator)
    sizes = dict(candidates=planet.candidates, top_k=planet.top_k, iterations=planet.iterations, generator=generator)
    chosen = {name: [] for name in PLANNERS}
    for frame, action in zip(frames, actions):
        track.observe(frame, sample=False)
        belief, state = track.belief, track.state
        thesis = cem_belief(lambda a: model.imagined_returns(belief, state, a, generator), model.n_actions,
                            planet.horizon, **sizes)
        first = value_scores(model, value, belief, state, planner.value_prior, planner.horizon) if planner.value_prior else None
        ours = cem_belief(lambda a: value_returns(model, value, belief, state, a, generator, planner.discount,
                                                  planner.imagine, planner.rewards, planner.pessimism or 0.0,
                                                  planner.particles or 1),
                          model.n_actions, planner.horizon,
                          mean=first, **sizes)
        q = action_values(model, value, belief, state)[0]
        for name, pick in zip(PLANNERS, (thesis.mean[0].argmax(), ours.mean[0].argmax(), q.argmax())):
            chosen[name].append(int(pick))
        track.prev_action = F.one_hot(torch.tensor([int(action)], device=belief.device), model.n_actions).float()
    return {name: np.asarray(picks, np.int64) for name, picks in chosen.items()}


__all__ = ["value_planner_mind", "value_returns", "path_returns", "imagined_state", "pessimistic_q", "value_scores", "IMAGINE", "REWARDS", "ValuePlanetMind", "play_value_planner", "plan_choices", "PLANNERS"]
