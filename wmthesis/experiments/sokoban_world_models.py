"""World Models on Sokoban (thesis 5.3.1-5.3.3): one vision, five memory variants (frames or
grid states, stochastic or deterministic, with or without auxiliary heads), three controllers,
and the open-loop measures of what the thesis judged by eye."""
from __future__ import annotations

import json
import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from wmthesis.config import CollectConfig, ControllerConfig, MemoryConfig, VisionConfig, for_profile, profile_name
from wmthesis.experiments.results import _first_run_seconds, _jsonable, _read_json, _run_header, _save
from wmthesis.utils import atomic_path, data_dir

# Memory variants, all trained on the same random rollouts: name -> (input, memory kind,
# auxiliary value head). "rgb": the VAE's latents (16) of 64x64 frames; "grid": the 64 block
# types of the inner 8x8 cells, bypassing vision (5.3.2, see encode_grid_store).
SOKOBAN_WM_VARIANTS = {
    "mdn": ("rgb", "mdn", False),                      # 5.3.1: the stochastic MDN-RNN
    "deterministic": ("rgb", "deterministic", False),  # 5.3.1: linear next-latent head (4.3.1)
    "auxiliary": ("rgb", "mdn", True),                 # 5.3.3: + value head (Monte-Carlo return)
    "grid": ("grid", "mdn", False),                    # 5.3.2: grid states, latent 64
    "grid-auxiliary": ("grid", "mdn", True),           # 5.3.3 on grid states
}
# Controllers evolved with CMA-ES in the real game, named by the memory variant whose [z h] they
# read: 5.3.1's (VAE + MDN-RNN), 5.3.2's (grid states) and 5.3.3's (grid states + auxiliary heads).
SOKOBAN_WM_CONTROLLERS = ("mdn", "grid", "grid-auxiliary")

# Changes on top of the profile (per config class), as SOKOBAN_CHANGES does for PlaNet.
# quick: a Sokoban episode is 120 steps (a Boxing bout ~1,780), so the store holds 400 random
# episodes, 48,000 frames and as many new levels (Boxing's quick: 20 bouts, ~36,000 frames).
# The rest is the quick profile's, as for Boxing: the VAE 1,500 updates of 64 frames, each of the
# five memories 1,500 updates of 16 chunks of 100 steps, each of the three controllers 60
# generations of 16 candidates x 3 levels (an episode ends at the game's own 120 steps). Measured
# pieces on one core: ~0.3 s a VAE update, 0.03-0.06 s a memory update, 2-4 s a generation: about
# 25 minutes end to end on two idle cores.
# thesis: the thesis's chunks of 1,000 steps do not fit 120-step episodes; whole episodes
# (119 transitions) are used. The thesis states no other Sokoban-specific setting.
SOKOBAN_WM_CHANGES = {
    "smoke": {},
    "quick": {"CollectConfig": dict(episodes=400)},
    "thesis": {"MemoryConfig": dict(sequence_length=119)},
}

# Evaluation per profile: ``levels`` unseen levels for the controllers and random play;
# open-loop rollouts on up to ``episodes`` validation episodes, ``context`` real steps then
# ``horizon`` predicted ones; numbers reported at ``cutoff`` steps ahead.
SOKOBAN_WM_EVAL = {
    "smoke": dict(levels=4, episodes=2, context=10, horizon=10, cutoff=5),
    "quick": dict(levels=50, episodes=40, context=60, horizon=30, cutoff=10),
    "thesis": dict(levels=100, episodes=100, context=60, horizon=30, cutoff=10),
}

SOKOBAN_FRAME_SIZE = 64
# The thesis judged Sokoban's World Models by eye (5.3) and reported no score.
SOKOBAN_WM_REFERENCE = {
    "5.3.1 vision": "reconstructions resemble the frames (Fig. 54)",
    "5.3.1 memory": "dynamics not learned: the agent disappears, blocks change type, pushes not modelled (Fig. 55); "
                    "deterministic memory no better",
    "5.3.1 controller": "solved no level, comparable to random play",
    "5.3.2 grid states": "no improvement over 5.3.1",
    "5.3.3 auxiliary heads": "reward and value not learned (sparse rewards); no improvement",
}


