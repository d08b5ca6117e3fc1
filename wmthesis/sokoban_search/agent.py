"""Playing levels in the real environment: random play, and the search agent.

The agent searches in its model for a plan to the end of the level, then plays the plan in the
real environment while the real states match the model's; at the first difference it searches
again from where it stands (at most ``replans`` times). It remembers what it saw: in the searches
that follow, a state and action it has played give the real outcome, not the model's
(:class:`Remembered`), so a mistake of the model misleads it once, not at every search. Every
transition it sees is kept, to train the model further; a solved level also labels its states
with the steps that remained.

A search that spends its budget without a plan starts again with the next of the agent's
``weights`` on the value (quick: 3, then 1.5). The two orders of expansion fail on different
levels: of the 73 unseen 10x10 levels that the pixel agent of a quick run failed with weight 3
alone (budget 20,000), a second search with weight 1.5 solved 24; going on to 40,000 nodes with
weight 3 solved 23, at about the same cost, and the two sets overlap in 14 levels only.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from wmthesis.envs import SOKOBAN_VARIANTS
from wmthesis.envs.sokoban import SokobanEnv
from wmthesis.sokoban_search.cells import GRID
from wmthesis.sokoban_search.heuristic import backed_up
from wmthesis.sokoban_search.search import best_first
from wmthesis.utils import check_choice, derive_seeds


@dataclass
class Play:
    """One level played: its ``seed`` (None for a given board), whether it was ``solved``, the
    ``actions`` taken, the search's ``expanded`` nodes and ``generated`` model transitions,
    ``searches`` run, ``seconds``, the ``transitions`` seen (arrays of
    :class:`~wmthesis.sokoban_search.experience.Experience`), and ``backed_up``: states its
    searches expanded with their backed-up steps to go (``states`` uint8 (n, h, w), ``labels``
    float32 (n,); empty unless the agent keeps some)."""

    seed: int | None
    solved: bool
    actions: list[int]
    expanded: int
    generated: int
    searches: int
    seconds: float
    transitions: dict = field(repr=False, default_factory=dict)
    backed_up: dict = field(repr=False, default_factory=dict)

    def record(self) -> dict:
        """What is saved of the play (JSON-ready): everything but the transitions."""
        return dict(seed=self.seed, solved=self.solved, steps=len(self.actions), actions=list(self.actions),
                    expanded=self.expanded, generated=self.generated, searches=self.searches,
                    seconds=round(self.seconds, 4))


def variant_options(name: str) -> dict:
    """The ``SokobanEnv`` options of a variant the agent may train on: a generated one
    (``sokoban``, ``sokoban-small``), or DeepMind's Boxoban train levels
    (``boxoban-unfiltered-train``, ``boxoban-medium-train[:FILES]``, 10x10 with 4 boxes), a level
    drawn by the seed. Boxoban's valid files are for validation and report, never for training."""
    if name.startswith("boxoban-"):
        from wmthesis.envs.boxoban import parse_source

        kind, _ = parse_source(name)
        if not kind.endswith("-train"):
            raise ValueError(f"Sokoban variant {name!r}: only Boxoban's train files are played in training "
                             "(the valid files are kept for validation and the reported figures)")
        return dict(dim_room=(10, 10), num_boxes=4, levels=name)
    check_choice("Sokoban variant", name, tuple(SOKOBAN_VARIANTS))
    return SOKOBAN_VARIANTS[name]


def grid_env(name: str, **options) -> SokobanEnv:
    """The Sokoban variant ``name`` (:func:`variant_options`) with grid observations."""
    return SokobanEnv(**variant_options(name), observation="grid", **options)


def grid_state(env: SokobanEnv, observation: np.ndarray) -> np.ndarray:
    """A grid observation (h' * w',) -> the state, uint8 (h', w') (the board's inner cells)."""
    return GRID.observe(env, observation)


