"""How right the learned model is, on transitions of levels no part of training saw.

Every measure stands beside the "nothing moves" baseline (the next state is the current one),
which a model that learned nothing but to copy its input would match:

- one-step whole-board exactness, reward accuracy (on every transition and on the rare ones
  whose reward is not the commonest), end-of-episode accuracy;
- open-loop exactness after k steps: the model fed its own predictions along a real action
  sequence (the planner's), compared with the real state k steps on;
- how often a prediction has no player, or fewer boxes than the real state ("vanishing").
"""
from __future__ import annotations

import numpy as np

from wmthesis.envs.sokoban import BOX, BOX_ON_TARGET, PLAYER, PLAYER_ON_TARGET


def one_step(model, rows: dict, to_types=None) -> dict:
    """Measures of ``model.step`` on transitions ``rows`` (arrays of
    :class:`~wmthesis.sokoban_search.experience.Experience`), and of the baseline.
    ``to_types``: maps model states to board codes for the vanishing counts (a pixel model's
    codes, :func:`~wmthesis.sokoban_search.cells.code_table`); None: they are board codes."""
    predicted, rewards, dones = model.step(rows["states"], rows["actions"])
    truth = rows["next_states"]
    values, counts = np.unique(rows["rewards"], return_counts=True)
    events = rows["rewards"] != values[counts.argmax()]
    right_reward = np.abs(rewards - rows["rewards"]) < 1e-4
    return {"transitions": int(len(truth)),
            "exact": _exact(predicted, truth), "exact_nothing_moves": _exact(rows["states"], truth),
            "reward_accuracy": float(right_reward.mean()),
            "event_reward_accuracy": float(right_reward[events].mean()) if events.any() else None,
            "end_accuracy": float((dones == rows["dones"]).mean()),
            **_vanishing(predicted, truth, to_types)}


def open_loop(model, trajectories: list[tuple[np.ndarray, np.ndarray]], horizons=(10, 30), to_types=None) -> dict:
    """Exactness after each horizon k, over ``trajectories`` of (states (T + 1, h, w), actions
    (T,)) at least k long: the model's state after k of its own predictions against the real
    one; with the "nothing moves" baseline and vanishing rates at k."""
    out = {}
    for k in horizons:
        long_enough = [(s, a) for s, a in trajectories if len(a) >= k]
        if not long_enough:
            out[k] = {"sequences": 0}
            continue
        by_shape: dict = {}
        for s, a in long_enough:
            by_shape.setdefault(s.shape[1:], []).append((s, a))
        predicted, truth, first = [], [], []
        for group in by_shape.values():
            state = np.stack([s[0] for s, _ in group])
            for t in range(k):
                state, _, _ = model.step(state, np.array([a[t] for _, a in group]))
            predicted.extend(state)
            truth.extend(s[k] for s, _ in group)
            first.extend(s[0] for s, _ in group)
        predicted, truth, first = (np.stack(x) for x in (predicted, truth, first))
        out[k] = {"sequences": len(long_enough), "exact": _exact(predicted, truth),
                  "exact_nothing_moves": _exact(first, truth), **_vanishing(predicted, truth, to_types)}
    return out


def _vanishing(predicted: np.ndarray, truth: np.ndarray, to_types=None) -> dict:
    if to_types is not None:
        predicted, truth = to_types(predicted), to_types(truth)
    return {"player_vanished": vanished_player(predicted), "box_vanished": vanished_boxes(predicted, truth)}


def vanished_player(states: np.ndarray) -> float:
    """The fraction of states (N, h, w) of board codes with no player."""
    players = np.isin(states, (PLAYER, PLAYER_ON_TARGET)).reshape(len(states), -1).sum(1)
    return float((players == 0).mean())


def vanished_boxes(predicted: np.ndarray, truth: np.ndarray) -> float:
    """The fraction of predictions with fewer boxes than the real state."""
    def boxes(states):
        return np.isin(states, (BOX, BOX_ON_TARGET)).reshape(len(states), -1).sum(1)

    return float((boxes(predicted) < boxes(truth)).mean())


def _exact(predicted: np.ndarray, truth: np.ndarray) -> float:
    return float((np.asarray(predicted) == np.asarray(truth)).reshape(len(truth), -1).all(1).mean())


__all__ = ["one_step", "open_loop", "vanished_player", "vanished_boxes"]