def sokoban_wm_configs(profile: str | None = None, seed: int = 0) -> dict:
    """The configs of ``sokoban-wm`` in ``profile``: the profile's, with :data:`SOKOBAN_WM_CHANGES`
    on top. Returns ``collect``, ``vision``, ``memory`` (the variants change ``kind`` and
    ``auxiliary``) and ``controller`` (seeded with ``seed``)."""
    profile = profile_name(profile)
    changes = dict(SOKOBAN_WM_CHANGES[profile])
    changes["ControllerConfig"] = {**changes.get("ControllerConfig", {}), "seed": seed}
    classes = {"collect": CollectConfig, "vision": VisionConfig, "memory": MemoryConfig,
               "controller": ControllerConfig}
    return {key: for_profile(cls, profile, **changes.get(cls.__name__, {})) for key, cls in classes.items()}


def sokoban_world_models(profile: str | None = None, seed: int = 0, progress: bool = True) -> dict:
    """Thesis 5.3.1-5.3.3: World Models on Sokoban (10x10, 4 boxes, a new level each episode).

    1. Random rollouts, stored twice from the same seeds (the same levels and actions): 64x64
       World Models frames (the wall ring cropped, 8x8 pixels a cell) and grid states.
    2. Vision: the VAE (latent 16) on the frames; every frame encoded once.
    3. Memory: the :data:`SOKOBAN_WM_VARIANTS` on the same episodes: stochastic and
       deterministic (5.3.1), grid states as the latent of size 64 (5.3.2), auxiliary value
       heads (5.3.3).
    4. Controllers (:data:`SOKOBAN_WM_CONTROLLERS`): CMA-ES on ``[z h]`` in the real game, then
       scored beside random play on the same unseen levels.
    5. Open-loop rollouts on validation episodes (thesis 5.3: ~60 real steps warm the memory,
       then it predicts from its own predictions): pixel and latent error per horizon, and what
       the thesis saw by eye, read off the predicted frames (:func:`read_grid`): cells of the
       right type, one player or none, boxes kept; beside "nothing moves" (the last real frame
       repeated) and the VAE's own reconstructions. The reward and value heads against the truth.

    Artifacts under ``data/<profile>/sokoban-wm/seed<seed>/``, results (figures, a rerun
    recording of truth vs predictions, ``metrics.json``) under
    ``data/results/sokoban-wm/<profile>-seed<seed>/``; every step resumes from its artifact.
    Returns the metrics; ``score`` is the 5.3.1 controller's.
    """
    import dataclasses

    from wmthesis.agents.world_models import encode_grid_store, encode_store, train_memory, train_vision
    from wmthesis.data import EpisodeStore, collect
    from wmthesis.envs.sokoban import ACTIONS
    from wmthesis.metrics import score_summary

    profile = profile_name(profile)
    started = time.time()
    work = data_dir(profile, "sokoban-wm", f"seed{seed}")
    out = data_dir("results", "sokoban-wm", f"{profile}-seed{seed}")
    configs = sokoban_wm_configs(profile, seed)
    evaluation = SOKOBAN_WM_EVAL[profile]
    collect_cfg = configs["collect"]
    stores = {source: collect("sokoban", collect_cfg.episodes, work / f"random-{source}.h5",
                              workers=collect_cfg.workers, seed=seed, max_steps=collect_cfg.max_steps,
                              progress=progress, **_sokoban_options(source))
              for source in ("rgb", "grid")}
    vae, vision_history = train_vision(stores["rgb"], work, configs["vision"], seed=seed, progress=progress)
    latents = {"rgb": encode_store(stores["rgb"], vae, work / "latents-rgb.h5", progress=progress),
               "grid": encode_grid_store(stores["grid"], work / "latents-grid.h5")}
    _check_same_episodes(latents)
    memories, memory_histories = {}, {}
    for variant, (source, kind, auxiliary) in SOKOBAN_WM_VARIANTS.items():
        config = dataclasses.replace(configs["memory"], kind=kind, auxiliary=auxiliary)
        memories[variant], memory_histories[variant] = train_memory(
            latents[source], work / f"memory-{variant}", config, n_actions=len(ACTIONS), seed=seed, progress=progress)

    level_seeds = _sokoban_level_seeds(seed, evaluation["levels"])
    controllers = {variant: _sokoban_controller(variant, vae, memories[variant], configs["controller"], work,
                                                level_seeds, progress)
                   for variant in SOKOBAN_WM_CONTROLLERS}
    random_returns, random_steps = _sokoban_random_play(level_seeds, seed, configs["controller"].max_steps)
    evaluated = _sokoban_evaluate_memories(vae, memories, stores, latents, configs["memory"], evaluation)
    figures = _sokoban_figures(out, evaluated, memory_histories, controllers, random_returns, evaluation)
    recording = _sokoban_recording(out / "open_loop.rrd", evaluated)
    with EpisodeStore(stores["grid"]) as store:
        store_returns = [float(store.episode(i)["rewards"].sum()) for i in range(len(store))]

    metrics = {
        **_run_header("sokoban-wm", profile, seed, time.time() - started),
        "score": score_summary(controllers[SOKOBAN_WM_CONTROLLERS[0]]["returns"]),
        "controllers": {variant: {"score": score_summary(c["returns"]), "solved": c["solved"],
                                  "generations": c["run"].generation, "curve": c["run"].curve}
                        for variant, c in controllers.items()},
        "random_play": {"score": score_summary(random_returns), "solved": _solved(random_returns, random_steps)},
        "random_play_in_store": score_summary(store_returns),
        "levels": evaluation["levels"],
        "vision_history": vision_history,
        "vision": evaluated["vision"],
        "memory": {variant: {"input": source, "kind": kind, "auxiliary": auxiliary,
                             "history": memory_histories[variant],
                             "best_val": {k: v for k, v in min(memory_histories[variant],
                                                               key=lambda h: h["val_loss"]).items()
                                          if k.startswith("val_")},
                             **evaluated["memory"][variant]}
                   for variant, (source, kind, auxiliary) in SOKOBAN_WM_VARIANTS.items()},
        "baselines": evaluated["baselines"],
        "open_loop": {key: evaluation[key] for key in ("context", "horizon", "cutoff")}
                     | {"episodes": evaluated["episodes"]},
        "reference": SOKOBAN_WM_REFERENCE,
        "settings": {key: dataclasses.asdict(config) for key, config in configs.items()}
                    | {"variants": SOKOBAN_WM_VARIANTS, "controllers": list(SOKOBAN_WM_CONTROLLERS),
                       "frame_size": SOKOBAN_FRAME_SIZE},
        "files": {"figures": [str(f) for f in figures], "recording": str(recording)},
    }
    metrics["first_run_wall_seconds"] = _first_run_seconds(out / "metrics.json", metrics["wall_seconds"])
    metrics = _jsonable(metrics)
    with atomic_path(out / "metrics.json") as tmp:
        tmp.write_text(json.dumps(metrics, indent=1))
    return metrics


