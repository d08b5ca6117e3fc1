"""A learned Sokoban model: next board, reward and end of episode from a board and an action.

The thesis's memory (an LSTM over a VAE's latent, 5.3) lost the player in 100% of its +10-step
predictions; it names the cause, too little capacity for Sokoban's combinatorics, and points at
I2A's convolutional model. This is that model, over a *discrete* state: a grid of cells, each one
of K codes (the board's cell types for grid inputs, 5.3.2; a code learned from pixels by
:mod:`~wmthesis.sokoban_search.cells`, 5.3.1). Nothing of the rules is written into it: it is a
plain residual convolutional network, trained on transitions collected in the environment.

Shapes: ``state`` long (B, h, w) codes in [0, K); A actions. The network sees
``one_hot(state)`` (K planes) and returns, for every action at once, the next board's logits
(B, A, K, h, w), the reward's logits (B, A, R) over the rewards seen in the data, and the
end-of-episode logit (B, A). Being convolutional with pooled heads, it runs on any board size.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from wmthesis.utils import device as default_device


class SokobanModel(nn.Module):
    """``forward(state) -> (next_logits (B, A, K, h, w), reward_logits (B, A, R), done_logit (B, A))``:
    the outcome of every action at once (as a Q-network scores every action), so one pass over a
    state expands all its children.

    ``rewards``: the distinct rewards of the training data (the reward head classifies among
    them); a trunk of ``channels`` x ``blocks`` residual 3x3 layers (receptive field
    ``4 * blocks + 3``), then per cell an MLP to the A next codes, and pooled heads for the
    rewards and ends. A learned multiple of the input's one-hot codes is added to the next
    board's logits (a skip connection, as in a residual network: most cells keep their code, so
    the network learns the changes).
    """

    def __init__(self, n_codes: int, n_actions: int, rewards, channels: int = 64, blocks: int = 2):
        super().__init__()
        self.n_codes, self.n_actions = int(n_codes), int(n_actions)
        self.register_buffer("rewards", torch.as_tensor(sorted(set(float(r) for r in rewards)), dtype=torch.float32))
        self.stem = nn.Conv2d(self.n_codes, channels, 3, padding=1)
        self.blocks = nn.ModuleList(nn.Sequential(nn.ReLU(), nn.Conv2d(channels, channels, 3, padding=1),
                                                  nn.ReLU(), nn.Conv2d(channels, channels, 3, padding=1))
                                    for _ in range(blocks))
        self.next_head = nn.Sequential(nn.Conv2d(channels, 2 * channels, 1), nn.ReLU(),
                                       nn.Conv2d(2 * channels, self.n_actions * self.n_codes, 1))
        self.event_head = nn.Sequential(nn.Linear(2 * channels, 2 * channels), nn.ReLU(),
                                        nn.Linear(2 * channels, self.n_actions * (len(self.rewards) + 1)))
        self.copy = nn.Parameter(torch.tensor(3.0))  # a skip connection: the input's code, scaled

    def forward(self, state: torch.Tensor):
        b, h, w = state.shape
        planes = F.one_hot(state.long(), self.n_codes).permute(0, 3, 1, 2).float()
        x = self.stem(planes)
        for block in self.blocks:
            x = x + block(x)
        x = F.relu(x)
        next_logits = self.next_head(x).view(b, self.n_actions, self.n_codes, h, w) + self.copy * planes[:, None]
        events = self.event_head(torch.cat([x.mean((2, 3)), x.amax((2, 3))], 1)).view(b, self.n_actions, -1)
        return next_logits, events[..., :-1], events[..., -1]

    @torch.no_grad()
    def expand(self, states: np.ndarray):
        """Every action's outcome, numpy: states uint8 (B, h, w) -> next states uint8
        (B, A, h, w) (the likeliest code per cell), rewards float32 (B, A), ends bool (B, A), and
        surprises float32 (B, A): -log of the predicted board's probability (the sum over cells of
        -log of the chosen code's probability), the model's doubt about its own prediction."""
        self.eval()
        next_logits, reward_logits, done_logit = self(torch.as_tensor(states, device=self.rewards.device))
        log_p, codes = next_logits.log_softmax(2).max(2)
        return (codes.to(torch.uint8).cpu().numpy(), self.rewards[reward_logits.argmax(2)].cpu().numpy(),
                (done_logit > 0).cpu().numpy(), (-log_p).sum((2, 3)).cpu().numpy())

    def step(self, states: np.ndarray, actions: np.ndarray):
        """One action per state: states uint8 (B, h, w), actions (B,) -> next states (B, h, w),
        rewards (B,), ends (B,)."""
        rows, actions = np.arange(len(states)), np.asarray(actions, dtype=np.int64)
        return tuple(x[rows, actions] for x in self.expand(states)[:3])

    def taken(self, batch: dict):
        """The logits of the actions in ``batch``: next (B, K, h, w), reward (B, R), end (B,)."""
        next_logits, reward_logits, done_logit = self(batch["states"])
        rows, actions = torch.arange(len(batch["actions"])), batch["actions"].long()
        return next_logits[rows, actions], reward_logits[rows, actions], done_logit[rows, actions]

    def losses(self, batch: dict) -> dict:
        """Cross-entropy of the next board (mean over cells), of the reward class and of the
        end of episode; ``board_exact``: the fraction of boards predicted whole (no gradient)."""
        next_logits, reward_logits, done_logit = self.taken(batch)
        cells = F.cross_entropy(next_logits, batch["next_states"].long())
        reward_class = (batch["rewards"][:, None] - self.rewards[None]).abs().argmin(1)  # the nearest seen reward
        reward = F.cross_entropy(reward_logits, reward_class)
        done = F.binary_cross_entropy_with_logits(done_logit, batch["dones"].float())
        exact = (next_logits.argmax(1) == batch["next_states"]).flatten(1).all(1).float().mean()
        return {"loss": cells * 10 + reward + done, "cells": cells, "reward": reward, "done": done,
                "board_exact": exact.detach()}

    def config(self) -> dict:
        return dict(n_codes=self.n_codes, n_actions=self.n_actions, rewards=self.rewards.tolist(),
                    channels=self.stem.out_channels, blocks=len(self.blocks))


def new_model(n_codes: int, n_actions: int, rewards, channels: int = 64, blocks: int = 2, seed: int = 0) -> SokobanModel:
    """A freshly initialised model (weights from ``seed``) on the default device."""
    torch.manual_seed(seed)
    return SokobanModel(n_codes, n_actions, rewards, channels, blocks).to(default_device())


__all__ = ["SokobanModel", "new_model"]
