"""Configs of the learned-value wing (beyond the thesis, on a frozen PlaNet model): the value and
CEM that ends in it; the defaults are Boxing's sizes (profiles: :mod:`wmthesis.config`)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar


@dataclass(frozen=True)
class LatentValueConfig:
    """A short-horizon action value on a trained PlaNet model's latent (beyond the thesis;
    :mod:`~wmthesis.value.latent_value`): Q of an action = the sum of the next ``reward_steps``
    rewards, the mean of ``heads`` two-layer heads of ``hidden_size`` (an ensemble, each head on
    its own batches) on the RSSM's features after the action.
    Fitted with ``fit_updates`` Adam steps (``batch_size``, ``lr``) on ``random_bouts`` random
    bouts, then ``rounds`` times on those and ``bouts_per_round`` more epsilon-greedy bouts of its own;
    ``validation_bouts`` greedy bouts after each fit choose the round whose value is kept (on bouts
    of their own), ``test_bouts`` greedy bouts score each round. The defaults are Boxing's sizes: a
    punch lands two steps after it is thrown, so three rewards.

    ``target``: ``reward-sum`` (the sum above, the agent of notebook 09), ``discounted-sum`` (each
    of the ``n`` rewards discounted by ``discount`` per step: a long window for rewards far
    apart, such as Freeway's crossings), ``log-discounted-sum`` (its logarithm,
    ``log(sum + discount^n)``: one step nearer a reward 90 steps away counts as much as one step
    nearer a reward 3 steps away; Q is the exponential of the heads' mean) or ``td``: temporal
    differences through the frozen model, ``r_t + ... + discount^(n-1) r_{t+n-1} + discount^n
    max_a Q(h_{t+n}, s_{t+n}, a)``, the bootstrap from the value fitted before (a fitted-Q
    iteration whose target network is the previous fit), refreshed ``td_iterations`` times per
    fit (the fit's updates shared among them), so the value looks past its ``n`` rewards.

    ``agent_rounds``: which values make the agent. 0: the round with the best validation mean;
    k > 0: the mean of the last k rounds' values (a snapshot ensemble, which averages out fitted
    Q's swings from round to round instead of choosing among them on a few bouts).
    ``score_rounds``: every round's value plays its validation and test bouts (the learning curve,
    and the choice of round); False (lean, with ``agent_rounds`` > 0, which chooses no round):
    only the agent plays, on the test bouts.
    """

    reward_steps: int = 3
    hidden_size: int = 256
    heads: int = 5
    random_bouts: int = 100
    fit_updates: int = 6000
    batch_size: int = 256
    lr: float = 1e-3
    rounds: int = 5
    bouts_per_round: int = 20
    epsilon: float = 0.3
    validation_bouts: int = 5
    test_bouts: int = 10
    target: str = "reward-sum"
    discount: float = 0.95
    td_iterations: int = 3
    agent_rounds: int = 0
    score_rounds: bool = True


@dataclass(frozen=True)
class ValuePlannerConfig:
    """CEM whose candidates end in the learned action value (beyond the thesis;
    :mod:`~wmthesis.value.planner`): ``horizon`` imagined steps, the last one's reward
    and what follows from the value, each step discounted by ``discount``; CEM's candidates,
    top K and iterations are the PlaNet config's. ``horizon`` 1 is the value agent itself.
    ``imagine``: the imagined states are the prior's samples (``sample``, the thesis's), its
    ``mean``, or samples sharing one noise draw across candidates (``shared``); ``value_prior`` > 0
    seeds CEM's first step with that many z-scores of the value's Q (0: the thesis's zero mean; the
    seeding was chosen on validation bouts, with the numbers in ``docs/findings/planet-boxing-value.md``).
    ``rewards``: the imagined steps' rewards from the model's reward head (``model``, the
    thesis's) or each step scored by the value's Q of its action (``value``); ``reward_head``: the
    model's reward head as PlaNet trained it (None) or refit on the value run's own bouts
    (``own``, :mod:`~wmthesis.value.own_rewards`; with ``rewards="model"``). ``candidates`` and
    ``iterations`` replace the PlaNet config's where set (a search budget of H x J x I imagined steps
    an action: ``reproduce planning-budget``). ``pessimism`` beta scores the value's Q of every imagined
    step after the first as its heads' mean less beta times their spread (an uncertainty penalty that
    keeps the search where the value was fitted). ``particles`` K: each candidate's return the mean
    over K imagined paths (PETS's particles; None: 1; a budget of H x J x I x K imagined steps)."""

    horizon: int = 3
    discount: float = 1.0
    imagine: str = "sample"
    value_prior: float = 1.0
    rewards: str = "model"
    reward_head: str | None = None       # None: PlaNet's own reward head; "own": refit (own_rewards)
    candidates: int | None = None        # CEM's candidates J (None: the PlaNet config's)
    iterations: int | None = None        # CEM's iterations I (None: the PlaNet config's)
    pessimism: float | None = None       # beta: imagined steps' Q less beta x its heads' spread (None: 0)
    particles: int | None = None         # K imagined paths per candidate, their returns' mean (None: 1)
    # what a run saved before a field was added did, where the field's default has changed since
    ADDED_AS: ClassVar[dict] = {"value_prior": 0.0}



@dataclass(frozen=True)
class ValueEvaluationConfig:
    """How a value run is scored beside its baselines: ``plan_steps`` steps of a bout on which the
    planners' choices are compared; ``lever_bouts`` validation bouts per Boxing planner lever or
    agent rule; Freeway's ``freeway_episodes`` evaluation episodes, ``freeway_lever_episodes``
    validation episodes per planner lever, and ``lookahead_episodes`` episodes of the planner that
    looks ahead in the emulator itself (the perfect-model ceiling)."""

    plan_steps: int = 500
    lever_bouts: int = 10
    freeway_episodes: int = 10
    freeway_lever_episodes: int = 10
    lookahead_episodes: int = 10


__all__ = ["LatentValueConfig", "ValuePlannerConfig", "ValueEvaluationConfig"]