class Remembered:
    """``model`` (anything with ``expand``), with the real transitions seen so far in place of
    its predictions (and no surprise in them). ``remember(state (h, w), action, following
    (h, w), reward, done)``; ``expand`` as the model's."""

    def __init__(self, model):
        self.model, self.seen = model, {}

    def remember(self, state: np.ndarray, action: int, following: np.ndarray, reward: float, done: bool) -> None:
        self.seen.setdefault(state.tobytes(), {})[int(action)] = (following, reward, done)

    def expand(self, states: np.ndarray):
        children, rewards, dones, surprises = self.model.expand(states)
        for i, state in enumerate(states):
            for action, (following, reward, done) in self.seen.get(state.tobytes(), {}).items():
                children[i, action], rewards[i, action], dones[i, action] = following, reward, done
                surprises[i, action] = 0.0
        return children, rewards, dones, surprises


class Memo:
    """``expand`` (a model's, (B, h, w) -> four arrays of B rows) and ``estimate`` (a value's,
    (B, h, w) -> (B,)), each state's answer kept and given again without calling the network.
    An agent's searches on one level share most of their states (the search with the next
    weight, the replans): on 3 medium Boxoban validation levels that took 31-40k expansions, 26-35%
    of the expanded states had been expanded before. Within one play only, so that memory stays
    bounded; the answers are the network's (a state's outcome may differ in its last bits with the
    batch it was computed in, as it already does between searches)."""

    def __init__(self, expand, estimate=None):
        self._expand, self._estimate = expand, estimate
        self.expansions, self.estimates = {}, {}

    def expand(self, states: np.ndarray):
        rows = self._remembered(self.expansions, self._expand, states)
        return tuple(np.stack([row[field] for row in rows]) for field in range(len(rows[0])))

    def estimate(self, states: np.ndarray) -> np.ndarray:
        return np.asarray(self._remembered(self.estimates, self._estimate, states), dtype=np.float32)

    @staticmethod
    def _remembered(memo: dict, fn, states: np.ndarray) -> list:
        keys = [state.tobytes() for state in states]
        new = list({key: i for i, key in enumerate(keys) if key not in memo}.values())
        if new:
            answers = fn(np.asarray(states)[new])
            answers = list(zip(*answers)) if isinstance(answers, tuple) else list(answers)
            memo.update(zip((keys[i] for i in new), answers))
        return [memo[key] for key in keys]


