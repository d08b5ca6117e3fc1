"""Figures in the thesis's style and rerun recordings of rollouts.

Figures are matplotlib; recordings are rerun ``.rrd`` files, opened with ``rerun FILE.rrd``
(the viewer ships with ``rerun-sdk``). Nothing here knows about models or environments.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Sequence

import matplotlib.pyplot as plt
import numpy as np
import rerun as rr

from wmthesis.core import Callback


def image_grid(images: Sequence[np.ndarray], ncols: int = 8, titles: Sequence[str] | None = None,
               scale: float = 1.3, suptitle: str | None = None):
    """A figure of ``images`` (each (H, W, 3) uint8 or (H, W)) in a grid; returns the figure."""
    n = len(images)
    if n == 0:
        raise ValueError("image_grid needs at least one image")
    ncols = min(ncols, n)
    nrows = -(-n // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(scale * ncols, scale * nrows + (0.3 if suptitle else 0)),
                             squeeze=False)
    for index, ax in enumerate(axes.flat):
        ax.axis("off")
        if index < n:
            ax.imshow(images[index], interpolation="nearest", cmap=None if np.ndim(images[index]) == 3 else "viridis")
            if titles is not None:
                ax.set_title(titles[index], fontsize=7)
    if suptitle:
        fig.suptitle(suptitle, fontsize=10)
    fig.tight_layout()
    return fig


def image_rows(rows: dict[str, Sequence[np.ndarray]], scale: float = 1.1, suptitle: str | None = None):
    """One labelled row of images per entry, e.g. ``{"raw": frames, "world_models": small}``,
    under ``suptitle`` where given (laid out with the figure, so it stays above the top row).

    Rows may hold images of different sizes; columns line up by index.
    """
    ncols = max(len(images) for images in rows.values())
    fig, axes = plt.subplots(len(rows), ncols, figsize=(scale * ncols, scale * len(rows) + (0.3 if suptitle else 0)),
                             squeeze=False)
    for (label, images), row in zip(rows.items(), axes):
        for index, ax in enumerate(row):
            ax.set_xticks([])
            ax.set_yticks([])
            if index < len(images):
                ax.imshow(images[index], interpolation="nearest")
            else:
                ax.axis("off")
        row[0].set_ylabel(label, fontsize=8)
    if suptitle:
        fig.suptitle(suptitle, fontsize=10)
    fig.tight_layout()
    return fig


class RerunRecorder(Callback):
    """Logs every step of one :func:`wmthesis.core.loop` call to a rerun recording file.

    Logged per step on the ``step`` timeline (and ``episode`` as a second timeline):
    ``observation`` (an image state; other states are logged as a tensor), ``action``,
    ``reward`` and ``return``. States with shape (H, W, 3) are images.
    """

    def __init__(self, path: str | Path, application_id: str = "wmthesis", action_names: Sequence[str] | None = None):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.action_names = action_names
        self.stream = rr.RecordingStream(application_id)
        self.stream.save(str(self.path))
        self.global_step = 0
        self.episode = 0
        self.episode_return = 0.0

    def on_episode_start(self, episode, train_mode):
        self.episode = episode
        self.episode_return = 0.0

    def on_step_taken(self, step, transition, info):
        self.stream.set_time("step", sequence=self.global_step)
        self.stream.set_time("episode", sequence=self.episode)
        self.stream.log("observation", _as_rerun(transition.state))
        action = transition.action
        label = self.action_names[action] if self.action_names else str(action)
        self.stream.log("action", rr.TextLog(label))
        self.stream.log("action_index", rr.Scalars([float(action)]))
        self.episode_return += transition.reward
        self.stream.log("reward", rr.Scalars([transition.reward]))
        self.stream.log("return", rr.Scalars([self.episode_return]))
        self.global_step += 1

    def on_loop_end(self, is_aborted):
        """Finish the file: a recorder makes one recording, of one :func:`loop` call."""
        self.stream.flush()
        self.stream.disconnect()


def _as_rerun(state):
    array = np.asarray(state)
    if array.ndim == 3 and array.shape[-1] in (1, 3, 4):
        return rr.Image(array)
    return rr.Tensor(array)


def record_frames(path: str | Path, streams: dict[str, np.ndarray], scalars: dict[str, np.ndarray] | None = None,
                  application_id: str = "wmthesis") -> Path:
    """Write image sequences side by side over a ``step`` timeline, e.g. true vs predicted.

    ``streams`` maps an entity name to frames of shape (T, H, W, 3); ``scalars`` maps a name to
    (T,) values (a reward, an error curve).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    stream = rr.RecordingStream(application_id)
    stream.save(str(path))
    length = max(len(frames) for frames in streams.values())
    for step in range(length):
        stream.set_time("step", sequence=step)
        for name, frames in streams.items():
            if step < len(frames):
                stream.log(name, _as_rerun(frames[step]))
        for name, values in (scalars or {}).items():
            if step < len(values):
                stream.log(name, rr.Scalars([float(values[step])]))
    stream.flush()
    stream.disconnect()
    return path


def recording_rows(path: str | Path) -> dict[str, int]:
    """How many rows each entity of a rerun recording holds, e.g. ``{"/observation": 120, ...}``."""
    from rerun.chunk import RrdReader

    summary = RrdReader(str(path)).store().summary()  # one line per chunk of an entity
    rows: dict[str, int] = {}
    for match in re.finditer(r"^(\S+) rows=(\d+)", summary, re.M):
        rows[match[1]] = rows.get(match[1], 0) + int(match[2])
    return rows


def grid_state_figure(rgb: np.ndarray, grid: np.ndarray, names: Sequence[str], scale: float = 3.0):
    """A level's RGB view beside its grid state: block types (h, w) as colours and numbers.

    ``names[code]`` labels each block type in the legend.
    """
    fig, (left, right) = plt.subplots(1, 2, figsize=(2 * scale + 1.5, scale))
    left.imshow(rgb, interpolation="nearest")
    left.set_title("RGB observation", fontsize=9)
    cmap = plt.get_cmap("tab10", len(names))
    right.imshow(grid, cmap=cmap, vmin=-0.5, vmax=len(names) - 0.5, interpolation="nearest")
    for (row, col), code in np.ndenumerate(grid):
        right.text(col, row, str(code), ha="center", va="center", fontsize=8, color="white")
    right.set_title(f"grid state ({grid.size} block types)", fontsize=9)
    handles = [plt.Rectangle((0, 0), 1, 1, color=cmap(code)) for code in range(len(names))]
    right.legend(handles, [f"{code} {name}" for code, name in enumerate(names)], fontsize=7,
                 loc="center left", bbox_to_anchor=(1.02, 0.5), frameon=False)
    for ax in (left, right):
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    return fig


def markdown_table(rows: Sequence[Sequence], headers: Sequence[str]) -> str:
    """A Markdown table (for ``IPython.display.Markdown``) of ``rows`` under ``headers``."""
    def cell(value):
        return f"{value:.2f}" if isinstance(value, float) else str(value)

    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def save_figure(fig, path: str | Path, dpi: int = 80) -> Path:
    """Write ``fig`` to ``path`` (at the modest DPI the committed notebooks use), whole
    (:func:`~wmthesis.runs.atomic_path`), and close it."""
    from wmthesis.runs import atomic_path

    path = Path(path)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, bbox_inches="tight", format=path.suffix.lstrip(".") or "png")
    finally:
        plt.close(fig)
    return path
