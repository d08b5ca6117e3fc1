"""Best-first search in a model with discrete states, batched (what MCTS is to one state at a
time, this is to a batch: one model call expands ``batch`` nodes by every action).

The model is any ``expand(states) -> (next_states, rewards, dones, surprises)``: uint8 states
(B, h, w) to every action's outcome, (B, A, h, w), (B, A), (B, A) and the model's doubt about
each predicted board (B, A), ``-log p(board)``: the learned
:class:`~wmthesis.sokoban_search.model.SokobanModel`, or the true rules (:class:`Simulator`, the
upper bound with the same search, never in doubt). States are hashed by their bytes, so
a state reached twice is expanded once; a discrete model makes that possible where a continuous
latent (the thesis's LSTM state) could not.

Priority ``f = g + weight * h``: ``g`` the cost from the root, ``h`` a learned estimate of the
steps still to go (:class:`~wmthesis.sokoban_search.heuristic.Heuristic`); without one, the
search is breadth first. A learned policy prior (:class:`~wmthesis.sokoban_search.policy.Policy`)
may add ``prior_weight * -log pi(a | s)`` to a step's cost. A step costs ``1 + doubt * surprise``: a search left to itself finds
the model's rare mistakes and prefers the ones that help it (a box that vanishes is a box
solved), so a transition the model is unsure of costs more, in proportion to its doubt. The goal
is a transition the model predicts to end the episode.

With ``graph=True`` the search also returns what it saw (:class:`SearchGraph`): the nodes, and
the children of each node it expanded, from which the value learns what the search found below
a state (:func:`~wmthesis.sokoban_search.heuristic.backed_up`).
"""
from __future__ import annotations

import heapq
import itertools
import time
from dataclasses import dataclass, field

import numpy as np

from wmthesis.envs.sokoban import BOX, WALL, apply_action, step_reward

UNKNOWN = 255  # Simulator over codes: a code that stands for no cell type


@dataclass
class SearchResult:
    """``actions``: the plan (None when the budget ran out first); ``states``: the model's
    states along it, uint8 (len(actions) + 1, h, w), the root first; ``expanded`` nodes and
    ``generated`` model transitions; ``seconds``."""

    actions: list[int] | None
    states: np.ndarray | None
    expanded: int
    generated: int
    seconds: float
    info: dict = field(default_factory=dict)

    @property
    def found(self) -> bool:
        return self.actions is not None


GOAL, UNSEEN = -1, -2  # a transition predicted to end the episode; one not looked at


@dataclass
class SearchGraph:
    """What a search saw: ``states`` uint8 (N, h, w), its nodes in the order found (the root
    first); ``expanded`` (E,) the nodes it expanded, in order; ``children`` (E, A) the node each
    action leads to from each of them (:data:`GOAL` for a transition predicted to end the
    episode, :data:`UNSEEN` for one the search stopped before looking at); ``estimates`` (N,)
    the value's steps to go of each node (0 without a value)."""

    states: np.ndarray
    expanded: np.ndarray
    children: np.ndarray
    estimates: np.ndarray


def best_first(expand, root: np.ndarray, *, heuristic=None, budget: int = 20_000, batch: int = 64,
               weight: float = 1.0, doubt: float = 0.0, prior=None, prior_weight: float = 0.0,
               graph: bool = False) -> SearchResult:
    """Search from ``root`` (uint8 (h, w)) for a transition that ``expand`` predicts to end the
    episode, expanding at most ``budget`` nodes, ``batch`` at a time (the lowest ``f`` first,
    first-in first-out on ties). ``heuristic(states (B, h, w)) -> steps to go (B,)``; ``doubt``
    the cost of one nat of the model's surprise; ``prior(states (B, h, w)) -> log pi (B, A)``, a
    policy whose unlikely actions cost ``prior_weight`` per nat of ``-log pi`` more (a policy
    prior orders the expansions, as in Levin tree search). With ``graph``, ``info["graph"]`` is
    the :class:`SearchGraph`."""
    start = time.perf_counter()
    root = np.ascontiguousarray(root, dtype=np.uint8)
    states, parents, actions, cost, estimate = [root], [-1], [-1], [0.0], [0.0]
    index, closed = {root.tobytes(): 0}, set()
    order = itertools.count()
    frontier = [(0.0, next(order), 0)]
    expanded = generated = 0
    seen = ([], []) if graph else None  # the expanded nodes, and their children (A,) each

    def estimated(nodes: list) -> None:  # the value's estimates of new nodes, one call for all
        if nodes and heuristic is not None:
            for i, h in zip(nodes, np.asarray(heuristic(np.stack([states[i] for i in nodes])), dtype=np.float64)):
                estimate[i] = float(h)

    def result(actions=None, path_states=None, **info) -> SearchResult:
        if graph:
            info["graph"] = _graph(states, estimate, *seen)
        return SearchResult(actions, path_states, expanded, generated, time.perf_counter() - start, info)

    while frontier and expanded < budget:
        picked = []
        while frontier and len(picked) < min(batch, budget - expanded):
            f, _, i = heapq.heappop(frontier)
            if i not in closed and f <= cost[i] + weight * estimate[i] + 1e-9:  # else a stale entry
                picked.append(i)
                closed.add(i)
        if not picked:
            break
        expanded += len(picked)
        parents_now = np.stack([states[i] for i in picked])
        children, _, dones, surprises = expand(parents_now)
        generated += dones.size
        unlikely = (-prior_weight * np.asarray(prior(parents_now), dtype=np.float64) if prior is not None and prior_weight
                    else np.zeros(dones.shape))
        fresh, improved = [], set()
        if graph:
            seen[0].extend(picked)
            seen[1].extend(np.full((len(picked), dones.shape[1]), UNSEEN, np.int64))
        for (k, action), child in zip(np.ndindex(dones.shape), children.reshape(-1, *root.shape)):
            parent = picked[k]
            if dones[k, action]:
                if graph:  # the graph's new nodes of this batch get their estimates too
                    seen[1][len(seen[1]) - len(picked) + k][action] = GOAL
                    estimated(fresh)
                plan = _path(parents, actions, parent) + [action]
                path_states = np.stack([states[i] for i in _nodes(parents, parent)] + [child])
                return result(plan, path_states)
            through = (cost[parent] + 1.0 + doubt * float(surprises[k, action])  # the cost of reaching child this way
                       + float(unlikely[k, action]))
            key = child.tobytes()
            if graph:
                seen[1][len(seen[1]) - len(picked) + k][action] = index.get(key, len(states))
            if key not in index:
                index[key] = len(states)
                states.append(child)
                parents.append(parent)
                actions.append(action)
                cost.append(through)
                estimate.append(0.0)
                fresh.append(len(states) - 1)
            elif through < cost[index[key]] - 1e-9 and index[key] not in closed:  # a cheaper way to an open node
                j = index[key]
                parents[j], actions[j], cost[j] = parent, action, through
                improved.add(j)
        estimated(fresh)
        for i in fresh + sorted(improved - set(fresh)):
            heapq.heappush(frontier, (cost[i] + weight * estimate[i], next(order), i))
    return result(exhausted=expanded < budget)  # exhausted: the frontier ran dry first


