"""World Models on Boxing (thesis 5.4.1): random rollouts -> VAE -> MDN-RNN -> CMA-ES."""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import NamedTuple

import matplotlib.pyplot as plt
import numpy as np

from wmthesis.config import CollectConfig, for_profile, profile_name
from wmthesis.data import EpisodeStore
from wmthesis.declarations import NAMES
from wmthesis.metrics import score_summary
from wmthesis.references import published
from wmthesis.rollouts import collect
from wmthesis.stamp import git_commit
from wmthesis.runs import (first_run_seconds, hold, over_sittings, read_json, releasing_holds, results_folder, run_header,
                           work_folder, write_json)
from wmthesis.viz import image_rows, record_frames, save_figure
from wmthesis.world_models.config import BoxingEvaluationConfig, MemoryConfig, VisionConfig
from wmthesis.world_models.agent import save_agent
from wmthesis.world_models.evolution import score_bouts, train_controller
from wmthesis.world_models.figures import plot_learning_curve
from wmthesis.world_models.prediction import open_loop, open_loop_errors
from wmthesis.training import trained_seconds
from wmthesis.world_models.train import encode_store, reconstruct, train_memory, train_vision
from wmthesis.world_models.variants import BOXING_WM, agent_path, controller_config, controller_folder
from wmthesis.world_models.vision import VAEVision


@releasing_holds
def boxing_world_models(profile: str | None = None, seed: int = 0, variant: str | None = None,
                        progress: bool = True) -> dict:
    """Thesis 5.4.1: World Models on Boxing, random rollouts -> VAE -> MDN-RNN -> CMA-ES.

    Returns the metrics dict (also written to ``metrics.json``): the controller's score over
    10 full evaluation episodes with varied starts, the learning curves, the open-loop error.
    """
    chosen = BOXING_WM.check(variant)
    profile = profile_name(profile)
    started = time.time()
    wm = _world_model(profile, seed, progress)
    modelling = time.time() - started  # this call's world model: a resumed or cached one trained before it
    work, store, vae, vision, memory = wm.work, wm.store, wm.vae, wm.vision, wm.memory
    out = results_folder(NAMES.boxing_wm, profile, seed, BOXING_WM.folder_name(chosen.name))
    controller_cfg = controller_config(profile, seed, chosen.name)
    evolving = time.time()
    run = train_controller("boxing", vision, memory, controller_cfg, out_dir=controller_folder(work, chosen.name),
                           progress=progress)
    evolving = time.time() - evolving  # this call's evolution: a resumed run evolved its first generations before
    cached = read_json(out / "metrics.json")
    if (cached is not None and cached.get("controller_curve") == json.loads(json.dumps(run.curve, default=float))
            and all(Path(f).is_file() for f in [*cached["files"]["figures"], cached["files"]["recording"],
                                                cached["files"].get("agent", "")])):
        return cached  # this controller's evaluation, figures and recording, made before

    returns = score_bouts(run.mean_params, vision, memory, for_profile(BoxingEvaluationConfig, profile).bouts,
                          controller_cfg.noop_max, controller_cfg.max_steps)
    agent = save_agent(agent_path(work, chosen.name), vae, memory, run, for_profile(MemoryConfig, profile), git_commit())

    with EpisodeStore(store) as episodes:
        episode = episodes.episode(len(episodes) - 1)  # a validation episode
        random_returns = [float(episodes.episode(i)["rewards"].sum()) for i in range(len(episodes))]
        random_steps = episodes.num_steps
    scoring = for_profile(BoxingEvaluationConfig, profile)
    context, horizon = scoring.context, scoring.horizon
    rollout = open_loop(vae, memory, episode["observations"], episode["actions"], context=context, horizon=horizon)
    errors = open_loop_errors(vae, memory, episode, context, horizon)
    figures = _boxing_figures(out, episode["observations"], reconstruct(vae, episode["observations"][::25][:8]),
                              rollout, run.curve)
    recording = record_frames(out / "open_loop.rrd", {"truth": rollout["truth"], "prediction": rollout["prediction"]},
                              {"pixel_error": rollout["pixel_error"]})
    metrics = {
        **run_header(NAMES.boxing_wm, profile, seed, time.time() - started,
                     **({} if BOXING_WM.folder_name(chosen.name) is None else {"variant": chosen.name})),
        "score": score_summary(returns),
        "random_play_in_store": {**score_summary(random_returns), "steps": random_steps},
        "reference": published(NAMES.boxing_wm),
        "controller_curve": run.curve, "vision_history": wm.vision_history, "memory_history": wm.memory_history,
        **{f"open_loop_{k}": v.tolist() if isinstance(v, np.ndarray) else v for k, v in errors.items()},
        "returns": returns.tolist(),
        "files": {"figures": [str(f) for f in figures], "recording": str(recording), "agent": str(agent)},
    }
    evolved = json.loads(json.dumps(run.curve, default=float))  # an earlier file of another controller keeps no time
    seconds = over_sittings(metrics["wall_seconds"], (sum(g["seconds"] for g in run.curve), evolving),
                            (wm.trained_seconds, modelling))
    metrics["first_run_wall_seconds"] = first_run_seconds(out / "metrics.json", seconds,
                                                          lambda earlier: earlier.get("controller_curve") == evolved)
    write_json(out / "metrics.json", metrics, default=float)
    return metrics


