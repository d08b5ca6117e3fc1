"""World Models on Sokoban (thesis 5.3.1-5.3.3): one vision, five memory variants (frames or
grid states, stochastic or deterministic, with or without auxiliary heads), three controllers,
and the open-loop measures of what the thesis judged by eye."""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from wmthesis.config import CollectConfig, for_profile, profile_name
from wmthesis.data import EpisodeStore
from wmthesis.declarations import NAMES
from wmthesis.envs.sokoban import ACTIONS
from wmthesis.envs.vector import make_game
from wmthesis.metrics import score_summary
from wmthesis.references import THESIS_SOKOBAN_WM
from wmthesis.rollouts import collect
from wmthesis.runs import (first_run_seconds, hold, jsonable, over_sittings, read_json, releasing_holds, results_folder,
                           run_header, work_folder, write_json)
from wmthesis.variants import no_variant
from wmthesis.world_models.config import ControllerConfig, MemoryConfig, SokobanWorldModelsConfig, VisionConfig
from wmthesis.world_models.evolution import episode_seeds, evaluate_population, random_play, train_controller
from wmthesis.world_models.figures import sokoban_figures, sokoban_recording
from wmthesis.world_models.grid import GridVision, encode_grid_store
from wmthesis.world_models.sokoban import (CONTROLLERS as SOKOBAN_WM_CONTROLLERS, VARIANTS as SOKOBAN_WM_VARIANTS,
                                           check_same_episodes, evaluate_memories, levels_solved)
from wmthesis.training import trained_seconds
from wmthesis.world_models.train import encode_store, train_memory, train_vision
from wmthesis.world_models.vision import VAEVision


SOKOBAN_FRAME_SIZE = 64


def sokoban_wm_configs(profile: str | None = None, seed: int = 0) -> dict:
    """The configs of ``sokoban-wm`` in ``profile``: the profile's, with
    :meth:`~wmthesis.world_models.config.SokobanWorldModelsConfig.changes` on top. Returns ``collect``, ``vision``, ``memory`` (the variants change ``kind`` and
    ``auxiliary``) and ``controller`` (seeded with ``seed``)."""
    profile = profile_name(profile)
    changes = for_profile(SokobanWorldModelsConfig, profile).changes()
    changes["ControllerConfig"] = {**changes.get("ControllerConfig", {}), "seed": seed}
    classes = {"collect": CollectConfig, "vision": VisionConfig, "memory": MemoryConfig,
               "controller": ControllerConfig}
    return {key: for_profile(cls, profile, **changes.get(cls.__name__, {})) for key, cls in classes.items()}