class SearchAgent:
    """Best-first search in ``model`` (a :class:`~wmthesis.sokoban_search.model.SokobanModel` or
    the :class:`~wmthesis.sokoban_search.search.Simulator`: anything with ``expand``), guided by
    ``heuristic`` (steps to go, or None: breadth first), ``budget`` nodes per search, ``batch``
    per model call, ``weights`` on the heuristic tried in turn (a search that spends its budget
    without a plan starts again with the next weight), ``doubt`` on the model's surprise and
    ``prior_weight`` on a policy prior's ``-log pi`` (``prior``: states -> log pi, or None)
    (:func:`~wmthesis.sokoban_search.search.best_first`); ``inputs``
    (:mod:`~wmthesis.sokoban_search.cells`: grid states or pixels) turns what the env shows into
    the model's state, and makes envs that show it. With ``backups``, each search keeps that
    many of the states it expanded (drawn evenly, seeded by the level), labelled with their
    :func:`~wmthesis.sokoban_search.heuristic.backed_up` steps to go (at most ``cap``)."""

    def __init__(self, model, *, inputs=GRID, heuristic=None, budget: int = 20_000,
                 batch: int = 64, weights: tuple = (1.0,), doubt: float = 0.0, replans: int = 4,
                 prior=None, prior_weight: float = 0.0, backups: int = 0, cap: float = 120.0):
        if not weights or min(weights) < 0:
            raise ValueError(f"weights must be one or more non-negative numbers, got {weights!r}")
        if prior_weight < 0:
            raise ValueError(f"prior_weight must be non-negative, got {prior_weight!r}")
        self.model, self.inputs = model, inputs
        self.heuristic, self.budget, self.batch, self.weights, self.replans = heuristic, budget, batch, weights, replans
        self.doubt, self.prior, self.prior_weight = doubt, prior, prior_weight
        self.backups, self.cap = backups, cap

    def env(self, variant: str) -> SokobanEnv:
        """Variant ``variant`` showing what this agent sees."""
        return SokobanEnv(**variant_options(variant), **self.inputs.env_options)

    def play(self, env: SokobanEnv, seed: int | None = None, board=None, on_search=None) -> Play:
        """Play one level: the one ``seed`` generates, or ``board`` (codes or text);
        ``on_search(step, result)``, where given, is told of each search (its last weight's
        :class:`~wmthesis.sokoban_search.search.SearchResult`) with the steps taken before it."""
        start = time.perf_counter()
        observation, _ = env.reset(seed=seed, options=None if board is None else {"board": board})
        state = self.inputs.observe(env, observation)
        rows = {k: [] for k in ("states", "actions", "next_states", "rewards", "dones")}
        taken, expanded, generated, searches, solved, over = [], 0, 0, 0, False, False
        memo = Memo(self.model.expand, self.heuristic)
        model, backed_up = Remembered(memo), []
        heuristic = memo.estimate if self.heuristic is not None else None
        rng = np.random.default_rng([0 if seed is None else seed, 7])
        while not (solved or over) and searches <= self.replans:
            for weight in self.weights:
                result = best_first(model.expand, state, heuristic=heuristic, budget=self.budget,
                                    batch=self.batch, weight=weight, doubt=self.doubt, prior=self.prior,
                                    prior_weight=self.prior_weight, graph=self.backups > 0)
                expanded, generated = expanded + result.expanded, generated + result.generated
                if self.backups:
                    backed_up.append(self._backed_up(result.info["graph"], rng))
                if result.found or result.info["exhausted"] or self.heuristic is None:
                    break  # found; or every weight would search the same (all reachable seen, no value)
            searches += 1
            if on_search is not None:
                on_search(len(taken), result)
            if not result.found:
                break
            for action, predicted in zip(result.actions, result.states[1:]):
                observation, reward, solved, over, _ = env.step(action)
                following = self.inputs.observe(env, observation)
                for key, value in zip(rows, (state, action, following, reward, solved)):
                    rows[key].append(value)
                model.remember(state, action, following, reward, solved)
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
                    transitions, _joined(backed_up, state.shape))

    def _backed_up(self, graph, rng: np.random.Generator) -> dict:
        """``self.backups`` expanded states of one search's graph and their backed-up labels."""
        labels = backed_up(graph, self.cap)
        kept = np.sort(rng.choice(len(labels), size=min(self.backups, len(labels)), replace=False))
        return {"states": graph.states[graph.expanded[kept]], "labels": labels[kept]}


def _joined(parts: list[dict], shape: tuple) -> dict:
    """Rows of several searches as one: ``states`` (n, h, w) uint8, ``labels`` (n,) float32."""
    if not parts:
        return {"states": np.zeros((0, *shape), np.uint8), "labels": np.zeros(0, np.float32)}
    return {k: np.concatenate([p[k] for p in parts]) for k in ("states", "labels")}


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


EVAL_PURPOSE = 1000  # level_seeds' stream of the evaluation levels


def level_seeds(seed: int, purpose: int, n: int) -> list[int]:
    """``n`` level seeds for a ``purpose`` (0: random play, 1 + r: training round r, 1000:
    evaluation), disjoint streams of one experiment seed."""
    return [int(s) for s in derive_seeds(seed, 7_000_000 + purpose, n=n)]


__all__ = ["EVAL_PURPOSE", "SearchAgent", "Remembered", "Memo", "Play", "random_play", "variant_options", "grid_env", "grid_state", "level_seeds"]