def _sokoban_options(source: str) -> dict:
    """The Sokoban options of an input: World Models frames (``rgb``) or grid states."""
    return {"frame_size": SOKOBAN_FRAME_SIZE} if source == "rgb" else {"observation": "grid"}


def _check_same_episodes(latents: dict) -> None:
    """The frame and grid stores must hold the same episodes (same seeds: same levels, actions)."""
    import torch

    from wmthesis.agents.world_models import LatentStore

    rgb, grid = LatentStore(latents["rgb"]), LatentStore(latents["grid"])
    if not (np.array_equal(rgb.ends, grid.ends) and all(torch.equal(rgb.data[k], grid.data[k])
                                                        for k in ("actions", "rewards", "terminals"))):
        raise ValueError(f"{latents['rgb']} and {latents['grid']} hold different episodes; delete the "
                         "stores and latents under that folder to collect them again")


def _sokoban_level_seeds(seed: int, n: int) -> np.ndarray:
    """The seeds of ``n`` unseen levels scoring the controllers and random play (a stream of
    their own: apart from the collected levels and those CMA-ES trained on)."""
    from wmthesis.agents.controller_training import episode_seeds

    return episode_seeds(seed, 0, n, stream=2)


def _solved(returns, steps) -> int:
    """Levels solved. Each step costs 0.1 and boxes net at most +4 (10x10: 4 boxes), so an
    unsolved episode has ``return + 0.1 * steps <= 4``, a solved one (the +10) at least 11."""
    return int(np.sum(np.asarray(returns, float) + 0.1 * np.asarray(steps, float) > 5))


