"""Figures of the search in a learned Sokoban model: the model's boards against the real ones
along a plan, the solve rate and the model's exactness by round, the table, a recording."""
from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from wmthesis.sokoban_search.agent import grid_env
from wmthesis.sokoban_search.evaluation import THESIS_ROW, thesis_row
from wmthesis.envs.sokoban import make_tiles, render_board
from wmthesis.viz import image_grid, image_rows, markdown_table, record_frames

TABLE_COLUMNS = ("solve_rate", "solved", "levels", "steps_when_solved", "nodes_per_move", "seconds_per_level")


def plot_plan(real: np.ndarray, predicted: np.ndarray, every: int = 1, columns: int = 10):
    """Real frames (T, H, W, 3) over the model's (T, H, W, 3) along one plan, every
    ``every``-th step."""
    picks = np.arange(0, min(len(real), len(predicted)), every)[:columns]
    return image_rows({"real": [real[t] for t in picks], "model": [predicted[t] for t in picks]})


SHORT_NAMES = {"sokoban-small": "5x5", "sokoban": "10x10", "boxoban-unfiltered-train": "unfilt.",
               "boxoban-medium-train": "medium"}  # the variants, as a round's tick label names them


def plot_rounds(runs: dict[str, list[dict]]):
    """Solve rate of each round's (new, unseen) levels, and the model's one-step exactness on
    unseen levels after it, for each run's history (name -> one dict per stage)."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 3.4))
    width = 0.8 / len(runs)
    for k, (name, history) in enumerate(runs.items()):
        rounds = [h for h in history if h["solved"] is not None]
        left.bar(np.arange(len(rounds)) + k * width, [100 * h["solved"] for h in rounds], width, label=name)
        for variant in history[0]["exactness"]:
            right.plot([h["round"] for h in history], [100 * h["exactness"][variant] for h in history], "o-",
                       label=f"{name}, {variant}")
    first = next(iter(runs.values()))
    labels = [f"{h['round']}\n{SHORT_NAMES.get(h['variant'], h['variant'])}" for h in first if h["solved"] is not None]
    left.set_xticks(np.arange(len(labels)) + 0.4 - width / 2, labels, fontsize=8)
    left.set_ylim(0, 100)
    left.set(xlabel="round (variant)", ylabel="levels solved (%)", title="the agent on each round's new levels")
    left.legend(fontsize=8)
    right.set(xlabel="round (0: random play)", ylabel="one-step exact boards (%)", title="the model on unseen levels")
    right.legend(fontsize=7)
    fig.tight_layout()
    return fig


def results_table(rows: dict[str, dict], levels: str | None = None) -> str:
    """Markdown table of evaluation rows (name -> measures). ``levels``, the table's (a variant of
    our generator, or a Boxoban kind): its thesis row is then :func:`thesis_row`'s, a run's own
    or not (runs written before it gave the thesis 0 on levels it never played); a row without a
    solve rate shows its ``note`` there."""
    def cell(value):
        if value is None:
            return ""
        if isinstance(value, float):
            return f"{value:.3g}"
        return str(value)

    if levels is not None and THESIS_ROW in rows:
        rows = {name: thesis_row(levels) if name == THESIS_ROW else row for name, row in rows.items()}
    return markdown_table([[name, row.get("note", "") if row.get("solve_rate") is None else cell(row["solve_rate"]),
                            *(cell(row.get(c)) for c in TABLE_COLUMNS[1:])] for name, row in rows.items()],
                          ["", *TABLE_COLUMNS])


def accuracy_table(measures: dict[str, dict]) -> str:
    """Markdown table of the models' accuracy (name -> :func:`~wmthesis.sokoban_search.accuracy`
    measures): exact boards one step and 10 and 30 steps ahead against "nothing moves", reward
    and end accuracy, vanishing players and boxes."""
    rows = []
    for name, m in measures.items():
        one = m["one_step"]
        rows.append([f"{name}, one step", one["exact"], one["exact_nothing_moves"], one["reward_accuracy"],
                     one["event_reward_accuracy"], one["end_accuracy"], one["player_vanished"], one["box_vanished"]])
        for k, loop in m["open_loop"].items():
            if loop.get("sequences"):
                rows.append([f"{name}, open loop +{k} ({loop['sequences']} plans)", loop["exact"],
                             loop["exact_nothing_moves"], "", "", "", loop["player_vanished"], loop["box_vanished"]])
    return markdown_table([[_percent(v) for v in row] for row in rows],
                          ["", "exact boards", "nothing moves", "reward right", "rare rewards right",
                           "end right", "player vanished", "box vanished"])


def _percent(value):
    return f"{100 * value:.2f}%" if isinstance(value, float) else ("" if value is None else value)


def plot_levels(boards, titles=None, columns: int = 8, tile_size: int = 8, suptitle: str | None = None):
    """Levels as pictures: ``boards`` (codes (h, w) each, wall ring included) in rows of
    ``columns``, each titled by ``titles``."""
    tiles = make_tiles(tile_size)
    return image_grid([render_board(np.asarray(b), tiles) for b in boards], columns, titles, scale=1.6,
                      suptitle=suptitle)


def record_solution(path: str | Path, variant: str, record: dict) -> Path:
    """A rerun recording of a saved solution replayed in the real environment."""
    env = grid_env(variant)
    env.reset(seed=int(record["seed"]))
    frames, rewards = [env.render()], [0.0]
    for action in record["actions"]:
        _, reward, terminated, truncated, _ = env.step(int(action))
        frames.append(env.render())
        rewards.append(reward)
        if terminated or truncated:
            break
    return record_frames(path, {"board": np.stack(frames)}, {"reward": np.array(rewards)})


__all__ = ["plot_plan", "plot_rounds", "plot_levels", "results_table", "accuracy_table", "record_solution"]
