"""Configs of the PlaNet wing (thesis 4.4): the model and its planner, the KL scale x free nats
search, the evaluation; the thesis's values as defaults (profiles: :mod:`wmthesis.config`)."""
from __future__ import annotations

from dataclasses import dataclass


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
    figure_sequences: int = 3            # open-loop sequences in a run's figure
    study_seeds: int = 2                 # the model study (5.6.1-5.6.4): seeds per configuration,
    study_held_out: int = 5              # its held-out random bouts,
    study_sequences: int = 64            # open-loop sequences on them,
    study_context: int = 5               # their context
    study_horizon: int = 15              # and predicted steps
    agent_bouts: int = 10                # planet-boxing-agent's evaluation bouts

    def study(self) -> dict:
        """The model study's sizes: ``seeds``, ``held_out``, ``sequences``, ``context``, ``horizon``."""
        return dict(seeds=self.study_seeds, held_out=self.study_held_out, sequences=self.study_sequences,
                    context=self.study_context, horizon=self.study_horizon)

    def open_loop(self, atari: bool) -> tuple:
        """(context, predicted steps, cut-off horizon) of an Atari game or of Sokoban."""
        return self.atari_open_loop if atari else self.sokoban_open_loop


__all__ = ["PlaNetConfig", "SearchConfig", "PlanetEvaluationConfig"]
