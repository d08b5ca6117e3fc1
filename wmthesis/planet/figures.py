"""PlaNet's figures: open-loop rollouts (thesis Fig. 58, 59, 510), error by horizon, learning curves."""
from __future__ import annotations

from typing import Sequence

import matplotlib.pyplot as plt
import numpy as np


def open_loop_figure(result: dict, *, sequences: int = 3, columns: int | None = None,
                     scale: float = 0.9, title: str | None = None):
    """Thesis Fig. 58 style: per sequence a row of true frames and a row of the model's
    frames; the model row shows the ``context`` true frames, then its open-loop predictions
    (columns titled +1, +2, ...). ``result`` is :func:`~wmthesis.planet.prediction.open_loop`'s output."""
    truth, prediction, context = result["truth"], result["prediction"], result["context"]
    sequences = min(sequences, len(truth))
    columns = min(columns or truth.shape[1], truth.shape[1])
    fig, axes = plt.subplots(2 * sequences, columns, squeeze=False,
                             figsize=(scale * columns, scale * 2 * sequences + (0.3 if title else 0)))
    for index in range(sequences):
        model_row = np.concatenate([truth[index, :context], prediction[index, context:]])
        for row, (label, frames) in enumerate((("truth", truth[index]), ("model", model_row))):
            for t, ax in enumerate(axes[2 * index + row]):
                ax.imshow(frames[t], interpolation="nearest")
                ax.set_xticks([])
                ax.set_yticks([])
                if t >= context and row == 1:
                    for spine in ax.spines.values():
                        spine.set_edgecolor("tab:red")
            axes[2 * index + row, 0].set_ylabel(f"{label} {index + 1}", fontsize=7)
    for t, ax in enumerate(axes[0]):
        ax.set_title("context" if t == context // 2 else (f"+{t - context + 1}" if t >= context else ""),
                     fontsize=7)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout(pad=0.2, rect=(0, 0, 1, 1 - 0.35 / fig.get_figheight() if title else 1))
    return fig


def horizon_error_figure(curves: dict[str, Sequence[float]], *, title: str | None = None):
    """Open-loop prediction error against the prediction horizon, one line per entry
    (e.g. ``{"unchanged": result["mse"], "free nats 12": other["mse"]}``)."""
    fig, ax = plt.subplots(figsize=(4.5, 3))
    for label, mse in curves.items():
        ax.plot(np.arange(1, len(mse) + 1), mse, marker=".", label=label)
    return _horizon_axes(fig, ax, "MSE per pixel", title, legend_size=8)


def learning_curve_figure(curves: dict[str, dict], *, references: dict[str, float] | None = None,
                          x: str = "env_steps", title: str | None = None):
    """Test score (mean and std band) against agent steps, one line per run; training
    episodes' returns as faint dots. ``curves`` maps labels to :func:`train_planet`'s
    ``curve`` (or ``curve.json``); ``references`` draws horizontal lines (e.g. random, human).
    """
    fig, ax = plt.subplots(figsize=(5, 3.2))
    for label, curve in curves.items():
        tests = curve.get("test", [])
        line = None
        if tests:
            steps = np.array([entry[x] for entry in tests])
            mean = np.array([entry["mean"] for entry in tests])
            std = np.array([entry["std"] for entry in tests])
            (line,) = ax.plot(steps, mean, marker=".", label=f"{label} (test)")
            ax.fill_between(steps, mean - std, mean + std, alpha=0.2, color=line.get_color())
        train = curve.get("train", [])
        if train:
            ax.scatter([entry[x] for entry in train], [entry["return"] for entry in train], s=6, alpha=0.4,
                       color=None if line is None else line.get_color(),
                       label=None if line is not None else f"{label} (train)")
    reference_lines(ax, references or {})
    ax.set_xlabel({"env_steps": "agent steps", "frames": "frames"}.get(x, x))
    ax.set_ylabel("score")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    if title:
        ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return fig


def reference_lines(ax, references: dict[str, float]) -> None:
    """Dashed gray lines at ``references`` (label -> score), each labelled at the panel's right
    edge; labels of close lines are moved apart (upwards) so none prints over another."""
    for value in references.values():
        ax.axhline(value, linestyle="--", linewidth=0.8, color="gray")
    low, high = ax.get_ylim()
    gap, right, placed = 0.06 * (high - low), ax.get_xlim()[1], -np.inf
    for name, value in sorted(references.items(), key=lambda item: item[1]):
        placed = max(value, placed + gap)
        ax.annotate(name, (right, value), xytext=(right, placed), textcoords="data", fontsize=7, color="gray",
                    va="bottom", ha="right")
    ax.set_ylim(low, max(high, placed + gap))


