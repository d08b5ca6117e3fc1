"""Configs of the PlaNet wing (thesis 4.4): the model and its planner, the learned value and CEM with
it, the KL scale x free nats search; the thesis's values as defaults (profiles: :mod:`wmthesis.config`)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar


@dataclass(frozen=True)
class PlaNetConfig:
    """PlaNet (thesis 4.4.3-4.4.5): model, loss, optimiser, data collection, CEM planner.

    RSSM: GRU 200, stochastic state 30, other functions FC 200 (ReLU), reward FF 100 x 2.
    Loss: KL scale and free nats (the tuned knobs, 5.6.3-5.6.5; these defaults are PlaNet's),
    decoder variance (5.6.3), latent overshooting with its KL terms scaled by 1/50.
    Adam lr 1e-3, eps 1e-4, gradient clipping 1000, 50 chunks of 50 steps. 6 random seed
    episodes, then one planner episode every C = ``update_steps`` updates (5000, 4.4.3; the
    PlaNet paper used 100), epsilon-greedy 0.3, action repeat 4. CEM: H 12, J 1000, K 100, I 10.
    Frames: the whole screen resized to 64x64 (4.4.4), the encoder and decoder of depth 32
    (:mod:`~wmthesis.planet.networks`); ``crop`` keeps only the play area (the World Models crop,
    :data:`~wmthesis.envs.preprocessing.CROPS`). Beyond the thesis, ``explore_scale`` > 0 adds
    Plan2Explore's ensemble disagreement to CEM's returns while collecting
    (:mod:`~wmthesis.planet.explore`).
    """

    frame_size: int = 64
    depth: int = 32                      # channels of the first convolution (then x2 per layer)
    crop: bool = False
    belief_size: int = 200
    state_size: int = 30
    hidden_size: int = 200
    reward_hidden_size: int = 100
    min_std: float = 0.1
    bits: int = 5
    kl_scale: float = 1.0
    free_nats: float = 3.0
    decoder_variance: float = 1.0
    reward_scale: float = 10.0           # the official code's default (the thesis used that code)
    overshooting_distance: int = 50      # 0 or 1: no latent overshooting
    overshooting_scale: float = 1 / 50
    overshooting_reward_scale: float = 0.0  # beyond the thesis: the reward head on open-loop beliefs too
    prior_reward_scale: float = 0.0      # beyond the thesis: the reward head on one-step prior states too
    reward_event_weight: float = 1.0     # beyond the thesis: steps with a reward count this many times
    lr: float = 1e-3
    adam_eps: float = 1e-4
    grad_clip: float = 1000.0
    batch_size: int = 50
    chunk_length: int = 50
    seed_episodes: int = 6
    update_steps: int = 5000
    pretrain_updates: int = 0            # on the seed episodes alone, before the first planner episode
    action_repeat: int = 4
    max_episode_steps: int | None = None  # None: full-length episodes
    env_steps: int = 1_000_000           # agent steps in the store when training stops
    epsilon: float = 0.3
    horizon: int = 12
    candidates: int = 1000
    top_k: int = 100
    iterations: int = 10
    test_interval: int = 10              # planner episodes between greedy tests (not in the thesis)
    test_episodes: int = 5               # not in the thesis
    explore_scale: float = 0.0           # beyond the thesis: the disagreement bonus while collecting (0: none)
    explore_heads: int = 5               # its ensemble of one-step models (wmthesis.planet.explore)


@dataclass(frozen=True)
class LatentValueConfig:
    """A short-horizon action value on a trained PlaNet model's latent (beyond the thesis;
    :mod:`~wmthesis.planet.value`): Q of an action = the sum of the next ``reward_steps``
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
    :mod:`~wmthesis.planet.value_planner`): ``horizon`` imagined steps, the last one's reward
    and what follows from the value, each step discounted by ``discount``; CEM's candidates,
    top K and iterations are the PlaNet config's. ``horizon`` 1 is the value agent itself.
    ``imagine``: the imagined states are the prior's samples (``sample``, the thesis's), its
    ``mean``, or samples sharing one noise draw across candidates (``shared``); ``value_prior`` > 0
    seeds CEM's first step with that many z-scores of the value's Q (0: the thesis's zero mean; the
    seeding was chosen on validation bouts, with the numbers in ``docs/findings/planet-boxing-value.md``).
    ``rewards``: the imagined steps' rewards from the model's reward head (``model``, the
    thesis's) or each step scored by the value's Q of its action (``value``); ``reward_head``: the
    model's reward head as PlaNet trained it (None) or refit on the value run's own bouts
    (``own``, :mod:`~wmthesis.planet.own_rewards`; with ``rewards="model"``). ``candidates`` and
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
class SearchConfig:
    """Random search over KL scale x free nats (thesis 5.6.3-5.6.5; the thesis gives no
    ranges, trial count or budget: these are ours, wide enough to hold Boxing's best values,
    3e-2 / 12 (5.6.4), and our guess for Freeway, 8e-3 / 3 (5.6.5 gives no values)). KL scale is log-uniform, free nats uniform.
    ``objective``: ``score`` (final greedy test score, maximised), ``error`` (open-loop error on
    the moving pixels of ``held_out_episodes`` random episodes at the game's cut-off horizon,
    minimised) or ``both`` (a two-objective study). ``env_steps``
    and ``max_episode_steps`` override the PlaNet budget and episode cap of each trial (None:
    the profile's). Heartbeats: a trial whose worker has not beaten for ``grace_period``
    seconds is marked failed."""

    trials: int = 50
    workers: int = 2
    seed: int = 0
    objective: str = "both"
    kl_scale_low: float = 1e-3
    kl_scale_high: float = 1.0
    free_nats_low: float = 0.0
    free_nats_high: float = 20.0
    env_steps: int | None = 100_000
    max_episode_steps: int | None = None   # caps each trial's episodes (None: the profile's PlaNet value)
    open_loop_sequences: int = 6
    open_loop_length: int = 30           # 5 context frames + 25 predicted
    held_out_episodes: int = 3
    heartbeat_interval: int = 60
    grace_period: int = 300


@dataclass(frozen=True)
class PlanetEvaluationConfig:
    """How a PlaNet run is scored after training (not in the thesis, which reported 5 runs'
    tests): ``episodes`` greedy episodes, and the open loop as (context, predicted steps, cut-off
    horizon) for Sokoban and for Atari games; the error at the cut-off horizon is the number its
    ``metrics.json`` reports."""
    episodes: int = 10
    sokoban_open_loop: tuple = (5, 15, 10)
    atari_open_loop: tuple = (5, 30, 15)

    def open_loop(self, atari: bool) -> tuple:
        """(context, predicted steps, cut-off horizon) of an Atari game or of Sokoban."""
        return self.atari_open_loop if atari else self.sokoban_open_loop


__all__ = ["PlaNetConfig", "LatentValueConfig", "ValuePlannerConfig", "SearchConfig", "PlanetEvaluationConfig"]