def _graph(states: list, estimate: list, expanded: list, children: list) -> SearchGraph:
    shape = (len(expanded), children[0].shape[0]) if children else (0, 0)
    return SearchGraph(np.stack(states), np.asarray(expanded, np.int64),
                       np.stack(children) if children else np.zeros(shape, np.int64),
                       np.asarray(estimate, np.float32))


def _nodes(parents: list[int], node: int) -> list[int]:
    """The nodes from the root down to ``node``."""
    path = []
    while node >= 0:
        path.append(node)
        node = parents[node]
    return path[::-1]


def _path(parents: list[int], actions: list[int], node: int) -> list[int]:
    """The actions from the root down to ``node``."""
    return [actions[i] for i in _nodes(parents, node)[1:]]


class Simulator:
    """The true rules with the model's interface, over a board's inner cells (B, h, w) (the
    outer ring, always wall, added and removed around :func:`~wmthesis.envs.sokoban.apply_action`).
    The reference that tells how much of the search's failures are the model's fault.

    ``codes``: (T,) the code of each cell type where the states are a pixel agent's codes
    (:meth:`~wmthesis.sokoban_search.cells.PixelInputs.type_codes`), so that the same value can
    guide it; None: the states are the cell types."""

    n_actions = 8

    def __init__(self, codes: np.ndarray | None = None):
        self.to_codes, self.to_types = None, None
        if codes is not None:
            self.to_codes = np.asarray(codes, np.uint8)
            if len(np.unique(self.to_codes)) < len(self.to_codes):
                raise ValueError(f"cell types share a code ({self.to_codes.tolist()}): no rules can be read from them")
            self.to_types = np.full(256, UNKNOWN, np.uint8)
            self.to_types[self.to_codes] = np.arange(len(self.to_codes))

    def expand(self, states: np.ndarray):
        """Every action's outcome: (B, h, w) -> (B, A, h, w), (B, A), (B, A), and no surprise
        (B, A) zeros."""
        states = np.asarray(states, dtype=np.uint8)
        b, a = len(states), self.n_actions
        children, rewards, dones = self.step(np.repeat(states, a, axis=0), np.tile(np.arange(a), b))
        return (children.reshape(b, a, *states.shape[1:]), rewards.reshape(b, a), dones.reshape(b, a),
                np.zeros((b, a), np.float32))

    def step(self, states: np.ndarray, actions: np.ndarray):
        """One action per state: (B, h, w), (B,) -> (B, h, w), (B,), (B,)."""
        states = np.asarray(states, dtype=np.uint8)
        if self.to_types is not None:
            states = self.to_types[states]
            if (states == UNKNOWN).any():
                raise ValueError("a state holds a code that no cell type renders to")
        b, h, w = states.shape
        boards = np.full((b, h + 2, w + 2), WALL, np.uint8)
        boards[:, 1:-1, 1:-1] = states
        rewards, dones = np.zeros(b, np.float32), np.zeros(b, bool)
        for i in range(b):
            change = apply_action(boards[i], int(actions[i]))
            dones[i] = not np.any(boards[i] == BOX)
            rewards[i] = step_reward(change, dones[i])
        children = boards[:, 1:-1, 1:-1]
        return (children.copy() if self.to_codes is None else self.to_codes[children]), rewards, dones


__all__ = ["best_first", "SearchResult", "SearchGraph", "Simulator", "GOAL", "UNSEEN"]
