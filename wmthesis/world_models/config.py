"""Configs of the World Models wing (thesis 4.2): the vision, the memory and the controller evolved with
CMA-ES, the thesis's values as their defaults (profiles: :mod:`wmthesis.config`)."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class VisionConfig:
    """Vision (thesis 4.2.5): latent 16 (64 for the grid variant, 5.3.2), Adam lr 1e-3,
    eps 1e-7, batch 256. Not stated in the thesis: the number of updates, the validation
    split (the last episodes of the store) and early stopping."""

    latent_size: int = 16
    lr: float = 1e-3
    adam_eps: float = 1e-7
    batch_size: int = 256
    steps: int = 20_000
    eval_every: int = 500
    patience: int | None = 5
    val_fraction: float = 0.1


@dataclass(frozen=True)
class MemoryConfig:
    """Memory (thesis 4.2.5, 4.3.1, 5.3.3): LSTM 256, 5 Gaussians, Adam lr 1e-3, eps 1e-8,
    batch 128 chunks of 1000 steps; ``kind`` ``mdn`` or ``deterministic``; ``auxiliary`` adds
    the value head (Monte-Carlo return with ``discount``). Not stated in the thesis: the number
    of updates, the validation split and early stopping."""

    kind: str = "mdn"
    hidden_size: int = 256
    n_gaussians: int = 5
    auxiliary: bool = False
    temperature: float = 1.0
    lr: float = 1e-3
    adam_eps: float = 1e-8
    batch_size: int = 128
    sequence_length: int = 1000
    discount: float = 0.99
    steps: int = 20_000
    eval_every: int = 500
    patience: int | None = 5
    val_fraction: float = 0.1


@dataclass(frozen=True)
class ControllerConfig:
    """Controller evolution (thesis 4.2.2, 4.2.5): CMA-ES, population 64, 5 episodes per
    candidate, fitness = mean return; a linear greedy controller on ``[z h]``.

    Not stated in the thesis: the initial sigma (0.1, Ha & Schmidhuber's), the number of
    generations, and the start variation: each episode begins with a seeded random number of
    no-op actions in ``[0, noop_max)`` (Boxing with sticky actions off is deterministic, so five
    episodes of a greedy controller would otherwise be identical). ``dream=True`` (beyond the
    thesis) evolves inside the memory with sampling temperature ``temperature``; every
    ``eval_every`` generations the CMA-ES mean plays ``eval_episodes`` real episodes.
    ``diagonal=True`` (beyond the thesis) runs separable CMA-ES: a diagonal covariance, so the
    state and its checkpoint grow with D rather than D^2 (a Boxing controller on [z h] has
    D = 4,914: the full strategy pickles to ~390 MB, the diagonal one to ~3 MB). ``mirrored=True``
    (beyond the thesis) draws the candidates in antithetic pairs, every one of them (cma's
    ``CMA_mirrors`` = population / 2, unconditional), which cancels much of the noise in the
    mean's step.
    """

    population: int = 64
    episodes: int = 5                    # per candidate; fitness = mean return over them
    generations: int = 200               # not stated in the thesis
    sigma: float = 0.1                   # initial CMA-ES step size; the search starts at zero
    diagonal: bool = False               # separable CMA-ES (diagonal covariance): O(D) memory and time
    mirrored: bool = False               # mirrored sampling: candidates in pairs m +- sigma * y (cma's CMA_mirrors)
    max_steps: int | None = None         # None: full-length episodes
    noop_max: int = 30
    seed: int = 0
    dream: bool = False
    temperature: float = 1.0
    dream_max_steps: int = 1800          # a Boxing bout (2 minutes) is ~1,780 agent steps
    eval_every: int = 10                 # 0: never play the mean in the real game
    eval_episodes: int = 5


@dataclass(frozen=True)
class BoxingEvaluationConfig:
    """How an evolved Boxing controller is scored (the thesis reports its training fitness):
    ``bouts`` full bouts of the CMA-ES mean, the same seeded no-op starts for every controller and
    seed; the memory's open loop on a validation episode, ``context`` real steps then ``horizon``
    predicted."""

    bouts: int = 10
    context: int = 60
    horizon: int = 30


@dataclass(frozen=True)
class SokobanWorldModelsConfig:
    """World Models on Sokoban (thesis 5.3.1-5.3.3): what differs from the profile's configs, and
    the evaluation. ``collect_episodes``: random rollouts (None: the profile's
    :class:`~wmthesis.config.CollectConfig`); ``sequence_length``: the memory's chunks (None: the
    profile's; the thesis's 1,000 steps do not fit 120-step episodes, so whole episodes, 119
    transitions). ``levels`` unseen levels for the controllers and random play; open-loop rollouts
    on up to ``episodes`` validation episodes, ``context`` real steps then ``horizon`` predicted
    ones; numbers reported at ``cutoff`` steps ahead."""

    collect_episodes: int | None = None
    sequence_length: int | None = 119
    levels: int = 100
    episodes: int = 100
    context: int = 60
    horizon: int = 30
    cutoff: int = 10

    def changes(self) -> dict:
        """The changes on top of the profile's configs, by config class name."""
        return {**({"CollectConfig": dict(episodes=self.collect_episodes)} if self.collect_episodes else {}),
                **({"MemoryConfig": dict(sequence_length=self.sequence_length)} if self.sequence_length else {})}

    def evaluation(self) -> dict:
        """``levels``, ``episodes``, ``context``, ``horizon`` and ``cutoff``."""
        return dict(levels=self.levels, episodes=self.episodes, context=self.context, horizon=self.horizon,
                    cutoff=self.cutoff)

@dataclass(frozen=True)
class DreamConfig:
    """Learning inside the dream (beyond the thesis: World Models' iterative procedure, after Ha &
    Schmidhuber 2018 and SimPLe, Kaiser et al. 2019) under a budget of real agent steps.

    ``budget``: real agent steps the run may spend (Atari 100k's 100,000 = 400k frames; the final
    evaluation bouts do not count); ``random_bouts``: the first random-play bouts; then, while the
    budget lasts, each iteration fine-tunes the memory on every real step so far for
    ``memory_updates`` updates, evolves the controller in the dream for ``generations`` CMA-ES
    generations (``population`` candidates, ``starts`` dreams each, all from the same real states
    of the store: the memory warmed on ``warmup`` real steps, then ``dream_length`` dreamed steps
    at ``temperature``), and plays ``bouts`` real bouts with the CMA-ES mean, which join the
    store. ``reward_weight``: a rewarded step's weight in the memory's reward term (1: as the
    thesis). ``disagreement``: the weight of the penalty where ``ensemble`` memories disagree on
    the next latent (0 with one memory: none). The controller kept is the iteration's mean whose
    real bouts scored best."""

    budget: int = 100_000
    random_bouts: int = 10
    bouts: int = 5
    memory_updates: int = 300
    generations: int = 20
    population: int = 64
    starts: int = 16
    warmup: int = 20
    dream_length: int = 50
    temperature: float = 1.0
    sigma: float = 0.1
    reward_weight: float = 1.0
    ensemble: int = 1
    disagreement: float = 0.0
    noop_max: int = 30
    seed: int = 0


__all__ = ["VisionConfig", "MemoryConfig", "ControllerConfig", "BoxingEvaluationConfig", "SokobanWorldModelsConfig",
           "DreamConfig"]