def _sokoban_controller(variant: str, vae, memory, cfg, work: Path, level_seeds: np.ndarray, progress: bool) -> dict:
    """Evolve the controller that reads ``[z h]`` of memory ``variant`` (resumable), and play its
    CMA-ES mean on the levels ``level_seeds`` (cached in ``evaluation.json`` per generation)."""
    from wmthesis.agents.controller_training import VAEVision, evaluate_population, make_game, train_controller
    from wmthesis.agents.world_models import GridVision

    source = SOKOBAN_WM_VARIANTS[variant][0]
    vision, options = (VAEVision(vae) if source == "rgb" else GridVision()), _sokoban_options(source)
    folder = work / f"controller-{variant}"
    run = train_controller("sokoban", vision, memory, cfg, out_dir=folder, env_options=options, progress=progress)
    path = folder / "evaluation.json"
    cached = _read_json(path)
    if cached is None or cached["generation"] != run.generation or cached["seeds"] != level_seeds.tolist():
        game = make_game("sokoban", len(level_seeds), **options)
        try:
            returns, steps = evaluate_population(run.mean_params[None], game, vision, memory, seeds=level_seeds,
                                                 max_steps=cfg.max_steps)
        finally:
            game.close()
        cached = {"generation": run.generation, "seeds": level_seeds.tolist(), "returns": returns[0].tolist(),
                  "steps": steps[0].tolist()}
        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(cached))
    return {"run": run, "returns": cached["returns"], "steps": cached["steps"],
            "solved": _solved(cached["returns"], cached["steps"])}


def _sokoban_random_play(level_seeds: np.ndarray, seed: int, max_steps: int | None) -> tuple[np.ndarray, np.ndarray]:
    """Random play on the controllers' levels (grid observations: the same levels and rules, no drawing)."""
    from wmthesis.agents.controller_training import make_game, random_play

    game = make_game("sokoban", len(level_seeds), observation="grid")
    try:
        return random_play(game, level_seeds, seed=seed, max_steps=max_steps)
    finally:
        game.close()