class BoxingWorldModel(NamedTuple):
    """The Boxing world model of a profile and seed: its folders (``work``: artifacts,
    ``out``: results), the random rollouts' store path, the VAE and its
    :class:`~wmthesis.world_models.vision.VAEVision`,
    the MDN-RNN memory, the two training histories and the seconds the two trained, over every
    sitting (a resumed or cached model trained before this call)."""

    work: Path
    out: Path
    store: Path
    vae: object
    vision: object
    memory: object
    vision_history: list
    memory_history: list
    trained_seconds: float = 0.0


def _world_model(profile: str, seed: int, progress: bool) -> BoxingWorldModel:
    """Random rollouts -> VAE -> latents -> MDN-RNN under ``data/<profile>/boxing-wm/seed<seed>/``,
    each step cached."""
    work = hold(work_folder(profile, NAMES.boxing_wm, seed))

    collect_cfg, memory_cfg = for_profile(CollectConfig, profile), for_profile(MemoryConfig, profile)
    store = collect("boxing", collect_cfg.episodes, work / "random.h5", workers=collect_cfg.workers, seed=seed,
                    preprocessing="world_models", max_steps=collect_cfg.max_steps, progress=progress)
    vae, vision_history = train_vision(store, work, for_profile(VisionConfig, profile), seed=seed, progress=progress)
    latents = encode_store(store, vae, work / "latents.h5", progress=progress)
    memory, memory_history = train_memory(latents, work, memory_cfg, n_actions=18, seed=seed, progress=progress)
    trained = trained_seconds(work / "vision.pt") + trained_seconds(work / f"memory-{memory_cfg.kind}.pt")
    return BoxingWorldModel(work, results_folder(NAMES.boxing_wm, profile, seed), store, vae,
                            VAEVision(vae), memory, vision_history, memory_history, trained)


def _boxing_figures(out: Path, frames, reconstructions, rollout, curve) -> list[Path]:
    paths = []
    fig = image_rows({"original": list(frames[::25][:8]), "reconstruction": list(reconstructions)},
                     suptitle="Fig. 56: vision reconstructions")
    paths.append(save_figure(fig, out / "fig56_reconstructions.png"))
    fig = image_rows({"truth": list(rollout["truth"][::3]), "memory": list(rollout["prediction"][::3])},
                     suptitle="Fig. 57: open-loop memory rollout (every 3rd step)")
    paths.append(save_figure(fig, out / "fig57_open_loop.png"))
    fig, ax = plt.subplots(figsize=(5, 3))
    plot_learning_curve(curve, ax=ax, title="CMA-ES fitness per generation")
    paths.append(save_figure(fig, out / "cmaes_curve.png"))
    return paths