@releasing_holds
def sokoban_world_models(profile: str | None = None, seed: int = 0, variant: str | None = None,
                         progress: bool = True) -> dict:
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
    no_variant(NAMES.sokoban_wm, variant)
    profile = profile_name(profile)
    started = time.time()
    work = hold(work_folder(profile, NAMES.sokoban_wm, seed))
    out = results_folder(NAMES.sokoban_wm, profile, seed)
    configs = sokoban_wm_configs(profile, seed)
    evaluation = for_profile(SokobanWorldModelsConfig, profile).evaluation()
    collect_cfg = configs["collect"]
    stores = {source: collect("sokoban", collect_cfg.episodes, work / f"random-{source}.h5",
                              workers=collect_cfg.workers, seed=seed, max_steps=collect_cfg.max_steps,
                              progress=progress, **_sokoban_options(source))
              for source in ("rgb", "grid")}
    vae, vision_history = train_vision(stores["rgb"], work, configs["vision"], seed=seed, progress=progress)
    latents = {"rgb": encode_store(stores["rgb"], vae, work / "latents-rgb.h5", progress=progress),
               "grid": encode_grid_store(stores["grid"], work / "latents-grid.h5")}
    check_same_episodes(latents)
    memories, memory_histories = {}, {}
    for variant, (source, kind, auxiliary) in SOKOBAN_WM_VARIANTS.items():
        config = dataclasses.replace(configs["memory"], kind=kind, auxiliary=auxiliary)
        memories[variant], memory_histories[variant] = train_memory(
            latents[source], work / f"memory-{variant}", config, n_actions=len(ACTIONS), seed=seed, progress=progress)

    level_seeds = _sokoban_level_seeds(seed, evaluation["levels"])
    controllers = {variant: _sokoban_controller(variant, vae, memories[variant], configs["controller"], work,
                                                level_seeds, progress)
                   for variant in SOKOBAN_WM_CONTROLLERS}
    modelled = time.time() - started  # this call's share of the training below, which every sitting adds to
    trained = trained_seconds(work / "vision.pt") + sum(trained_seconds(work / f"memory-{variant}" / f"memory-{kind}.pt")
                                                        for variant, (_, kind, _) in SOKOBAN_WM_VARIANTS.items())
    evolved = sum(g["seconds"] for c in controllers.values() for g in c["run"].curve)
    random_returns, random_steps = _sokoban_random_play(level_seeds, seed, configs["controller"].max_steps)
    evaluated = evaluate_memories(vae, memories, stores, latents, configs["memory"], evaluation)
    figures = sokoban_figures(out, evaluated, memory_histories, controllers, random_returns, evaluation)
    recording = sokoban_recording(out / "open_loop.rrd", evaluated)
    with EpisodeStore(stores["grid"]) as store:
        store_returns = [float(store.episode(i)["rewards"].sum()) for i in range(len(store))]
        store_steps = store.num_steps

    metrics = {
        **run_header(NAMES.sokoban_wm, profile, seed, time.time() - started),
        "score": score_summary(controllers[SOKOBAN_WM_CONTROLLERS[0]]["returns"]),
        "controllers": {variant: {"score": score_summary(c["returns"]), "solved": c["solved"],
                                  "generations": c["run"].generation, "curve": c["run"].curve}
                        for variant, c in controllers.items()},
        "random_play": {"score": score_summary(random_returns), "solved": levels_solved(random_returns, random_steps)},
        "random_play_in_store": {**score_summary(store_returns), "steps": store_steps},
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
        "reference": THESIS_SOKOBAN_WM,
        "settings": {key: dataclasses.asdict(config) for key, config in configs.items()}
                    | {"variants": SOKOBAN_WM_VARIANTS, "controllers": list(SOKOBAN_WM_CONTROLLERS),
                       "frame_size": SOKOBAN_FRAME_SIZE},
        "files": {"figures": [str(f) for f in figures], "recording": str(recording)},
    }
    metrics["first_run_wall_seconds"] = first_run_seconds(out / "metrics.json",
                                                          over_sittings(metrics["wall_seconds"], (trained + evolved, modelled)))
    metrics = jsonable(metrics)
    write_json(out / "metrics.json", metrics)
    return metrics


def _sokoban_options(source: str) -> dict:
    """The Sokoban options of an input: World Models frames (``rgb``) or grid states."""
    return {"frame_size": SOKOBAN_FRAME_SIZE} if source == "rgb" else {"observation": "grid"}


def _sokoban_level_seeds(seed: int, n: int) -> np.ndarray:
    """The seeds of ``n`` unseen levels scoring the controllers and random play (a stream of
    their own: apart from the collected levels and those CMA-ES trained on)."""
    return episode_seeds(seed, 0, n, stream=2)


def _sokoban_controller(variant: str, vae, memory, cfg, work: Path, level_seeds: np.ndarray, progress: bool) -> dict:
    """Evolve the controller that reads ``[z h]`` of memory ``variant`` (resumable), and play its
    CMA-ES mean on the levels ``level_seeds`` (cached in ``evaluation.json`` per generation)."""
    source = SOKOBAN_WM_VARIANTS[variant][0]
    vision, options = (VAEVision(vae) if source == "rgb" else GridVision()), _sokoban_options(source)
    folder = work / f"controller-{variant}"
    run = train_controller("sokoban", vision, memory, cfg, out_dir=folder, env_options=options, progress=progress)
    path = folder / "evaluation.json"
    cached = read_json(path)
    if cached is None or cached["generation"] != run.generation or cached["seeds"] != level_seeds.tolist():
        game = make_game("sokoban", len(level_seeds), **options)
        try:
            returns, steps = evaluate_population(run.mean_params[None], game, vision, memory, seeds=level_seeds,
                                                 max_steps=cfg.max_steps)
        finally:
            game.close()
        cached = {"generation": run.generation, "seeds": level_seeds.tolist(), "returns": returns[0].tolist(),
                  "steps": steps[0].tolist()}
        write_json(path, cached, indent=None)
    return {"run": run, "returns": cached["returns"], "steps": cached["steps"],
            "solved": levels_solved(cached["returns"], cached["steps"])}


def _sokoban_random_play(level_seeds: np.ndarray, seed: int, max_steps: int | None) -> tuple[np.ndarray, np.ndarray]:
    """Random play on the controllers' levels (grid observations: the same levels and rules, no drawing)."""
    game = make_game("sokoban", len(level_seeds), observation="grid")
    try:
        return random_play(game, level_seeds, seed=seed, max_steps=max_steps)
    finally:
        game.close()
