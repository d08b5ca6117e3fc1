"""World Models' figures: the CMA-ES learning curve, and Sokoban's (thesis Fig. 54, 55)."""
from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from wmthesis.envs.sokoban import CELL_NAMES
from wmthesis.metrics import horizon_errors
from wmthesis.viz import grid_state_figure, image_grid, image_rows, record_frames, save_figure
from wmthesis.world_models.sokoban import VARIANTS


def plot_learning_curve(curve: list[dict], ax=None, title: str | None = None):
    """Best/mean/worst population fitness per generation (the band spans worst to best) and,
    where present, the real-game return of the CMA-ES mean (mean +- std). Returns the figure."""
    if ax is None:
        _, ax = plt.subplots(figsize=(6, 3.5))
    generation = [e["generation"] for e in curve]
    ax.fill_between(generation, [e["worst"] for e in curve], [e["best"] for e in curve], alpha=0.2,
                    label="population (worst to best)")
    ax.plot(generation, [e["best"] for e in curve], lw=1, label="best")
    ax.plot(generation, [e["mean"] for e in curve], lw=1.5, label="mean")
    evals = [e for e in curve if "eval_return" in e]
    if evals:
        ax.errorbar([e["generation"] for e in evals], [e["eval_return"] for e in evals],
                    [e["eval_std"] for e in evals], fmt="o", ms=3, capsize=2, color="k",
                    label="CMA-ES mean, real game")
    ax.xaxis.set_major_locator(plt.MaxNLocator(integer=True))
    ax.set_xlabel("generation")
    ax.set_ylabel("return")
    ax.set_title(title or "Controller fitness (CMA-ES)")
    ax.legend(fontsize=7)
    ax.figure.tight_layout()
    return ax.figure


def plot_seed_curves(curves: dict, human: float | None = None, thesis: float | None = None):
    """Every seed's evolution at a glance, so a stalled seed shows: per seed (one colour), the
    population's mean (solid) and best (dotted) fitness by real agent steps (x 1e6, so recipes of
    other populations compare), and the real-game returns of the CMA-ES mean (points) on the
    right. ``curves``: ``{label: controller curve}``; ``human``/``thesis``: reference lines.
    Returns the figure."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    for i, (label, curve) in enumerate(curves.items()):
        colour = f"C{i % 10}"
        steps = [e["agent_steps"] / 1e6 for e in curve]
        left.plot(steps, [e["mean"] for e in curve], color=colour, lw=1.4, label=str(label))
        left.plot(steps, [e["best"] for e in curve], color=colour, lw=0.8, ls=":")
        evals = [(e["agent_steps"] / 1e6, e["eval_return"]) for e in curve if "eval_return" in e]
        if evals:
            right.plot(*zip(*evals), "o-", color=colour, ms=4, lw=1, label=str(label))
    for ax in (left, right):
        for value, name, style in ((human, "human", "--"), (thesis, "thesis", "-.")):
            if value is not None:
                ax.axhline(value, color="grey", ls=style, lw=0.8, label=name)
        ax.set_xlabel("real agent steps (millions)")
    left.set_ylabel("return")
    left.set_title("population fitness: mean (solid), best (dotted)")
    right.set_title("CMA-ES mean in the real game")
    left.legend(fontsize=7, ncol=2)
    right.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    return fig


def dream_and_reality(iterations: list[dict], dream_length: int):
    """Each iteration's controller in its dream and in the real game, by the real steps spent: its
    dream return and the real reward per as many steps (left), its real bouts' returns (right)."""
    steps = [i["real_steps"] / 1000 for i in iterations]
    fig, (left, right) = plt.subplots(1, 2, figsize=(9, 3))
    left.plot(steps, [i["dream_return"] for i in iterations], "o-", label="in the dream")
    left.plot(steps, [i["real_per_dream"] for i in iterations], "s-", label="in the real game")
    left.set_title(f"reward per {dream_length} steps", fontsize=9)
    right.errorbar(steps, [i["real_return"] for i in iterations], [np.std(i["real_returns"]) for i in iterations],
                   fmt="o-", capsize=3)
    right.set_title("the real bouts' return (mean, std)", fontsize=9)
    for ax in (left, right):
        ax.set_xlabel("real agent steps spent (thousands)")
        ax.axhline(0, color="gray", lw=0.5)
    left.legend(fontsize=8)
    fig.tight_layout()
    return fig


