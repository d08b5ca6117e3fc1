"""Gumbel MuZero's root for the search in the memory (Danihelka et al., ICLR 2022; as
``google-deepmind/mctx``'s ``gumbel_muzero_policy``), beside the thesis's PUCT root (4.3.2).

The root samples the actions it considers without replacement (Gumbel-top-k: the k largest
``g + logits``, ``g`` Gumbel noise), splits the simulations among them by sequential halving
(each round visits every remaining action equally, then keeps the better half by
``g + logits + sigma(completed Q)``), and acts on the survivor. Below the root, selection is
deterministic: the action whose visits lag furthest behind the improved policy
``softmax(logits + sigma(completed Q))``, which is also the policy a network learns from. Because
the action returned maximises ``g + logits + sigma(q)`` over a Gumbel-top-k sample, it is at least
as good as the prior's action in expectation at any budget, even 2 simulations.

    sigma(q) = (c_visit + max_b N(b)) * c_scale * q           (q rescaled to [0, 1] over the node)
    completed Q(a) = Q(a) where N(a) > 0, else the mixed value
    mixed value = (V + sum_b N(b) * sum_{b visited} pi(b) Q(b) / sum_{b visited} pi(b)) / (1 + sum_b N(b))

Small functions over a node's arrays (A,), each as mctx writes it; :class:`GumbelMCTS` runs them
on :class:`~wmthesis.alphazero.mcts.MCTS`'s tree.
"""
from __future__ import annotations

import math
import time

import numpy as np

from wmthesis.alphazero.config import ROOTS
from wmthesis.alphazero.mcts import MCTS, Node

LOW_LOGIT = -1e9


def gumbel_top_k(logits: np.ndarray, k: int, gumbel: np.ndarray) -> np.ndarray:
    """The ``k`` actions with the largest ``gumbel + logits`` (A,), best first: a sample without
    replacement from ``softmax(logits)``."""
    return np.argsort(-(gumbel + logits), kind="stable")[:k]


