"""Playing levels in the real environment: random play, and the search agent.

The agent searches in its model for a plan to the end of the level, then plays the plan in the
real environment while the real states match the model's; at the first difference it searches
again from where it stands (at most ``replans`` times). Every transition it sees is kept, to
train the model further; a solved level also labels its states with the steps that remained.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from wmthesis.envs import SOKOBAN_VARIANTS
from wmthesis.envs.sokoban import SokobanEnv
from wmthesis.sokoban_search.cells import GRID
from wmthesis.sokoban_search.search import best_first
from wmthesis.utils import check_choice, derive_seeds


@dataclass
class Play:
    """One level played: its ``seed`` (None for a given board), whether it was ``solved``, the
    ``actions`` taken, the search's ``expanded`` nodes and ``generated`` model transitions,
    ``searches`` run, ``seconds``, and the ``transitions`` seen (arrays of
    :class:`~wmthesis.sokoban_search.experience.Experience`)."""

    seed: int | None
    solved: bool
    actions: list[int]
    expanded: int
    generated: int
    searches: int
    seconds: float
    transitions: dict = field(repr=False, default_factory=dict)

    def record(self) -> dict:
        """What is saved of the play (JSON-ready): everything but the transitions."""
        return dict(seed=self.seed, solved=self.solved, steps=len(self.actions), actions=list(self.actions),
                    expanded=self.expanded, generated=self.generated, searches=self.searches,
                    seconds=round(self.seconds, 4))


def grid_env(name: str, **options) -> SokobanEnv:
    """The Sokoban variant ``name`` with grid observations."""
    check_choice("Sokoban variant", name, tuple(SOKOBAN_VARIANTS))
    return SokobanEnv(**SOKOBAN_VARIANTS[name], observation="grid", **options)


def grid_state(env: SokobanEnv, observation: np.ndarray) -> np.ndarray:
    """A grid observation (h' * w',) -> the state, uint8 (h', w') (the board's inner cells)."""
    return GRID.observe(env, observation)


class SearchAgent:
    """Best-first search in ``model`` (a :class:`~wmthesis.sokoban_search.model.SokobanModel` or
    the :class:`~wmthesis.sokoban_search.search.Simulator`: anything with ``expand``), guided by
    ``heuristic`` (steps to go, or None: breadth first), ``budget`` nodes per search, ``batch``
    per model call; ``inputs`` (:mod:`~wmthesis.sokoban_search.cells`: grid states or pixels)
    turns what the env shows into the model's state, and makes envs that show it."""

    def __init__(self, model, *, inputs=GRID, heuristic=None, budget: int = 20_000,
                 batch: int = 64, weight: float = 1.0, replans: int = 4):
        self.model, self.inputs = model, inputs
        self.heuristic, self.budget, self.batch, self.weight, self.replans = heuristic, budget, batch, weight, replans

    def env(self, variant: str) -> SokobanEnv:
        """Variant ``variant`` showing what this agent sees."""
        check_choice("Sokoban variant", variant, tuple(SOKOBAN_VARIANTS))
        return SokobanEnv(**SOKOBAN_VARIANTS[variant], **self.inputs.env_options)

    def play(self, env: SokobanEnv, seed: int | None = None, board=None) -> Play:
        """Play one level: the one ``seed`` generates, or ``board`` (codes or text)."""
        start = time.perf_counter()
        observation, _ = env.reset(seed=seed, options=None if board is None else {"board": board})
        state = self.inputs.observe(env, observation)
        rows = {k: [] for k in ("states", "actions", "next_states", "rewards", "dones")}
        taken, expanded, generated, searches, solved, over = [], 0, 0, 0, False, False
        while not (solved or over) and searches <= self.replans:
            result = best_first(self.model.expand, state, heuristic=self.heuristic, budget=self.budget,
                                batch=self.batch, weight=self.weight)
            searches, expanded, generated = searches + 1, expanded + result.expanded, generated + result.generated
            if not result.found:
                break
            for action, predicted in zip(result.actions, result.states[1:]):
                observation, reward, solved, over, _ = env.step(action)
                following = self.inputs.observe(env, observation)
                for key, value in zip(rows, (state, action, following, reward, solved)):
                    rows[key].append(value)
                taken.append(action)
                state = following
                if solved or over or not np.array_equal(following, predicted):
                    break
        transitions = {k: np.asarray(v, dtype=dtype) for (k, v), dtype in
                       zip(rows.items(), (np.uint8, np.uint8, np.uint8, np.float32, bool))}
        if not taken:
            shape = (0, *state.shape)
            transitions.update(states=np.zeros(shape, np.uint8), next_states=np.zeros(shape, np.uint8))
        return Play(seed, bool(solved), taken, expanded, generated, searches, time.perf_counter() - start,
                    transitions)


def random_play(name: str, seed: int, levels: int, max_steps: int | None = None) -> dict[str, np.ndarray]:
    """``levels`` episodes of uniformly random actions on levels of variant ``name``: level i
    and its actions seeded from ``(seed, i)``. Returns the transitions' arrays."""
    env = grid_env(name, **({} if max_steps is None else {"max_steps": max_steps}))
    rows = {k: [] for k in ("states", "actions", "next_states", "rewards", "dones")}
    for i in range(levels):
        level_seed, action_seed = (int(s) for s in derive_seeds(seed, i, n=2))
        rng = np.random.default_rng(action_seed)
        observation, _ = env.reset(seed=level_seed)
        state, done = grid_state(env, observation), False
        while not done:
            action = int(rng.integers(env.action_space.n))
            observation, reward, terminated, truncated, _ = env.step(action)
            following = grid_state(env, observation)
            for key, value in zip(rows, (state, action, following, reward, terminated)):
                rows[key].append(value)
            state, done = following, terminated or truncated
    return {k: np.asarray(v, dtype=dtype) for (k, v), dtype in
            zip(rows.items(), (np.uint8, np.uint8, np.uint8, np.float32, bool))}


def level_seeds(seed: int, purpose: int, n: int) -> list[int]:
    """``n`` level seeds for a ``purpose`` (0: random play, 1 + r: training round r, 1000:
    evaluation), disjoint streams of one experiment seed."""
    return [int(s) for s in derive_seeds(seed, 7_000_000 + purpose, n=n)]


__all__ = ["SearchAgent", "Play", "random_play", "grid_env", "grid_state", "level_seeds"]
