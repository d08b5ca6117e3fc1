"""AlphaZero Monte-Carlo tree search in a learned model (thesis 4.3.2, Fig. 45).

The planner sees the model only through the :class:`~wmthesis.core.MDP` protocol
(``transition(state, action) -> (next_state, reward)``, ``is_terminal(state)``) and an
*evaluator* ``evaluator(state) -> (priors, value)``: the policy and value heads, priors a 1-D
array-like over the A actions (need not be normalised), value a float.

Every edge (s, a) of the tree stores a prior P, a visit count N, an action value Q and the
reward R of its transition. Nodes are plain Python objects, one per expanded state (states
are never hashed); a node holds its edges as arrays of shape (A,) and its children, created
lazily. One *simulation*:

1. **select**: from the root, follow ``argmax_a Q(s, a) + U(s, a)`` with the PUCT bonus
   ``U = c * P * sqrt(max(N(s), 1)) / (1 + N(s, a))``, N(s) the node's total visits, until an
   edge that was never taken or a terminal node. The ``max(., 1)`` lets the first visit of a
   node follow its priors (the author's ``sqrt(N(s))`` makes every bonus 0 then, so the first
   pick was always action 0). Unvisited edges have Q = 0. Ties go to the lowest action index.
2. **expand**: the model's ``transition`` gives the edge's next state and reward R; the
   evaluator gives the new node's priors and the leaf value V. A terminal state is worth 0 and
   is not expanded; reaching a terminal node again also backs up 0.
3. **backup**: along the path, edge k's return is ``G_k = R_k + gamma * G_{k+1}`` with
   ``G = V(leaf)`` innermost, and Q is the running mean of those returns, i.e.
   ``Q(s_t, a_t) = 1/N sum [ sum_{i=t+1}^{t'} gamma^(i-t-1) r_i + gamma^(t'-t) V(s_t') ]``.

The search stops after ``n_simulations`` or ``timeout`` seconds, whichever comes first (at
least one simulation runs; the clock includes evaluating a fresh root). Its scores are the
root's visit counts N(root, .), so the ``proportional`` and ``deterministic`` policies of
:func:`~wmthesis.core.loop` turn them into the thesis's action choice.

Options beyond the thesis: ``normalize_q`` (MuZero) scores ``(Q - min) / (max - min)`` with
min and max over every Q backed up since the tree was started (0 while fewer than two
distinct values were seen; an unvisited edge scores the node's mean Q), so unbounded rewards such as Atari's do
not drown the prior bonus. Tree reuse (the author's ``query_tree``): :meth:`MCTS.advance` keeps
the subtree below the action taken, and the next :meth:`MCTS.plan` continues it with the
root's model-predicted state replaced by the real one; its statistics are kept.

Speed: selection is one numpy expression over the A edges, and leaves are not batched: the
model's transition and the evaluator take most of a simulation (``benchmarks/bench_mcts.py``;
the measurements are in ``docs/findings/boxing-wm-alphazero.md``).
"""
from __future__ import annotations

import math
import time
from typing import Any, Callable

import numpy as np

from wmthesis.core import MDP, Callback, Mind, Transition

Evaluator = Callable[[Any], tuple[Any, float]]


class Node:
    """A state in the tree and its A outgoing edges.

    ``P``, ``N``, ``Q``, ``R``: float64 arrays (A,) of priors, visits, mean discounted
    returns and transition rewards; ``children[a]``: the node behind edge a, None until
    expanded; ``visits``: N(s) = sum of ``N``. A terminal node has no edges (``P`` is None).
    """

    __slots__ = ("state", "terminal", "P", "N", "Q", "R", "children", "visits", "value")

    def __init__(self, state, priors: np.ndarray | None, value: float = 0.0):
        self.state = state
        self.value = value  # the evaluator's value of the state (0 if terminal)
        self.terminal = priors is None
        self.P = priors
        self.visits = 0
        if priors is not None:
            n_actions = len(priors)
            self.N, self.Q, self.R = np.zeros(n_actions), np.zeros(n_actions), np.zeros(n_actions)
            self.children: list[Node | None] = [None] * n_actions


