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
symmetries (:func:`turned`), as AlphaGo Zero showed its Go positions. On the solved levels of a
quick run (seed 0, 20,941 labelled states, 1,500 updates), the value trained with them solved
135, 141 and 138 of 150 unseen 10x10 levels with the true rules (budget 20,000, three seeds)
expanding 3,800 nodes a level; without, 137, 133 and 136, expanding 4,700.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

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


def turned(states: torch.Tensor, quarter_turns: int, mirrored: bool) -> torch.Tensor:
    """Boards (B, h, w) turned by ``quarter_turns`` quarter turns, then mirrored about the
    diagonal if ``mirrored``: one of the square's 8 symmetries, (B, h, w) or (B, w, h)."""
    states = torch.rot90(states, quarter_turns, (1, 2))
    return (states.transpose(1, 2) if mirrored else states).contiguous()


def steps_to_go(states: np.ndarray) -> np.ndarray:
    """The labels of one solved episode's states s_0..s_{T-1} (T actions to the end): T - t."""
    return np.arange(len(states), 0, -1, dtype=np.float32)


__all__ = ["Heuristic", "steps_to_go", "turned"]