def _sokoban_evaluate_memories(vae, memories: dict, stores: dict, latents: dict, memory_cfg, evaluation: dict) -> dict:
    """Open-loop rollouts of every memory variant, and its heads' predictions, on validation
    episodes; with two baselines, "nothing moves" (the last real frame repeated) and the VAE's
    reconstructions of the true frames (the best a VAE-decoded prediction can look). Returns
    ``episodes``, ``vision``, ``memory`` and ``baselines`` (numbers and curves) and ``examples``
    (arrays for the figures)."""
    from wmthesis.agents.world_models import (LatentStore, grid_accuracy, open_loop, open_loop_grid, reconstruct,
                                              split_episodes)
    from wmthesis.data import EpisodeStore
    from wmthesis.envs.sokoban import read_grid
    from wmthesis.metrics import error_at, horizon_errors

    context, horizon, cutoff = evaluation["context"], evaluation["horizon"], evaluation["cutoff"]
    latent_stores = {source: LatentStore(path) for source, path in latents.items()}
    grid_latents = latent_stores["grid"]
    train_episodes, val_episodes = split_episodes(len(grid_latents), memory_cfg.val_fraction)
    lengths = grid_latents.ends - grid_latents.starts
    chosen = [int(i) for i in val_episodes if lengths[i] >= context + horizon][:evaluation["episodes"]]
    if not chosen:
        raise ValueError(f"no validation episode has the {context + horizon} steps of an open-loop rollout")
    names = [*SOKOBAN_WM_VARIANTS, "nothing moves", "vae reconstruction"]
    curves = {name: {"pixel": [], "latent": [], "codes": []} for name in names}
    shown = min(3, len(chosen))
    examples = {"start": [], "truth": [], "prediction": {name: [] for name in names}}
    truth_codes, last_seen = [], []
    with EpisodeStore(stores["rgb"]) as rgb, EpisodeStore(stores["grid"]) as grid:
        for k, index in enumerate(chosen):
            episode = rgb.episode(index)
            frames, actions = episode["observations"], episode["actions"]
            grids = grid.episode(index)["observations"]
            truth = frames[context:context + horizon]
            truth_codes.append(grids[context:context + horizon])
            last_seen.append(grids[context - 1])
            results = {}
            for variant, (source, _, _) in SOKOBAN_WM_VARIANTS.items():
                if source == "rgb":
                    result = open_loop(vae, memories[variant], frames, actions, context=context, horizon=horizon)
                    results[variant] = (result["prediction"], result["latent_error"], read_grid(result["prediction"]))
                else:
                    result = open_loop_grid(memories[variant], grids, actions, context=context, horizon=horizon)
                    results[variant] = (result["prediction"], result["latent_error"], result["prediction_grid"])
            still = np.repeat(frames[context - 1][None], horizon, axis=0)
            results["nothing moves"] = (still, None, np.repeat(grids[context - 1][None], horizon, axis=0))
            reconstruction = reconstruct(vae, truth)
            results["vae reconstruction"] = (reconstruction, None, read_grid(reconstruction))
            for name, (prediction, latent_error, codes) in results.items():
                curves[name]["pixel"].append(horizon_errors(truth, prediction))
                curves[name]["codes"].append(codes)
                if latent_error is not None:
                    curves[name]["latent"].append(latent_error)
                if k < shown:
                    examples["prediction"][name].append(prediction)
            if k < shown:
                examples["start"].append(frames[context - 1])
                examples["truth"].append(truth)
            if k == 0:
                examples["grid_state"] = (frames[context - 1], grids[context - 1])
        picks = chosen[:8]
        fig54 = np.stack([rgb.episode(i)["observations"][(37 * n) % lengths[i]] for n, i in enumerate(picks)])
    examples["fig54"] = (fig54, reconstruct(vae, fig54))

    truth_codes, last_seen = np.stack(truth_codes), np.stack(last_seen)
    summary = {}
    for name, curve in curves.items():
        entry = {"pixel_error": np.mean(curve["pixel"], axis=0),
                 **grid_accuracy(np.stack(curve["codes"]), truth_codes, last_seen)}
        if curve["latent"]:
            entry["latent_error"] = np.mean(curve["latent"], axis=0)
        entry["at_cutoff"] = {key: error_at(values, cutoff) for key, values in entry.items()}
        summary[name] = entry
    heads, examples["heads"] = _sokoban_heads(memories, latent_stores, memory_cfg.discount, train_episodes,
                                              val_episodes[:evaluation["episodes"]])
    reconstruction = summary["vae reconstruction"]
    return {"episodes": len(chosen),
            "vision": {"reconstruction_pixel_error": float(np.mean(reconstruction["pixel_error"])),
                       "reconstruction_cell_accuracy": float(np.mean(reconstruction["cell_accuracy"]))},
            "memory": {variant: {"open_loop": summary[variant], **heads[variant]} for variant in SOKOBAN_WM_VARIANTS},
            "baselines": {name: summary[name] for name in ("nothing moves", "vae reconstruction")},
            "examples": examples}


