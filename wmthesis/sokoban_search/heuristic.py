"""The search's learned value: the steps still to go from a state to the end of the level.

Learned from the agent's own search results only (expert iteration, as AlphaZero's value head
learns from its self-play): every state along a level the agent solved, labelled with the steps
it then took to finish. No Sokoban knowledge: no distances to targets, no deadlock tables; the
network sees the state's codes and nothing else.

``Heuristic(state (B, h, w) long) -> steps to go (B,)``: a residual convolutional trunk over
``one_hot(state)``, a non-negative contribution per cell, summed over the board (so an estimate
on a larger board adds up its parts, and one network serves every board size).

Symmetries: a board turned or mirrored is as far from its end as the board itself (the game has
no favourite direction), so each training batch may be shown in one of the square's 8
symmetries (:func:`turned`), as AlphaGo Zero showed its Go positions (what they changed:
``docs/findings/sokoban-search.md``).

Dead ends: states along solutions are all states from which the level can still be solved. A
search spends most of its nodes elsewhere, many of them on boards with a box pushed into a corner
off its target, which such a value never saw and may put nearer the end than the level's start
(counted in ``docs/findings/sokoban-search.md``). So the value may also learn from the searches themselves
(:func:`backed_up`): an expanded state is 1 step more than the best of its children, a state the
search did not expand is its estimate; solved by Dijkstra's algorithm over the search's graph.
What a search found below a state (a region that went nowhere) lifts its label, as a search
tree's backed-up values teach a game's evaluation (Veness et al. 2009, "Bootstrapping from game
tree search").
"""
from __future__ import annotations

import numpy as np
import torch
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from torch import nn
from torch.nn import functional as F

from wmthesis.sokoban_search.search import GOAL, UNSEEN
from wmthesis.utils import half_precision


class Heuristic(nn.Module):
    """Steps to go (B,) from states (B, h, w) of ``n_codes`` codes."""

    def __init__(self, n_codes: int, channels: int = 32, blocks: int = 3):
        super().__init__()
        self.n_codes = int(n_codes)
        self.stem = nn.Conv2d(self.n_codes, channels, 3, padding=1)
        self.blocks = nn.ModuleList(nn.Sequential(nn.ReLU(), nn.Conv2d(channels, channels, 3, padding=1),
                                                  nn.ReLU(), nn.Conv2d(channels, channels, 3, padding=1))
                                    for _ in range(blocks))
        self.cell = nn.Conv2d(channels, 1, 1)

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        x = self.stem(F.one_hot(state.long(), self.n_codes).permute(0, 3, 1, 2).float())
        for block in self.blocks:
            x = x + block(x)
        return F.softplus(self.cell(F.relu(x))).sum((1, 2, 3))

    @torch.no_grad()
    def estimate(self, states: np.ndarray) -> np.ndarray:
        """Numpy in and out: uint8 (B, h, w) -> float32 (B,) (in bfloat16 where the hardware
        has it: :func:`~wmthesis.utils.half_precision`)."""
        self.eval()
        dev = self.cell.weight.device
        with half_precision(dev):
            return self(torch.as_tensor(states, device=dev)).float().cpu().numpy()

    def losses(self, batch: dict) -> dict:
        """Huber loss of the estimate against ``batch["to_go"]`` (B,), and its mean absolute error."""
        estimate = self(batch["states"])
        return {"loss": F.smooth_l1_loss(estimate, batch["to_go"]),
                "abs_error": (estimate - batch["to_go"]).abs().mean().detach()}


def backed_up(graph, cap: float) -> np.ndarray:
    """The steps to go of each expanded node of a search's
    :class:`~wmthesis.sokoban_search.search.SearchGraph`, float32 (E,): Bellman's equation over
    the graph, ``v(s) = 1 + min_a v(child(s, a))``, where a child predicted to end the episode
    counts 0, a node not expanded its estimate (so does one whose children the search never looked
    at, having found the end first), and an action not looked at nothing. The least
    solution (every path's cost counted), by Dijkstra's algorithm backwards from the ends and the
    frontier (:func:`scipy.sparse.csgraph.dijkstra`); at most ``cap`` (a region with no way out
    in the graph: infinite)."""
    looked = (graph.children != UNSEEN).any(1)  # a search that ends at a goal stops in mid-batch:
    expanded, seen = graph.expanded[looked], graph.children[looked]  # the nodes after it count as not expanded
    n, (parents, actions) = len(graph.states), np.nonzero(seen != UNSEEN)
    source = n  # one extra node, the ends and the frontier's estimates hang from it
    children = seen[parents, actions]
    frontier = np.setdiff1d(np.arange(n), expanded)
    to_goal = np.unique(expanded[parents[children == GOAL]])
    rows = np.concatenate([children[children >= 0], np.full(len(to_goal) + len(frontier), source)])
    cols = np.concatenate([expanded[parents[children >= 0]], to_goal, frontier])
    weights = np.concatenate([np.ones((children >= 0).sum() + len(to_goal)),
                              np.maximum(graph.estimates[frontier], 1e-6)])  # an explicit 0 is no edge
    order = np.lexsort((weights, cols, rows))  # one edge per pair, the cheapest (CSR would add them up)
    rows, cols, weights = rows[order], cols[order], weights[order]
    first = np.r_[True, (np.diff(rows) != 0) | (np.diff(cols) != 0)]
    edges = csr_matrix((weights[first], (rows[first], cols[first])), shape=(n + 1, n + 1))
    distance = dijkstra(edges, directed=True, indices=source)
    return np.minimum(distance[graph.expanded], cap).astype(np.float32)


def turned(states: torch.Tensor, quarter_turns: int, mirrored: bool) -> torch.Tensor:
    """Boards (B, h, w) turned by ``quarter_turns`` quarter turns, then mirrored about the
    diagonal if ``mirrored``: one of the square's 8 symmetries, (B, h, w) or (B, w, h)."""
    states = torch.rot90(states, quarter_turns, (1, 2))
    return (states.transpose(1, 2) if mirrored else states).contiguous()


def steps_to_go(states: np.ndarray) -> np.ndarray:
    """The labels of one solved episode's states s_0..s_{T-1} (T actions to the end): T - t."""
    return np.arange(len(states), 0, -1, dtype=np.float32)


__all__ = ["Heuristic", "backed_up", "steps_to_go", "turned"]