def considered_visits(k: int, simulations: int) -> tuple[int, ...]:
    """Sequential halving's schedule: at simulation i, the visits that a considered action must
    have to be visited next (mctx's ``get_sequence_of_considered_visits``). Each round gives every
    one of the ``m`` remaining actions ``max(1, n / (ceil(log2 k) * m))`` visits, then halves m
    (to at least 2)."""
    if k <= 1:
        return tuple(range(simulations))
    rounds = math.ceil(math.log2(k))
    sequence, visits, considered = [], [0] * k, k
    while len(sequence) < simulations:
        for _ in range(max(1, int(simulations / (rounds * considered)))):
            sequence.extend(visits[:considered])
            visits[:considered] = [v + 1 for v in visits[:considered]]
        considered = max(2, considered // 2)
    return tuple(sequence[:simulations])


def mixed_value(value: float, q: np.ndarray, visits: np.ndarray, priors: np.ndarray) -> float:
    """The node's value estimate for unvisited actions: its own ``value`` mixed with the
    prior-weighted mean Q of the visited actions, in proportion to the visits."""
    total = visits.sum()
    seen = visits > 0
    if total == 0:
        return float(value)
    p = np.maximum(priors, np.finfo(np.float64).tiny)
    weighted = float((p[seen] * q[seen]).sum() / p[seen].sum())
    return float((value + total * weighted) / (total + 1))


def completed_q(value: float, q: np.ndarray, visits: np.ndarray, priors: np.ndarray) -> np.ndarray:
    """Q where visited, the :func:`mixed_value` elsewhere: (A,)."""
    return np.where(visits > 0, q, mixed_value(value, q, visits, priors))


def sigma(completed: np.ndarray, visits: np.ndarray, c_visit: float = 50.0, c_scale: float = 0.1,
          epsilon: float = 1e-8) -> np.ndarray:
    """The monotone transform of completed Q (A,): rescaled to [0, 1] over the node, times
    ``(c_visit + max N) * c_scale`` (mctx's ``qtransform_completed_by_mix_value``)."""
    low, high = completed.min(), completed.max()
    rescaled = (completed - low) / max(high - low, epsilon)
    return (c_visit + visits.max()) * c_scale * rescaled


def improved_policy(logits: np.ndarray, transformed_q: np.ndarray) -> np.ndarray:
    """``softmax(logits + sigma(completed Q))``: the policy target, (A,)."""
    x = logits + transformed_q
    e = np.exp(x - x.max())
    return e / e.sum()


def considered_scores(considered_visit: int, gumbel: np.ndarray, logits: np.ndarray, transformed_q: np.ndarray,
                      visits: np.ndarray) -> np.ndarray:
    """``g + logits + sigma(q)`` (floored at :data:`LOW_LOGIT`) where an action has exactly
    ``considered_visit`` visits, -inf elsewhere: the root's argmax (mctx's ``score_considered``)."""
    penalty = np.where(visits == considered_visit, 0.0, -np.inf)
    return np.maximum(LOW_LOGIT, gumbel + (logits - logits.max()) + transformed_q) + penalty


def interior_action(logits: np.ndarray, transformed_q: np.ndarray, visits: np.ndarray) -> int:
    """Below the root: the action whose visit share lags the improved policy most."""
    return int((improved_policy(logits, transformed_q) - visits / (1 + visits.sum())).argmax())


def logits_of(priors: np.ndarray) -> np.ndarray:
    """Log-priors (A,), an action of prior 0 at :data:`LOW_LOGIT`."""
    with np.errstate(divide="ignore"):
        return np.maximum(np.log(priors), LOW_LOGIT)


class GumbelMCTS(MCTS):
    """:class:`~wmthesis.alphazero.mcts.MCTS` with Gumbel MuZero's root (module docstring):
    ``considered`` actions (k, at most A), ``gumbel_scale`` on the noise (0: Gumbel-free top-k by
    the prior), ``c_visit`` and ``c_scale`` of sigma. :meth:`plan` returns scores whose argmax is
    the action the search chose; ``info["improved_policy"]`` is the policy target. No Dirichlet
    noise and no tree reuse (the Gumbel noise explores)."""

    def __init__(self, mdp, evaluator, *, considered: int = 16, gumbel_scale: float = 1.0, c_visit: float = 50.0,
                 c_scale: float = 0.1, **options):
        options.update(reuse_tree=False, noise_ratio=0.0)
        super().__init__(mdp, evaluator, **options)
        if isinstance(considered, bool) or not isinstance(considered, int) or not 1 <= considered <= self.n_actions:
            raise ValueError(f"considered must be an integer in [1, {self.n_actions}], got {considered!r}")
        if self.n_simulations < 2:
            raise ValueError(f"a Gumbel root needs at least 2 simulations, got {self.n_simulations}")
        self.considered, self.gumbel_scale, self.c_visit, self.c_scale = considered, gumbel_scale, c_visit, c_scale

    def transformed(self, node: Node) -> np.ndarray:
        return sigma(completed_q(node.value, node.Q, node.N, node.P), node.N, self.c_visit, self.c_scale)

    def plan(self, state, train_mode: bool = True, debug_mode: bool = False):
        start = time.perf_counter()
        root, reused = self._query_tree(state)
        if root.terminal:
            scores = np.zeros(self.n_actions)
            return (scores, self._info(root, 0, 0, time.perf_counter() - start, reused)) if debug_mode else scores
        logits = logits_of(root.P)
        gumbel = self.gumbel_scale * self.rng.gumbel(size=self.n_actions)
        schedule = considered_visits(self.considered, self.n_simulations)
        deadline = math.inf if self.timeout is None else start + self.timeout
        simulations, deepest = 0, 0
        for considered_visit in schedule:
            action = int(considered_scores(considered_visit, gumbel, logits, self.transformed(root), root.N).argmax())
            path, value = self._simulate(root, np.arange(self.n_actions) == action)
            self._backup(path, value)
            simulations, deepest = simulations + 1, max(deepest, len(path))
            if time.perf_counter() >= deadline:
                break
        transformed = self.transformed(root)
        scores = considered_scores(int(root.N.max()), gumbel, logits, transformed, root.N)
        scores = np.where(np.isfinite(scores), scores, 2 * LOW_LOGIT)
        if not debug_mode:
            return scores
        info = self._info(root, simulations, deepest, time.perf_counter() - start, reused)
        info.update(improved_policy=improved_policy(logits, transformed), visits=root.N.copy())
        return scores, info

    def _select(self, node: Node, allowed: np.ndarray | None = None) -> int:
        if allowed is not None:  # the root's action, chosen by sequential halving
            return int(allowed.argmax())
        return interior_action(logits_of(node.P), self.transformed(node), node.N)


def root_search(config, mdp, evaluator, seed) -> MCTS:
    """The search of an :class:`~wmthesis.alphazero.config.AlphaZeroConfig`: the thesis's PUCT root,
    or Gumbel MuZero's where ``config.root == "gumbel"``."""
    root = config.root or "puct"
    if root not in ROOTS:
        raise ValueError(f"unknown root {root!r}; valid: {', '.join(ROOTS)}")
    options = dict(c=config.c, n_simulations=config.simulations, timeout=config.timeout, gamma=config.gamma,
                   dirichlet_alpha=config.dirichlet_alpha, max_depth=config.search_depth, seed=seed)
    if root == "gumbel":
        actions = int(mdp.action_space.n)
        if config.considered is not None and config.considered > actions:
            raise ValueError(f"a Gumbel root considers at most the game's {actions} actions, got {config.considered}")
        considered = config.considered or min(16, actions)
        return GumbelMCTS(mdp, evaluator, considered=considered, gumbel_scale=config.gumbel_scale,
                          c_scale=config.c_scale, c_visit=config.c_visit, **options)
    return MCTS(mdp, evaluator, noise_ratio=config.noise_ratio, normalize_q=config.normalize_q,
                reuse_tree=config.reuse_tree, root_actions=config.root_actions, **options)


__all__ = ["ROOTS", "root_search", "GumbelMCTS", "gumbel_top_k", "considered_visits", "mixed_value", "completed_q", "sigma",
           "improved_policy", "considered_scores", "interior_action", "logits_of"]
