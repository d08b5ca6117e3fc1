"""A learned Sokoban model: next board, reward and end of episode from a board and an action.

The thesis's memory (an LSTM over a VAE's latent, 5.3) lost the player in its +10-step
predictions; it names the cause, too little capacity for Sokoban's combinatorics, and points at
I2A's convolutional model. This is that model, over a *discrete* state: a grid of cells, each one
of K codes (the board's cell types for grid inputs, 5.3.2; a code learned from pixels by
:mod:`~wmthesis.sokoban_search.cells`, 5.3.1). Nothing of the rules is written into it: it is a
plain residual convolutional network, trained on transitions collected in the environment.

Shapes: ``state`` long (B, h, w) codes in [0, K); A actions. The network sees
``one_hot(state)`` (K planes) and returns, for every action at once, the next board's logits
(B, A, K, h, w), the reward's logits (B, A, R) over the rewards seen in the data, and the
end-of-episode logit (B, A). Being convolutional with pooled heads, it runs on any board size.

Seen changes. A search finds a model's rare mistakes and follows them: a board with the player
gone is a board the value never saw, and a search can spend much of its budget below such boards
on the levels it fails. So the model also keeps, from the real transitions it
is trained on, every change of the board's code counts it saw (on grid inputs, 7 of them: none
for a step on the floor, a step onto a target, a push, ...), and a prediction whose change is
not among them is not trusted: that move is blocked (the board stays as it was). This is learned
from experience like everything else (no rule says which changes are possible) and serves any
board of discrete codes.

Seen ends. The end-of-episode head looks at the whole board through pooled features, and it
can call an end too early: the search takes the first predicted end for the goal, and the
agent plays a plan whose last push does not end the level (in the cases looked at, it pushed a
box into a corner, where no plan is left). So the
model also keeps which codes the boards at the real ends of episodes show, and an end predicted
on a board that shows a code no end ever showed (on grid inputs: a box off its target, or a
target left open) is not trusted (what seen changes and seen ends solved:
``docs/findings/sokoban-search.md``).
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from wmthesis.utils import device as default_device, half_precision


class SokobanModel(nn.Module):
    """``forward(state) -> (next_logits (B, A, K, h, w), reward_logits (B, A, R), done_logit (B, A))``:
    the outcome of every action at once (as a Q-network scores every action), so one pass over a
    state expands all its children.

    ``rewards``: the distinct rewards of the training data (the reward head classifies among
    them); a trunk of ``channels`` x ``blocks`` residual 3x3 layers (receptive field
    ``4 * blocks + 3``), then per cell an MLP to the A next codes, and pooled heads for the
    rewards and ends. A learned multiple of the input's one-hot codes is added to the next
    board's logits (a skip connection, as in a residual network: most cells keep their code, so
    the network learns the changes). ``changes``: the count changes seen so far, (M, K), and
    ``ends``: which codes the boards at episodes' ends showed, (E, K) of 0/1 (none for a new
    model; :meth:`see_changes` and :meth:`see_ends` add to them; a checkpoint's config carries them).
    """

    def __init__(self, n_codes: int, n_actions: int, rewards, channels: int = 64, blocks: int = 2, changes=(),
                 ends=()):
        super().__init__()
        self.n_codes, self.n_actions = int(n_codes), int(n_actions)
        self.register_buffer("rewards", torch.as_tensor(sorted(set(float(r) for r in rewards)), dtype=torch.float32))
        self.register_buffer("changes", torch.as_tensor(np.asarray(changes, np.int64).reshape(-1, self.n_codes)))
        self.register_buffer("ends", torch.as_tensor(np.asarray(ends, np.int64).reshape(-1, self.n_codes)))
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

    def count_changes(self, states: torch.Tensor, next_states: torch.Tensor) -> torch.Tensor:
        """How many cells of each code a transition adds (removes, if negative): states (..., h, w)
        and next states of the same shape -> (..., K)."""
        counts = lambda x: F.one_hot(x.long(), self.n_codes).sum((-3, -2))  # noqa: E731
        return counts(next_states) - counts(states)

    @torch.no_grad()
    def see_changes(self, states: np.ndarray, next_states: np.ndarray) -> None:
        """Add the count changes of real transitions, uint8 (N, h, w) each, to the seen ones."""
        for i in range(0, len(states), 8192):  # in chunks: the one-hot planes of all would be large
            change = self.count_changes(torch.as_tensor(states[i:i + 8192]), torch.as_tensor(next_states[i:i + 8192]))
            self.changes = torch.unique(torch.cat([self.changes, change.to(self.changes)]), dim=0)

    def shown(self, boards: torch.Tensor) -> torch.Tensor:
        """Which codes boards (..., h, w) show: (..., K) of 0/1."""
        return (F.one_hot(boards.long(), self.n_codes).sum((-3, -2)) > 0).long()

    @torch.no_grad()
    def see_ends(self, boards: np.ndarray) -> None:
        """Add the codes shown by boards at the real ends of episodes, uint8 (N, h, w), to the seen ones."""
        for i in range(0, len(boards), 8192):
            shown = self.shown(torch.as_tensor(boards[i:i + 8192]))
            self.ends = torch.unique(torch.cat([self.ends, shown.to(self.ends)]), dim=0)

    @torch.no_grad()
    def expand(self, states: np.ndarray):
        """Every action's outcome, numpy: states uint8 (B, h, w) -> next states uint8
        (B, A, h, w) (the likeliest code per cell; the state itself where the prediction's count
        change was never seen), rewards float32 (B, A), ends bool (B, A) (false on a board that
        shows a code no end showed), and surprises float32
        (B, A): -log of the predicted board's probability (the sum over cells of -log of the
        chosen code's probability), the model's doubt about its own prediction. In bfloat16
        where the hardware has it (:func:`~wmthesis.utils.half_precision`)."""
        self.eval()
        states = torch.as_tensor(states, device=self.rewards.device)
        with half_precision(states.device):
            next_logits, reward_logits, done_logit = self(states)
        log_p, codes = next_logits.float().log_softmax(2).max(2)
        codes, surprise, done = codes.to(torch.uint8), (-log_p).sum((2, 3)), done_logit > 0
        if len(self.changes):
            change = self.count_changes(states[:, None], codes)  # (B, A, K)
            seen = (change[:, :, None] == self.changes).all(-1).any(-1)  # (B, A)
            codes = torch.where(seen[..., None, None], codes, states[:, None])
            surprise, done = torch.where(seen, surprise, 0.0), done & seen
        if len(self.ends):  # no code on the board that no end ever showed
            done = done & (self.shown(codes) <= self.ends.amax(0)).all(-1)
        return (codes.cpu().numpy(), self.rewards[reward_logits.argmax(2)].cpu().numpy(), done.cpu().numpy(),
                surprise.cpu().numpy())

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
                    channels=self.stem.out_channels, blocks=len(self.blocks), changes=self.changes.tolist(),
                    ends=self.ends.tolist())


def new_model(n_codes: int, n_actions: int, rewards, channels: int = 64, blocks: int = 2, seed: int = 0) -> SokobanModel:
    """A freshly initialised model (weights from ``seed``) on the default device."""
    torch.manual_seed(seed)
    return SokobanModel(n_codes, n_actions, rewards, channels, blocks).to(default_device())


__all__ = ["SokobanModel", "new_model"]
