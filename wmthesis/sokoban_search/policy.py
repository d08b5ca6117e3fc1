"""The search's learned policy prior: which action the agent's own solutions took from a state.

Learned from the agent's own search results only, as the value is
(:mod:`~wmthesis.sokoban_search.heuristic`): every state along a level the agent solved,
labelled with the action it then played. No Sokoban knowledge: the network sees the state's
codes and nothing else, not even where the player stands.

It orders the search's expansions as a policy orders Levin tree search and PHS* (Orseau et
al. 2018; Orseau & Lelis 2021): a step costs ``prior_weight * -log pi(a | s)`` more
(:func:`~wmthesis.sokoban_search.search.best_first`), so the actions the agent's solutions take
are tried first and the rest later, not never.

``Policy(state (B, h, w) long) -> log pi (B, A)``: a residual convolutional trunk over
``one_hot(state)``, action logits at every cell, the largest over the board (so one network
serves every board size, and the cell that decides, the player's, can speak for the board).

Symmetries: a board turned or mirrored is solved by the actions turned or mirrored alike
(:func:`turned_actions`), so each training batch may be shown in one of the square's 8
symmetries, states and actions together.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from wmthesis.envs.sokoban import MOVES
from wmthesis.utils import half_precision


class Policy(nn.Module):
    """Log-probabilities (B, A) of ``n_actions`` actions from states (B, h, w) of ``n_codes`` codes."""

    def __init__(self, n_codes: int, n_actions: int = 8, channels: int = 32, blocks: int = 2):
        super().__init__()
        self.n_codes, self.n_actions = int(n_codes), int(n_actions)
        self.stem = nn.Conv2d(self.n_codes, channels, 3, padding=1)
        self.blocks = nn.ModuleList(nn.Sequential(nn.ReLU(), nn.Conv2d(channels, channels, 3, padding=1),
                                                  nn.ReLU(), nn.Conv2d(channels, channels, 3, padding=1))
                                    for _ in range(blocks))
        self.head = nn.Conv2d(channels, self.n_actions, 1)

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        x = self.stem(F.one_hot(state.long(), self.n_codes).permute(0, 3, 1, 2).float())
        for block in self.blocks:
            x = x + block(x)
        return F.log_softmax(self.head(F.relu(x)).amax((2, 3)).float(), -1)  # normalised in float32 under bfloat16

    @torch.no_grad()
    def log_probs(self, states: np.ndarray) -> np.ndarray:
        """Numpy in and out: uint8 (B, h, w) -> float32 (B, A)."""
        self.eval()
        dev = self.head.weight.device
        with half_precision(dev):
            return self(torch.as_tensor(states, device=dev)).float().cpu().numpy()

    def losses(self, batch: dict) -> dict:
        """Cross-entropy of ``batch["actions"]`` (B,) under the policy, and how often its most
        likely action is the one taken."""
        log_probs = self(batch["states"])
        actions = batch["actions"].long()
        return {"loss": F.nll_loss(log_probs, actions),
                "accuracy": (log_probs.argmax(-1) == actions).float().mean().detach()}


def turned_actions(actions: torch.Tensor, quarter_turns: int, mirrored: bool) -> torch.Tensor:
    """The actions (B,) that do on a board turned as :func:`~wmthesis.sokoban_search.heuristic.turned`
    turns it what ``actions`` do on the board itself: each direction (``MOVES``, the action
    modulo 4) turned ``quarter_turns`` times counter-clockwise, then mirrored about the
    diagonal; pushes stay pushes and moves moves."""
    table = []
    for dr, dc in MOVES:
        for _ in range(quarter_turns % 4):
            dr, dc = -dc, dr  # torch.rot90 over (rows, columns): cell (r, c) -> (w - 1 - c, r)
        if mirrored:
            dr, dc = dc, dr
        table.append(MOVES.index((dr, dc)))
    table = torch.as_tensor(table, device=actions.device)
    actions = actions.long()
    return (actions // 4) * 4 + table[actions % 4]


__all__ = ["Policy", "turned_actions"]