def _sokoban_heads(memories: dict, latent_stores: dict, discount: float, train_episodes,
                   val_episodes) -> tuple[dict, dict]:
    """The reward head of every memory and the value head of the auxiliary ones on validation
    episodes (teacher forcing), against the truth and naive predictors: the training mean, and
    for the value the return of a level where nothing but the step cost ever happens (known
    from the time left alone). Returns the numbers by variant and the series for the figure."""
    from wmthesis.agents.world_models import head_predictions

    numbers, series = {}, {}
    returns = {source: store.returns(discount).numpy() for source, store in latent_stores.items()}
    for variant, (source, _, auxiliary) in SOKOBAN_WM_VARIANTS.items():
        store = latent_stores[source]
        rows = np.concatenate([np.arange(store.starts[i], store.ends[i]) for i in train_episodes])
        rewards = store.data["rewards"].numpy()
        collected = {key: [] for key in ("reward", "true_reward", "value", "true_value", "time_only")}
        for index in val_episodes:
            episode = store.episode(int(index))
            predicted = head_predictions(memories[variant], episode["mu"], episode["actions"])
            steps_left = np.arange(len(episode["actions"]), 0, -1)
            collected["reward"].append(predicted["reward"])
            collected["true_reward"].append(episode["rewards"].numpy())
            collected["true_value"].append(returns[source][store.starts[index]:store.ends[index]])
            collected["time_only"].append(-0.1 * (1 - discount ** steps_left) / (1 - discount))
            if auxiliary:
                collected["value"].append(predicted["value"])
        data = {key: np.concatenate(values) for key, values in collected.items() if values}
        numbers[variant] = {"reward_head": _head_numbers(data["reward"], data["true_reward"], rewards[rows].mean(),
                                                         events=np.abs(data["true_reward"] + 0.1) > 1e-3)}
        if auxiliary:
            numbers[variant]["value_head"] = _head_numbers(data["value"], data["true_value"],
                                                           returns[source][rows].mean(), time_only=data["time_only"])
        series[variant] = {"reward": data["reward"], "true_reward": data["true_reward"],
                           "episode": {key: values[0] for key, values in collected.items() if values}}
    return numbers, series


def _head_numbers(predicted, true, constant: float, events=None, time_only=None) -> dict:
    """How well a head predicts ``true`` (N,): its MSE; a constant's (the training mean); the
    skill ``1 - mse / constant_mse`` (> 0: better than the constant); the correlation; on
    ``events`` (the rare steps where a box moved on or off a target) the same MSEs; the MSE of a
    predictor that knows only the time left (``time_only``)."""
    predicted, true = np.asarray(predicted, np.float64), np.asarray(true, np.float64)
    mse, constant_mse = float(np.mean((predicted - true) ** 2)), float(np.mean((constant - true) ** 2))
    correlation = (float(np.corrcoef(predicted, true)[0, 1])
                   if predicted.std() > 0 and true.std() > 0 else float("nan"))
    skill = 1 - mse / constant_mse if constant_mse > 0 else float("nan")
    out = {"mse": mse, "constant_mse": constant_mse, "skill": skill, "correlation": correlation,
           "steps": int(true.size)}
    if events is not None:
        out["events"] = int(events.sum())
        out["event_mse"] = float(np.mean((predicted[events] - true[events]) ** 2)) if events.any() else float("nan")
        out["event_constant_mse"] = float(np.mean((constant - true[events]) ** 2)) if events.any() else float("nan")
    if time_only is not None:
        out["time_only_mse"] = float(np.mean((np.asarray(time_only) - true) ** 2))
    return out



