"""The config of Sokoban solved by search in a learned model (beyond the thesis; profiles:
:mod:`wmthesis.config`)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar


@dataclass(frozen=True)
class SokobanSearchConfig:
    """Sokoban solved by search in a learned model (beyond the thesis: its aim, chapter 1, where
    5.3 and 5.5 stopped at 0 levels). None of this is in the thesis; every value is ours.

    Data: ``random_levels`` levels of uniformly random play per variant, then ``rounds`` rounds
    per variant of ``levels_per_round`` levels played by the search agent (5.3.3's "iterative
    approach to gathering data"). The variants are played in the order of ``variants``, the
    later ones starting from what the earlier ones learned (one model, any board size): our
    generator's (``sokoban-small``, ``sokoban``) and Boxoban's train files
    (``boxoban-unfiltered-train``, ``boxoban-medium-train``). The default is a curriculum: 5x5
    levels of our generator, then Boxoban unfiltered train, then medium train.

    Model (:mod:`~wmthesis.sokoban_search.model`): ``channels`` x ``blocks`` residual layers,
    ``model_updates`` Adam updates (``lr``, cosine decay to lr / 10, batch ``batch_size`` with
    ``event_fraction`` of transitions whose reward is not the step penalty and ``agent_fraction``
    of transitions the agent played, not random play: the states its plans pass through, where the
    model must be exact) after random play, ``round_updates`` more after each round. Value (:mod:`~wmthesis.sokoban_search.heuristic`):
    ``value_channels`` x ``value_blocks``, ``value_updates`` after each round on every labelled
    state so far, shown in the board's 8 symmetries if ``value_symmetries``.

    Inputs: ``grid`` states (5.3.2) or ``pixels`` (5.3.1: RGB frames of ``tile_size`` pixels a
    cell, quantised to one of ``codes`` codes per cell by :mod:`~wmthesis.sokoban_search.cells`).

    Search (:mod:`~wmthesis.sokoban_search.search`): ``budget`` nodes per search, ``batch``
    nodes per model call, priority ``g + weight * h`` where a step costs ``1 + doubt`` times
    the model's surprise at its own prediction (nats), each of ``weights`` in turn until one
    finds a plan, at most ``replans`` searches again after the real game left the plan; in the
    training rounds ``round_budget`` nodes (0: ``budget``), a stronger expert than at evaluation,
    and at evaluation ``eval_budget`` (0: ``budget``). Fields that only the evaluation reads
    (``eval_budget``, ``eval_levels``) do not tell one trained run from another.
    A policy prior learned from the agent's own solutions (:mod:`~wmthesis.sokoban_search.policy`,
    the value's sizes and updates) adds ``prior_weight`` per nat of ``-log pi`` to a step's cost
    (0: none, and none is trained).
    Backed-up values: in the rounds each search keeps ``backups`` of the states it expanded,
    labelled with what the search found below them (:func:`~wmthesis.sokoban_search.heuristic.backed_up`,
    at most ``backup_cap`` steps), and ``backup_fraction`` of each of the value's batches is
    drawn among the last round's (``backups`` 0: only the states of solved levels, as before).
    Evaluation: ``eval_levels`` unseen levels of each of our generator's variants. Every choice
    above was made on Boxoban's validation files; the numbers: ``docs/findings/sokoban-search.md``.
    """

    variants: tuple = ("sokoban-small", "boxoban-unfiltered-train", "boxoban-medium-train")
    inputs: str = "grid"
    tile_size: int = 8
    codes: int = 8
    random_levels: int = 2000
    rounds: int = 4
    levels_per_round: int = 400
    channels: int = 64
    blocks: int = 2
    model_updates: int = 4000
    round_updates: int = 1500
    batch_size: int = 256
    lr: float = 2e-3
    event_fraction: float = 0.25
    agent_fraction: float = 0.5
    value_channels: int = 32
    value_blocks: int = 2
    value_updates: int = 1500
    value_symmetries: bool = True
    budget: int = 20_000
    batch: int = 64
    weights: tuple = (3.0, 1.5)
    doubt: float = 20.0
    replans: int = 4
    round_budget: int = 0
    eval_budget: int = 0
    prior_weight: float = 0.0
    backups: int = 200
    backup_cap: float = 120.0
    backup_fraction: float = 0.5
    eval_levels: int = 500
    seed: int = 0
    # what a run saved before a field was added did, where the field's default has changed since
    ADDED_AS: ClassVar[dict] = {"backups": 0}


@dataclass(frozen=True)
class SokobanEvaluationConfig:
    """How many levels the experiment plays beyond training: ``report_levels``, the first of each of
    Boxoban's report files; ``reference_levels``, the first of each evaluation's levels that the
    reference rows play (the true rules in place of the model, and A*: how much of the failures
    are the model's); ``validation_levels``, the first of each validation file a lever plays."""
    report_levels: int = 1000
    reference_levels: int = 1000
    validation_levels: int = 1000


__all__ = ["SokobanSearchConfig", "SokobanEvaluationConfig"]