def study_error_figure(scores: dict[str, list[dict]], *, title: str | None = None):
    """The model study's open-loop error on the moving pixels against the horizon: per
    configuration the seeds' mean with their min-max band, and the two baselines (dashed).
    ``scores``: ``{variant: [score_run per seed]}`` (:mod:`~wmthesis.planet.study`)."""
    fig, ax = plt.subplots(figsize=(5.5, 3.4))
    for variant, runs in scores.items():
        errors = np.array([run["errors"]["model"] for run in runs])
        steps = np.arange(1, errors.shape[1] + 1)
        (line,) = ax.plot(steps, errors.mean(0), marker=".", label=study_label(runs[0]))
        ax.fill_between(steps, errors.min(0), errors.max(0), alpha=0.25, color=line.get_color())
    first = next(iter(scores.values()))[0]["errors"]
    for name, style in (("repeat last", "--"), ("mean frame", ":")):
        ax.plot(np.arange(1, len(first[name]) + 1), first[name], style, color="gray", label=name)
    return _horizon_axes(fig, ax, "squared error, moving pixels", title, legend_size=7)


def _horizon_axes(fig, ax, ylabel: str, title: str | None, legend_size: int):
    """Label, grid, legend and title of an error-by-horizon plot; the finished figure."""
    ax.set_xlabel("steps predicted open-loop")
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=legend_size)
    if title:
        ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return fig


def study_label(run: dict, separator: str = ", ") -> str:
    """A study run's setting, e.g. "KL scale 0.03, free nats 12"."""
    return f"KL scale {run['kl_scale']:g}{separator}free nats {run['free_nats']:g}"


def study_pictures_figure(rollouts: dict[str, dict], *, sequence: int = 0, columns: int = 15,
                          scale: float = 0.8):
    """Fig. 59 beside Fig. 510: one held-out sequence, the truth above each configuration's
    open-loop frames (the context frames, then predictions framed in red). ``rollouts``:
    ``{label: open_loop result}`` on the same sequences."""
    labels = list(rollouts)
    first = rollouts[labels[0]]
    context, columns = first["context"], min(columns, first["truth"].shape[1])
    rows = [("truth", first["truth"][sequence])] + [
        (label, np.concatenate([first["truth"][sequence, :context], r["prediction"][sequence, context:]]))
        for label, r in rollouts.items()]
    fig, axes = plt.subplots(len(rows), columns, squeeze=False, figsize=(scale * columns, scale * len(rows)))
    for row, (label, frames) in enumerate(rows):
        for t, ax in enumerate(axes[row]):
            ax.imshow(frames[t], interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if row > 0 and t >= context:
                for spine in ax.spines.values():
                    spine.set_edgecolor("tab:red")
        axes[row, 0].set_ylabel(label, fontsize=6, rotation=0, ha="right", va="center")
    for t, ax in enumerate(axes[0]):
        ax.set_title(f"+{t - context + 1}" if t >= context else ("context" if t == context // 2 else ""), fontsize=7)
    fig.tight_layout(pad=0.2)
    return fig


def plan_choices_figure(choices: dict[str, np.ndarray], action_names: Sequence[str], title: str | None = None):
    """How often each planner of ``choices`` (name -> actions (T,)) picks each action: grouped
    bars over ``action_names``, and the share of steps on which each pair agrees in the legend."""
    names = list(choices)
    fig, ax = plt.subplots(figsize=(11, 3.2))
    width = 0.8 / len(names)
    for k, name in enumerate(names):
        counts = np.bincount(choices[name], minlength=len(action_names)) / max(len(choices[name]), 1)
        ax.bar(np.arange(len(action_names)) + k * width, 100 * counts, width, label=name)
    agreement = ", ".join(f"{a} = {b}: {100 * np.mean(choices[a] == choices[b]):.0f}%"
                          for i, a in enumerate(names) for b in names[i + 1:])
    ax.set_xticks(np.arange(len(action_names)) + 0.4 - width / 2, action_names, rotation=60, fontsize=7)
    ax.set(ylabel="steps (%)", title=title or "the action each planner picks, from the same belief")
    ax.legend(fontsize=8, title=f"same action: {agreement}", title_fontsize=7)
    fig.tight_layout()
    return fig