def _sokoban_figures(out: Path, evaluated: dict, memory_histories: dict, controllers: dict, random_returns,
                     evaluation: dict) -> list[Path]:
    """Fig. 54 and Fig. 55 in the thesis's style, the grid state, the open-loop error curves,
    the memories' validation losses, the heads' predictions and the CMA-ES curves."""
    from wmthesis.agents.controller_training import plot_learning_curve
    from wmthesis.envs.sokoban import CELL_NAMES
    from wmthesis.viz import grid_state_figure, image_grid, image_rows

    examples, paths = evaluated["examples"], []
    frames, reconstructions = examples["fig54"]
    fig = image_grid([image for pair in zip(frames, reconstructions) for image in pair], ncols=4,
                     titles=["original", "reconstruction"] * len(frames),
                     suptitle="Fig. 54: vision, originals and their reconstructions")
    paths.append(_save(fig, out / "fig54_reconstructions.png"))
    frame, grid = examples["grid_state"]
    fig = grid_state_figure(frame, grid.reshape(8, 8), CELL_NAMES)
    paths.append(_save(fig, out / "grid_state.png"))

    every = 3
    for variant in SOKOBAN_WM_VARIANTS:
        rows = {}
        for k, (start, truth, prediction) in enumerate(zip(examples["start"], examples["truth"],
                                                           examples["prediction"][variant])):
            rows[f"{k + 1}: truth"] = [start, *truth[every - 1::every]]
            rows[f"{k + 1}: {variant}"] = [start, *prediction[every - 1::every]]
        fig = image_rows(rows)
        fig.suptitle(f"Fig. 55: open-loop rollouts of the {variant} memory (first column: the last real frame; "
                     f"then every {every}rd predicted step)", fontsize=9)
        fig.tight_layout()
        paths.append(_save(fig, out / f"fig55_open_loop_{variant}.png"))
    rows = {"truth": [examples["start"][0], *examples["truth"][0][every - 1::every]]}
    rows |= {variant: [examples["start"][0], *examples["prediction"][variant][0][every - 1::every]]
             for variant in SOKOBAN_WM_VARIANTS}
    fig = image_rows(rows)
    fig.suptitle("Fig. 55: one validation episode, every memory variant", fontsize=9)
    fig.tight_layout()
    paths.append(_save(fig, out / "fig55_open_loop_variants.png"))

    curves = {**{v: evaluated["memory"][v]["open_loop"] for v in SOKOBAN_WM_VARIANTS}, **evaluated["baselines"]}
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
    paths.append(_save(fig, out / "open_loop_error.png"))

    fig, axes = plt.subplots(1, 5, figsize=(19, 3.2))
    panels = {("rgb", "mdn"): 0, ("rgb", "deterministic"): 1, ("grid", "mdn"): 2, ("grid", "deterministic"): 2}
    for variant, history in memory_histories.items():
        source, kind, _ = SOKOBAN_WM_VARIANTS[variant]
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
    paths.append(_save(fig, out / "memory_losses.png"))

    auxiliary = [v for v, (_, _, aux) in SOKOBAN_WM_VARIANTS.items() if aux]
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
    paths.append(_save(fig, out / "auxiliary_heads.png"))

    for variant, controller in controllers.items():
        fig, ax = plt.subplots(figsize=(5, 3))
        plot_learning_curve(controller["run"].curve, ax=ax, title=f"CMA-ES, controller on [z h] of {variant}")
        ax.axhline(float(np.mean(random_returns)), color="r", ls="--", lw=1, label="random play, test levels")
        ax.legend(fontsize=7)
        paths.append(_save(fig, out / f"cmaes_curve_{variant}.png"))
    return paths


def _sokoban_recording(path: Path, evaluated: dict) -> Path:
    """A rerun recording of one validation episode's open loop: the truth beside every variant."""
    from wmthesis.metrics import horizon_errors
    from wmthesis.viz import record_frames

    examples = evaluated["examples"]
    truth = examples["truth"][0]
    streams = {"truth": truth, **{f"prediction/{v}": examples["prediction"][v][0] for v in SOKOBAN_WM_VARIANTS}}
    scalars = {f"pixel_error/{v}": horizon_errors(truth, examples["prediction"][v][0]) for v in SOKOBAN_WM_VARIANTS}
    return record_frames(path, streams, scalars)