class MCTS(Mind, Callback):
    """AlphaZero planner: ``plan(state)`` returns the root visit counts, float64 (A,).

    ``mdp`` is the model (:class:`~wmthesis.core.MDP`, ``action_space`` Discrete(A));
    ``evaluator(state) -> (priors, value)``. Author's values: ``c=1``, 50 simulations,
    Dirichlet noise 0.3 mixed in at ratio 0.25 on the root priors (``train_mode`` only, drawn
    from the ``seed``-ed generator), ``gamma=0.99``. Beyond the thesis: ``max_depth`` caps how
    many edges below the root the tree grows (None: no cap; :meth:`_simulate`); ``root_actions``
    = k lets the root choose only among its k most probable actions (after noise; None: all of
    them), as Gumbel MuZero's root considers only its top-k sampled actions: more simulations
    then estimate those k actions better instead of finding an unlikely action whose learned value
    or reward the model gets wrong (the optimiser's curse; ``docs/findings/planning-budget.md``).

    As a callback it forgets the tree when an episode starts and follows the action taken
    after each step (:meth:`advance`); register it in ``loop(..., callbacks=[mcts])`` to reuse
    subtrees. A tree is reused only by the first ``plan`` after an ``advance``, so a planner
    that is not registered never plans on stale statistics.
    """

    def __init__(self, mdp: MDP, evaluator: Evaluator, *, c: float = 1.0, n_simulations: int = 50,
                 timeout: float | None = None, gamma: float = 0.99, dirichlet_alpha: float = 0.3,
                 noise_ratio: float = 0.25, normalize_q: bool = False, reuse_tree: bool = True,
                 max_depth: int | None = None, root_actions: int | None = None,
                 seed: int | np.random.SeedSequence | None = None):
        _check_options(c, n_simulations, timeout, gamma, dirichlet_alpha, noise_ratio)
        for name, value in (("max_depth", max_depth), ("root_actions", root_actions)):
            if value is not None and value < 1:
                raise ValueError(f"{name} must be >= 1 or None, got {value}")
        self.max_depth, self.root_actions = max_depth, root_actions
        self.mdp, self.evaluator = mdp, evaluator
        self.n_actions = int(mdp.action_space.n)
        self.c, self.n_simulations, self.timeout, self.gamma = c, int(n_simulations), timeout, gamma
        self.dirichlet_alpha, self.noise_ratio = dirichlet_alpha, noise_ratio
        self.normalize_q, self.reuse_tree = normalize_q, reuse_tree
        self.rng = np.random.default_rng(seed)
        self.root: Node | None = None  # the last search's root, or the subtree kept by advance
        self._advanced = False
        self._q_min, self._q_max = math.inf, -math.inf

    # ------------------------------------------------------------------ search
    def plan(self, state, train_mode: bool = True, debug_mode: bool = False):
        """Search from ``state``; return the root visit counts (A,), or ``(counts, info)``.

        ``info`` (``debug_mode``): ``root_value`` (visit-weighted mean of the root Q: the
        search's value estimate), ``q`` (A,) root Q (nan where unvisited), ``priors`` (A,)
        root priors after noise, ``simulations``, ``max_depth`` (edges on the longest path),
        ``seconds`` and ``reused`` (whether a subtree kept by :meth:`advance` was continued).
        """
        start = time.perf_counter()
        deadline = math.inf if self.timeout is None else start + self.timeout
        root, reused = self._query_tree(state)
        if train_mode and not root.terminal and self.noise_ratio > 0:
            noise = self.rng.dirichlet(np.full(self.n_actions, self.dirichlet_alpha))
            root.P = (1 - self.noise_ratio) * root.P + self.noise_ratio * noise
        allowed = None if root.terminal or self.root_actions is None else most_probable(root.P, self.root_actions)
        simulations, deepest = 0, 0
        while True:
            path, value = self._simulate(root, allowed)
            self._backup(path, value)
            simulations, deepest = simulations + 1, max(deepest, len(path))
            if simulations >= self.n_simulations or time.perf_counter() >= deadline:
                break
        counts = np.zeros(self.n_actions) if root.terminal else root.N * (1.0 if allowed is None else allowed)
        if not debug_mode:
            return counts
        return counts, self._info(root, simulations, deepest, time.perf_counter() - start, reused)

    def _query_tree(self, state) -> tuple[Node, bool]:
        """The root for ``state``: the subtree kept by :meth:`advance` with its state replaced
        by ``state``, or a fresh node evaluated by the evaluator."""
        kept, advanced = self.root, self._advanced
        self._advanced = False
        if advanced and kept is not None:
            kept.state = state
            return kept, True
        self._q_min, self._q_max = math.inf, -math.inf
        self.root, _ = self._new_node(state)
        return self.root, False

    def _simulate(self, root: Node, allowed: np.ndarray | None = None) -> tuple[list[tuple[Node, int]], float]:
        """Select edges from ``root`` down to a leaf and expand it; at the root only the
        ``allowed`` actions (bool (A,); None: all).

        Returns the path as (node, action) pairs and the leaf's value V (0 if terminal). With
        ``max_depth``, a node that many edges below the root is a leaf for good: its value is
        backed up again and it is never expanded (more simulations widen the tree near the root
        instead of deepening it into states the model has not learned).
        """
        node, path = root, []
        while not node.terminal:
            if self.max_depth is not None and len(path) >= self.max_depth:
                return path, node.value
            action = self._select(node, allowed if node is root else None)
            path.append((node, action))
            child = node.children[action]
            if child is None:
                return path, self._expand(node, action)
            node = child
        return path, 0.0

    def _select(self, node: Node, allowed: np.ndarray | None = None) -> int:
        """``argmax_a Q + c * P * sqrt(max(N(s), 1)) / (1 + N)`` over the ``allowed`` actions (bool
        (A,); None: all), the lowest index on ties."""
        q = self._normalized(node.Q, node.N) if self.normalize_q else node.Q
        u = (self.c * math.sqrt(max(node.visits, 1))) * node.P / (1.0 + node.N)
        score = q + u if allowed is None else np.where(allowed, q + u, -np.inf)
        return int(score.argmax())

    def _expand(self, node: Node, action: int) -> float:
        """Take edge (node, action) in the model, attach the new node; return its value."""
        next_state, reward = self.mdp.transition(node.state, action)
        node.R[action] = float(reward)
        node.children[action], value = self._new_node(next_state)
        return value

    def _new_node(self, state) -> tuple[Node, float]:
        """A node for ``state`` with the evaluator's priors, and its value (0 if terminal)."""
        if self.mdp.is_terminal(state):
            return Node(state, None), 0.0
        priors, value = self.evaluator(state)
        return Node(state, self._normalized_priors(priors), float(value)), float(value)

    def _backup(self, path: list[tuple[Node, int]], value: float) -> None:
        """``G_k = R_k + gamma * G_{k+1}`` from the leaf up; Q += (G - Q) / N on each edge."""
        g = value
        for node, action in reversed(path):
            g = node.R[action] + self.gamma * g
            n = node.N[action] + 1.0
            node.N[action] = n
            node.Q[action] += (g - node.Q[action]) / n
            node.visits += 1
            if self.normalize_q:
                q = node.Q[action]
                self._q_min, self._q_max = min(self._q_min, q), max(self._q_max, q)

    # ------------------------------------------------------------------ helpers
    def _normalized(self, q: np.ndarray, n: np.ndarray) -> np.ndarray:
        """Min-max normalised Q in [0, 1] (MuZero); 0 on a flat tree. An unvisited edge gets
        the node's value (the visit-weighted mean of its Q; as mctx does), not 0: with 0 an
        untried action looks like the worst one and the search dives after two actions."""
        span = self._q_max - self._q_min
        if not span > 0:
            return np.zeros_like(q)
        visits = n.sum()
        value = n @ q / visits if visits > 0 else self._q_min
        return (np.where(n > 0, q, value) - self._q_min) / span

    def _normalized_priors(self, priors) -> np.ndarray:
        """Priors (A,) summing to 1; uniform when they sum to 0 or a non-finite number."""
        p = np.asarray(priors, dtype=np.float64).reshape(-1)
        if p.shape != (self.n_actions,):
            raise ValueError(f"evaluator priors have {p.size} entries, the MDP has {self.n_actions} actions")
        if p.min() < 0:
            raise ValueError("evaluator priors must be non-negative (probabilities, not logits)")
        total = p.sum()
        if not (total > 0 and math.isfinite(total)):
            return np.full(self.n_actions, 1.0 / self.n_actions)
        return p / total

    def _info(self, root: Node, simulations: int, max_depth: int, seconds: float, reused: bool) -> dict:
        if root.terminal:
            q, priors, root_value = np.full(self.n_actions, np.nan), np.zeros(self.n_actions), 0.0
        else:
            q = np.where(root.N > 0, root.Q, np.nan)
            priors, root_value = root.P.copy(), float(root.N @ root.Q / root.N.sum())
        return dict(root_value=root_value, q=q, priors=priors, simulations=simulations,
                    max_depth=max_depth, seconds=seconds, reused=reused)

    # ------------------------------------------------------------------ tree reuse
    def advance(self, action: int) -> None:
        """Make the child behind ``action`` the root kept for the next :meth:`plan`.

        Without ``reuse_tree``, or if that edge was never expanded, the next plan starts a
        fresh tree.
        """
        root = self.root
        child = root.children[action] if root is not None and not root.terminal else None
        self.root = child if self.reuse_tree and child is not None and not child.terminal else None
        self._advanced = self.root is not None

    def reset(self) -> None:
        """Forget the tree."""
        self.root, self._advanced = None, False

    def on_episode_start(self, episode: int, train_mode: bool) -> None:
        self.reset()

    def on_step_taken(self, step: int, transition: Transition, info: dict) -> None:
        self.advance(transition.action)


def most_probable(priors: np.ndarray, k: int) -> np.ndarray:
    """Bool (A,): True on the ``k`` largest ``priors`` (A,), the lower index first among equals."""
    allowed = np.zeros(len(priors), bool)
    allowed[np.argsort(-priors, kind="stable")[:k]] = True
    return allowed


def _check_options(c, n_simulations, timeout, gamma, dirichlet_alpha, noise_ratio) -> None:
    if c < 0:
        raise ValueError(f"c must be >= 0, got {c}")
    if n_simulations < 1:
        raise ValueError(f"n_simulations must be >= 1, got {n_simulations}")
    if timeout is not None and not timeout > 0:
        raise ValueError(f"timeout must be positive or None, got {timeout}")
    if not 0 <= gamma <= 1:
        raise ValueError(f"gamma must be in [0, 1], got {gamma}")
    if not dirichlet_alpha > 0:
        raise ValueError(f"dirichlet_alpha must be positive, got {dirichlet_alpha}")
    if not 0 <= noise_ratio <= 1:
        raise ValueError(f"noise_ratio must be in [0, 1], got {noise_ratio}")


__all__ = ["MCTS", "Node", "Evaluator", "most_probable"]