def sokoban_figures(out: Path, evaluated: dict, memory_histories: dict, controllers: dict, random_returns,
                     evaluation: dict) -> list[Path]:
    """Fig. 54 and Fig. 55 in the thesis's style, the grid state, the open-loop error curves,
    the memories' validation losses, the heads' predictions and the CMA-ES curves."""
    examples, paths = evaluated["examples"], []
    frames, reconstructions = examples["fig54"]
    fig = image_grid([image for pair in zip(frames, reconstructions) for image in pair], ncols=4,
                     titles=["original", "reconstruction"] * len(frames),
                     suptitle="Fig. 54: vision, originals and their reconstructions")
    paths.append(save_figure(fig, out / "fig54_reconstructions.png"))
    frame, grid = examples["grid_state"]
    fig = grid_state_figure(frame, grid.reshape(8, 8), CELL_NAMES)
    paths.append(save_figure(fig, out / "grid_state.png"))

    every = 3
    for variant in VARIANTS:
        rows = {}
        for k, (start, truth, prediction) in enumerate(zip(examples["start"], examples["truth"],
                                                           examples["prediction"][variant])):
            rows[f"{k + 1}: truth"] = [start, *truth[every - 1::every]]
            rows[f"{k + 1}: {variant}"] = [start, *prediction[every - 1::every]]
        fig = image_rows(rows)
        fig.suptitle(f"Fig. 55: open-loop rollouts of the {variant} memory (first column: the last real frame; "
                     f"then every {every}rd predicted step)", fontsize=9)
        fig.tight_layout()
        paths.append(save_figure(fig, out / f"fig55_open_loop_{variant}.png"))
    rows = {"truth": [examples["start"][0], *examples["truth"][0][every - 1::every]]}
    rows |= {variant: [examples["start"][0], *examples["prediction"][variant][0][every - 1::every]]
             for variant in VARIANTS}
    fig = image_rows(rows)
    fig.suptitle("Fig. 55: one validation episode, every memory variant", fontsize=9)
    fig.tight_layout()
    paths.append(save_figure(fig, out / "fig55_open_loop_variants.png"))

    curves = {**{v: evaluated["memory"][v]["open_loop"] for v in VARIANTS}, **evaluated["baselines"]}
    fig, axes = plt.subplots(1, 4, figsize=(16, 3.4))
    panels = (("pixel_error", "pixel MSE"), ("cell_accuracy", "cells of the right type"),
              ("changed_cell_accuracy", "changed cells right (dynamics)"), ("one_player", "rollouts with one player"))
    for ax, (key, label) in zip(axes, panels):
        for name, entry in curves.items():
            style = {"nothing moves": dict(ls="--", color="k"), "vae reconstruction": dict(ls=":", color="grey")}
            ax.plot(range(1, len(entry[key]) + 1), entry[key], label=name, lw=1.3, **style.get(name, {}))
        ax.axvline(evaluation["cutoff"], color="grey", lw=0.5)
        ax.set_xlabel("steps ahead")
        ax.set_title(label, fontsize=9)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"open-loop error on {evaluated['episodes']} validation episodes "
                 f"(after {evaluation['context']} real steps)", fontsize=10)
    fig.tight_layout()
    paths.append(save_figure(fig, out / "open_loop_error.png"))

    fig, axes = plt.subplots(1, 5, figsize=(19, 3.2))
    panels = {("rgb", "mdn"): 0, ("rgb", "deterministic"): 1, ("grid", "mdn"): 2, ("grid", "deterministic"): 2}
    for variant, history in memory_histories.items():
        source, kind, _ = VARIANTS[variant]
        steps = [h["step"] for h in history]
        axes[panels[source, kind]].plot(steps, [h["val_latent"] for h in history], label=variant)
        axes[3].plot(steps, [h["val_reward"] for h in history], label=variant)
        if "val_value" in history[0]:
            axes[4].plot(steps, [h["val_value"] for h in history], label=variant)
    for ax, title in zip(axes, ("next latent, VAE latents: mixture NLL", "next latent, VAE latents: squared error",
                                "next latent, grid states: mixture NLL", "reward MSE", "value MSE (auxiliary)")):
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("update")
        if ax.lines:
            ax.legend(fontsize=7)
    fig.suptitle("memory validation losses", fontsize=10)
    fig.tight_layout()
    paths.append(save_figure(fig, out / "memory_losses.png"))

    auxiliary = [v for v, (_, _, aux) in VARIANTS.items() if aux]
    fig, axes = plt.subplots(len(auxiliary), 2, figsize=(10, 3.2 * len(auxiliary)), squeeze=False)
    for row, variant in zip(axes, auxiliary):
        series = examples["heads"][variant]
        row[0].scatter(series["true_reward"], series["reward"], s=4, alpha=0.3)
        row[0].set_xlabel("true reward")
        row[0].set_ylabel("predicted reward")
        row[0].set_title(f"{variant}: reward head, validation steps", fontsize=9)
        episode = series["episode"]
        row[1].plot(episode["true_value"], label="true return (Monte-Carlo)")
        row[1].plot(episode["value"], label="value head")
        row[1].plot(episode["time_only"], ls="--", label="time left only")
        row[1].set_xlabel("step")
        row[1].set_title(f"{variant}: value head, one validation episode", fontsize=9)
        row[1].legend(fontsize=7)
    fig.tight_layout()
    paths.append(save_figure(fig, out / "auxiliary_heads.png"))

    for variant, controller in controllers.items():
        fig, ax = plt.subplots(figsize=(5, 3))
        plot_learning_curve(controller["run"].curve, ax=ax, title=f"CMA-ES, controller on [z h] of {variant}")
        ax.axhline(float(np.mean(random_returns)), color="r", ls="--", lw=1, label="random play, test levels")
        ax.legend(fontsize=7)
        paths.append(save_figure(fig, out / f"cmaes_curve_{variant}.png"))
    return paths


def sokoban_recording(path: Path, evaluated: dict) -> Path:
    """A rerun recording of one validation episode's open loop: the truth beside every variant."""
    examples = evaluated["examples"]
    truth = examples["truth"][0]
    streams = {"truth": truth, **{f"prediction/{v}": examples["prediction"][v][0] for v in VARIANTS}}
    scalars = {f"pixel_error/{v}": horizon_errors(truth, examples["prediction"][v][0]) for v in VARIANTS}
    return record_frames(path, streams, scalars)
