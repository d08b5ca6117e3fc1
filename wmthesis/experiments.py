"""The thesis's experiments end to end, as used by ``python -m wmthesis reproduce NAME``.

Each experiment writes its artifacts (stores, checkpoints) under ``data/<profile>/<name>/``
and its results (figures, ``metrics.json``, rerun recordings) under
``data/results/<name>/<profile>-seed<seed>/`` (PlaNet's: one subfolder per variant).
Every step skips work whose artifact exists, so re-running resumes.
"""
from __future__ import annotations

import dataclasses
import json
import os
import platform
import time
from datetime import date
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from wmthesis.config import CollectConfig, ControllerConfig, MemoryConfig, VisionConfig, for_profile, profile_name
from wmthesis.utils import atomic_path, check_choice, data_dir, derive_seeds

EXPERIMENTS = ("sokoban-wm", "boxing-wm", "boxing-wm-alphazero", "planet-sokoban", "planet-boxing", "planet-freeway")

# Published numbers (DESIGN.md) shown beside ours.
BOXING_REFERENCE = {"random": 0.1, "human": 12.1, "thesis World Models": "above 18"}


def reproduce(name: str, profile: str | None = None, seed: int = 0, variant: str | None = None,
              progress: bool = True) -> dict:
    """Run experiment ``name`` (one of :data:`EXPERIMENTS`) and return its metrics.

    ``variant`` selects a variant of experiments that have them (PlaNet's, AlphaZero's); others
    refuse one.
    """
    check_choice("experiment", name, EXPERIMENTS)
    if name == "sokoban-wm":
        if variant is not None:
            raise ValueError(f"experiment {name!r} has no variants, got {variant!r}")
        return sokoban_world_models(profile, seed, progress)
    if name == "boxing-wm":
        if variant is not None:
            raise ValueError(f"experiment {name!r} has no variants, got {variant!r}")
        return boxing_world_models(profile, seed, progress)
    if name == "boxing-wm-alphazero":
        return boxing_wm_alphazero(profile, seed, variant, progress)
    if name in PLANET_GAMES:
        return planet_experiment(name, profile, seed, variant, progress)
    raise AssertionError(f"experiment {name!r} is listed but not wired")


def reproduce_all(runs, profile: str | None = None, seed: int = 0, workers: int = 1) -> dict:
    """Run several experiments, ``workers`` at a time, and return their metrics by run.

    ``runs``: ``(name, variant)`` pairs (variant None: the default). With ``workers`` > 1 each
    run goes to a spawned process with ``cpu_count // workers`` torch threads (runs are
    independent; each resumes from its own artifacts). Returns ``{(name, variant): metrics}``
    in the order of ``runs``.
    """
    import concurrent.futures
    import multiprocessing

    runs = [tuple(run) for run in runs]
    for name, _ in runs:
        check_choice("experiment", name, EXPERIMENTS)
    profile = profile_name(profile)
    if workers <= 1:
        return {run: reproduce(run[0], profile, seed, variant=run[1], progress=False) for run in runs}
    threads = max(1, (os.cpu_count() or 1) // workers)
    with concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                                initializer=_set_threads, initargs=(threads,)) as executor:
        futures = {run: executor.submit(reproduce, run[0], profile, seed, variant=run[1], progress=False)
                   for run in runs}
        return {run: future.result() for run, future in futures.items()}


def _set_threads(threads: int) -> None:
    import torch

    torch.set_num_threads(threads)


def boxing_world_models(profile: str | None = None, seed: int = 0, progress: bool = True) -> dict:
    """Thesis 5.4.1: World Models on Boxing, random rollouts -> VAE -> MDN-RNN -> CMA-ES.

    Returns the metrics dict (also written to ``metrics.json``): the controller's score over
    10 full evaluation episodes with varied starts, the learning curves, the open-loop error.
    """
    from wmthesis.agents.controller_training import VAEVision, evaluate_population, make_game, train_controller
    from wmthesis.agents.world_models import encode_store, open_loop, reconstruct, train_memory, train_vision
    from wmthesis.data import EpisodeStore, collect
    from wmthesis.metrics import score_summary
    from wmthesis.viz import record_frames

    profile = profile_name(profile)
    started = time.time()
    work = data_dir(profile, "boxing-wm", f"seed{seed}")
    out = data_dir("results", "boxing-wm", f"{profile}-seed{seed}")
    collect_cfg = for_profile(CollectConfig, profile)
    store = collect("boxing", collect_cfg.episodes, work / "random.h5", workers=collect_cfg.workers, seed=seed,
                    preprocessing="world_models", max_steps=collect_cfg.max_steps, progress=progress)
    vae, vision_history = train_vision(store, work, for_profile(VisionConfig, profile), seed=seed, progress=progress)
    latents = encode_store(store, vae, work / "latents.h5", progress=progress)
    memory, memory_history = train_memory(latents, work, for_profile(MemoryConfig, profile), n_actions=18,
                                          seed=seed, progress=progress)
    vision = VAEVision(vae)
    controller_cfg = for_profile(ControllerConfig, profile, seed=seed)
    run = train_controller("boxing", vision, memory, controller_cfg, out_dir=work / "controller", progress=progress)

    n_eval = 2 if profile == "smoke" else 10
    game = make_game("boxing", n_eval, noop_max=controller_cfg.noop_max)
    returns, _ = evaluate_population(run.mean_params[None], game, vision, memory,
                                     seeds=np.arange(n_eval) + 1_000_000 + seed,
                                     max_steps=controller_cfg.max_steps if profile == "smoke" else None)
    game.close()

    with EpisodeStore(store) as episodes:
        episode = episodes.episode(len(episodes) - 1)  # a validation episode
        random_returns = [float(episodes.episode(i)["rewards"].sum()) for i in range(len(episodes))]
    context, horizon = (10, 10) if profile == "smoke" else (60, 30)
    rollout = open_loop(vae, memory, episode["observations"], episode["actions"], context=context, horizon=horizon)
    figures = _boxing_figures(out, episode["observations"], reconstruct(vae, episode["observations"][::25][:8]),
                              rollout, run.curve)
    recording = record_frames(out / "open_loop.rrd", {"truth": rollout["truth"], "prediction": rollout["prediction"]},
                              {"pixel_error": rollout["pixel_error"]})
    metrics = {
        "experiment": "boxing-wm", "profile": profile, "seed": seed, "date": date.today().isoformat(),
        "machine": f"{platform.node()} ({platform.machine()}, {os.cpu_count()} cores)",
        "wall_seconds": round(time.time() - started, 1),
        "score": score_summary(returns[0]),
        "random_play_in_store": score_summary(random_returns),
        "reference": BOXING_REFERENCE,
        "controller_curve": run.curve, "vision_history": vision_history, "memory_history": memory_history,
        "open_loop_pixel_error": rollout["pixel_error"].tolist(),
        "files": {"figures": [str(f) for f in figures], "recording": str(recording)},
    }
    metrics["first_run_wall_seconds"] = _first_run_seconds(out / "metrics.json", metrics["wall_seconds"])
    with atomic_path(out / "metrics.json") as tmp:
        tmp.write_text(json.dumps(metrics, indent=1, default=float))
    return metrics


def _first_run_seconds(path: Path, seconds: float) -> float:
    """The wall time of the run that computed everything: kept from an earlier metrics file
    (a resumed or cached run is faster), else this run's."""
    try:
        return json.loads(path.read_text())["first_run_wall_seconds"]
    except (OSError, ValueError, KeyError):
        return seconds


def _boxing_figures(out: Path, frames, reconstructions, rollout, curve) -> list[Path]:
    from wmthesis.agents.controller_training import plot_learning_curve
    from wmthesis.viz import image_rows

    paths = []
    fig = image_rows({"original": list(frames[::25][:8]), "reconstruction": list(reconstructions)})
    fig.suptitle("Fig. 56: vision reconstructions")
    paths.append(_save(fig, out / "fig56_reconstructions.png"))
    fig = image_rows({"truth": list(rollout["truth"][::3]), "memory": list(rollout["prediction"][::3])})
    fig.suptitle("Fig. 57: open-loop memory rollout (every 3rd step)")
    paths.append(_save(fig, out / "fig57_open_loop.png"))
    fig, ax = plt.subplots(figsize=(5, 3))
    plot_learning_curve(curve, ax=ax, title="CMA-ES fitness per generation")
    paths.append(_save(fig, out / "cmaes_curve.png"))
    return paths


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=80, bbox_inches="tight")
    plt.close(fig)
    return path


# ---------------------------------------------------------------------------- PlaNet (5.5, 5.6)
# Experiment -> (environment, the thesis's variants for that game, the default variant).
PLANET_GAMES = {
    "planet-sokoban": ("sokoban-small", ("unchanged",), "unchanged"),                       # 5.5.1
    "planet-boxing": ("boxing", ("unchanged", "action-repeat", "decoder-variance", "free-nats"),
                      "unchanged"),                                                          # 5.6.1-5.6.4
    "planet-freeway": ("freeway", ("freeway-tuned", "long-horizon"), "freeway-tuned"),       # 5.6.5-5.6.6
}

PLANET_REFERENCE = {
    "planet-boxing": {"random": 0.1, "human": 12.1, "thesis PlaNet 100k": "6.2±10.7",
                      "thesis PlaNet 500k": "35.2±8.3", "thesis PlaNet 1M": "78.2±19.1",
                      "SimPLe 100k": 7.8, "DreamerV3 100k": 78.0},
    "planet-freeway": {"random": 0.0, "human": 29.6, "thesis PlaNet": 0.0, "DreamerV3 100k": 0.0,
                       "SimPLe": 16.7, "STORM": 33.5},
    # The thesis judged Sokoban-small's PlaNet by its open-loop rollouts (Fig. 58), no score.
    "planet-sokoban": {},
}

# Atari (Boxing, Freeway) changes on top of the profile. Smoke: the profile's 80 steps (the
# action-repeat variant's 40 still hold one planner episode after its two seed episodes).
# Quick: 2 seed and 3 planner bouts (the budget of 8,000 agent steps ends within the fifth
# bout: ~8,900 steps) and 300 updates, ~15 CPU-minutes a variant, so that notebook 05's six
# variants fit an hour on 2 cores. Budgets count agent steps at the thesis's action repeat of
# 4 (frames / 4): a variant with another action repeat gets the same frames.
ATARI_CHANGES = {"smoke": {}, "quick": dict(seed_episodes=2, env_steps=8_000), "thesis": {}}

# Sokoban-small needs its own sizes: its episodes are at most 120 steps, where a Boxing bout is
# ~1,780 agent steps, so the profiles' ``env_steps`` (sized for Boxing) would give Sokoban 10-15
# times as many planner episodes, each followed by ``update_steps`` updates. These changes keep
# Sokoban's number of updates near a Boxing run's in the thesis profile (~2M: ~560 episodes x
# 5000); quick: ~1,250 updates. The thesis does not state Sokoban's budget.
SOKOBAN_CHANGES = {
    "smoke": dict(env_steps=48),
    "quick": dict(env_steps=3_000, update_steps=50, test_interval=5, test_episodes=2),
    "thesis": dict(env_steps=50_000),
}

# Greedy evaluation episodes after training (not in the thesis, which reported 5 runs' tests).
PLANET_EVAL_EPISODES = {"smoke": 2, "quick": 3, "thesis": 10}

# Open-loop evaluation, (context, predicted steps, cut-off horizon) per profile and game kind:
# the error at the cut-off horizon is the number reported in metrics.json.
PLANET_OPEN_LOOP = {
    "smoke": {"sokoban": (4, 8, 4), "atari": (4, 8, 4)},
    "quick": {"sokoban": (5, 15, 10), "atari": (5, 30, 15)},
    "thesis": {"sokoban": (5, 15, 10), "atari": (5, 30, 15)},
}


def planet_variants(name: str) -> tuple[str, ...]:
    """The :data:`~wmthesis.agents.planet.VARIANTS` valid for PlaNet experiment ``name``."""
    check_choice("PlaNet experiment", name, PLANET_GAMES)
    return PLANET_GAMES[name][1]


def planet_experiment(name: str, profile: str | None = None, seed: int = 0, variant: str | None = None,
                      progress: bool = True) -> dict:
    """Thesis 5.5.1 (``planet-sokoban``) and 5.6.1-5.6.6 (``planet-boxing``, ``planet-freeway``):
    train PlaNet with ``variant`` (see :data:`PLANET_GAMES`), evaluate it greedily, roll it out
    open-loop, and write the figures, a rerun recording of truth vs prediction and ``metrics.json``.

    Artifacts (episode store, checkpoint) go under ``data/<profile>/<name>/<variant>-seed<seed>/``,
    results under ``data/results/<name>/<profile>-seed<seed>/<variant>/``. Re-running resumes:
    training continues from its checkpoint (a finished run does no work), the evaluation is
    cached, and when ``metrics.json`` matches the trained run and its files exist it is returned
    as it is. Returns the metrics: ``score`` (greedy test episodes), ``open_loop`` (error per
    horizon and at the cut-off), the learning ``curve``, ``reference`` (published numbers).
    """
    from wmthesis.agents.planet import (VARIANTS, horizon_error_figure, learning_curve_figure, load_planet,
                                        open_loop_figure, train_planet, with_variant)
    from wmthesis.data import EpisodeStore
    from wmthesis.envs import ATARI_GAMES
    from wmthesis.config import PlaNetConfig
    from wmthesis.metrics import error_at, horizon_errors, score_summary
    from wmthesis.viz import record_frames

    env_name, valid, default = PLANET_GAMES[name]
    variant = default if variant is None else variant
    check_choice(f"variant of {name}", variant, valid)
    assert variant in VARIANTS, variant
    profile = profile_name(profile)
    started = time.time()
    work = data_dir(profile, name, f"{variant}-seed{seed}")
    out = data_dir("results", name, f"{profile}-seed{seed}", variant)
    config = for_profile(PlaNetConfig, profile,
                         **(SOKOBAN_CHANGES if env_name == "sokoban-small" else ATARI_CHANGES)[profile])
    repeat = with_variant(config, variant).action_repeat
    if env_name in ATARI_GAMES and repeat != config.action_repeat:      # the same frames
        config = dataclasses.replace(config, env_steps=config.env_steps * config.action_repeat // repeat)

    run = train_planet(env_name, config, work, seed=seed, variant=variant, progress=progress)
    n_eval = PLANET_EVAL_EPISODES[profile]
    cached = _read_json(out / "metrics.json")
    if (cached is not None and cached.get("updates") == run["updates"] and cached.get("env_steps") == run["env_steps"]
            and cached["score"]["episodes"] == n_eval
            and all(Path(f).is_file() and Path(f).stat().st_size > 0
                    for f in [*cached["files"]["figures"], cached["files"]["recording"]])):
        return cached

    model, trained_config, meta = load_planet(work)
    returns = _planet_evaluate(model, trained_config, env_name, work, seed, n_eval, run["updates"])
    context, horizon, cutoff = PLANET_OPEN_LOOP[profile]["atari" if env_name in ATARI_GAMES else "sokoban"]
    with EpisodeStore(work / "episodes.h5") as store:
        random_returns = [float(store.episode(i)["rewards"].sum()) for i in range(trained_config.seed_episodes)]
        rollout = _planet_open_loop(model, store, context + horizon, context, trained_config, seed)
    title = {"planet-sokoban": "Fig. 58", "planet-boxing": "Fig. 59/510", "planet-freeway": "Fig. 511"}[name]
    label = f"{env_name}, {variant}"
    figures = [
        _save(open_loop_figure(rollout, sequences=1 if profile == "smoke" else 3,
                               columns=min(context + horizon, 20),
                               title=f"{title}: {label}, open-loop after {context} context frames"),
              out / "open_loop.png"),
        _save(horizon_error_figure({label: rollout["mse"]}, title=f"open-loop error, {label}"),
              out / "horizon_error.png"),
    ]
    references = {key: value for key, value in PLANET_REFERENCE[name].items()
                  if key in ("random", "human") and isinstance(value, float)}
    if not references:
        references = {"random (seed episodes)": float(np.mean(random_returns))}
    figures.append(_save(learning_curve_figure({label: meta["curve"]}, references=references,
                                               title=f"PlaNet {label}: test score"), out / "learning_curve.png"))
    recording = record_frames(out / "open_loop.rrd",
                              {"truth": rollout["truth"][0], "prediction": rollout["prediction"][0]},
                              {"pixel_error": horizon_errors(rollout["truth"][0], rollout["prediction"][0])})
    metrics = {
        "experiment": name, "env": env_name, "variant": variant, "profile": profile, "seed": seed,
        "date": date.today().isoformat(),
        "machine": f"{platform.node()} ({platform.machine()}, {os.cpu_count()} cores)",
        "wall_seconds": round(run["seconds"] + time.time() - started, 1),
        "env_steps": run["env_steps"], "updates": run["updates"], "episodes": run["episodes"],
        "score": score_summary(returns),
        "final_test": run["final_test"],
        "random_play_in_store": score_summary(random_returns),
        "open_loop": {"context": context, "horizon": horizon, "cutoff": cutoff,
                      "error_at_cutoff": error_at(rollout["mse"], cutoff),
                      "mse": [float(v) for v in rollout["mse"]]},
        "reference": PLANET_REFERENCE[name],
        "config": run["config"], "curve": meta["curve"],
        "files": {"figures": [str(f) for f in figures], "recording": str(recording)},
    }
    with atomic_path(out / "metrics.json") as tmp:
        tmp.write_text(json.dumps(metrics, indent=1, default=float))
    return metrics


def _planet_evaluate(model, config, env_name: str, work: Path, seed: int, n_eval: int, updates: int) -> list[float]:
    """``n_eval`` greedy planner episodes (seeds from (seed, 2, k), apart from training's
    tests); cached in ``evaluation.json`` for the checkpoint's number of updates."""
    from wmthesis.agents.planet import PlanetMind, make_planet_env, planet_interpreter
    from wmthesis.core import loop

    path = work / "evaluation.json"
    cached = _read_json(path)
    if cached is not None and cached["updates"] == updates and len(cached["returns"]) == n_eval:
        return cached["returns"]
    env = make_planet_env(env_name, config)
    returns = []
    try:
        for k in range(n_eval):
            env_seed, mind_seed = derive_seeds(seed, 2, k, n=2)
            mind = PlanetMind.from_config(model, config, int(mind_seed))
            history = loop(env, mind, planet_interpreter(config.bits), policy="deterministic",
                           callbacks=[mind], seed=int(env_seed), train_mode=False)
            returns.append(float(history[0]["return"]))
    finally:
        env.close()
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps({"updates": updates, "returns": returns}))
    return returns


def _planet_open_loop(model, store, length: int, context: int, config, seed: int, sequences: int = 6) -> dict:
    """:func:`~wmthesis.agents.planet.open_loop` on chunks of the most recent planner episodes
    long enough (the last one was collected after the final update: never trained on)."""
    import torch

    from wmthesis.agents.planet import open_loop

    lengths = store.episode_lengths
    long_enough = [i for i in range(config.seed_episodes, len(store)) if lengths[i] >= length]
    if not long_enough:
        long_enough = [i for i in range(len(store)) if lengths[i] >= length]
    if not long_enough:
        raise ValueError(f"{store.path}: no episode of {length} steps for the open-loop evaluation")
    batch = store.sample_chunks(sequences, length, np.random.default_rng(seed), episodes=long_enough[-3:])
    generator = torch.Generator(next(model.parameters()).device).manual_seed(seed)
    return open_loop(model, batch["observations"], batch["actions"], context=context, bits=config.bits,
                     generator=generator)


def _read_json(path: Path) -> dict | None:
    return json.loads(path.read_text()) if path.is_file() else None


# ---------------------------------------------------------------------------- World Models + AlphaZero (5.4.2)
ALPHAZERO_REFERENCE = {"random": 0.1, "human": 12.1,
                       "thesis World Models + AlphaZero": "no score: 'did not train to properly plan', abandoned"}
ALPHAZERO_DIAGNOSIS_DEPTH = {"smoke": 5, "quick": 10, "thesis": 10}
RECORDING_STEPS = 400  # the rerun recording shows the first steps of one evaluation game


def boxing_wm_alphazero(profile: str | None = None, seed: int = 0, variant: str | None = None,
                        progress: bool = True) -> dict:
    """Thesis 5.4.2: World Models + AlphaZero on Boxing, and why the thesis's version fails.

    Reuses the boxing-wm pipeline's random rollouts, vision and latents (the same artifacts
    under ``data/<profile>/boxing-wm/seed<seed>/``, cached), trains a deterministic memory in
    its own folder ``data/<profile>/boxing-wm-alphazero/seed<seed>/``, then self-play for each
    variant of :data:`~wmthesis.agents.alphazero.VARIANTS` (``variant=None``: all of them, side
    by side; one name: that one only), each resumable from its checkpoint. Every variant, the
    boxing-wm controller (when its run exists) and random play then play the same greedy
    evaluation games (same no-op starts). Diagnosis: the memory's reward error along the search
    depth, whether a linear value on ``[z h]`` predicts the random rollouts' returns at all, the
    value scale, the spread of root Q, ties and the actions taken.

    Results under ``data/results/boxing-wm-alphazero/<profile>-seed<seed>/`` (one variant: in
    its subfolder): figures, a rerun recording of an evaluation game, ``metrics.json``. Returns
    the metrics; ``score`` is the last variant's (``improved`` when all run).
    """
    from wmthesis.agents import alphazero as az
    from wmthesis.agents.controller_training import VAEVision
    from wmthesis.agents.world_models import LatentStore, encode_store, train_memory, train_vision
    from wmthesis.config import AlphaZeroConfig
    from wmthesis.data import EpisodeStore, collect
    from wmthesis.metrics import score_summary
    from wmthesis.viz import record_frames

    variants = tuple(az.VARIANTS) if variant is None else (variant,)
    check_choice("variant of boxing-wm-alphazero", variants[0], az.VARIANTS)
    profile = profile_name(profile)
    started = time.time()
    wm = data_dir(profile, "boxing-wm", f"seed{seed}")
    work = data_dir(profile, "boxing-wm-alphazero", f"seed{seed}")
    out = data_dir("results", "boxing-wm-alphazero", f"{profile}-seed{seed}", *(() if variant is None else (variant,)))
    collect_cfg = for_profile(CollectConfig, profile)
    store = collect("boxing", collect_cfg.episodes, wm / "random.h5", workers=collect_cfg.workers, seed=seed,
                    preprocessing="world_models", max_steps=collect_cfg.max_steps, progress=progress)
    vae, _ = train_vision(store, wm, for_profile(VisionConfig, profile), seed=seed, progress=progress)
    latents = encode_store(store, vae, wm / "latents.h5", progress=progress)
    memory, memory_history = train_memory(latents, work, for_profile(MemoryConfig, profile, kind="deterministic"),
                                          n_actions=18, seed=seed, progress=progress)
    vision = VAEVision(vae)

    configs, runs, games = {}, {}, {}
    for name in variants:
        configs[name] = cfg = for_profile(AlphaZeroConfig, profile, **az.VARIANTS[name])
        run = az.train_alphazero(lambda: az.boxing_env(cfg.noop_max), vision, memory, cfg, out_dir=work / name,
                                 seed=seed, progress=progress)
        runs[name] = run.summary()
        games[name] = _alphazero_evaluate(run, vision, memory, cfg, work / name, seed)
    cfg = configs[variants[-1]]
    baselines = _boxing_baselines(profile, wm, work, vision, cfg, seed)
    with EpisodeStore(store) as episodes:  # random play over the self-play games' length, for the curve
        random_in_store = [float(episodes.episode(i)["rewards"][:cfg.max_steps].sum()) for i in range(len(episodes))]

    mdp = az.LatentMDP(memory)
    all_games = [game for name in variants for game in games[name]]
    depth = ALPHAZERO_DIAGNOSIS_DEPTH[profile]
    reward_error = az.reward_error_by_depth(mdp, all_games, depth)
    value_fit = az.value_predictability(mdp, LatentStore(latents), cfg.gamma, cfg.n_step)
    search = {name: az.search_statistics(games[name], cfg.gamma, cfg.c, cfg.simulations) for name in variants}
    figures = [
        _save(az.plot_self_play(runs, {f"random play, first {cfg.max_steps or 'all'} steps (store)":
                                       float(np.mean(random_in_store))}), out / "self_play_curve.png"),
        _save(az.plot_search(games, cfg.gamma, cfg.c, cfg.simulations), out / "search_statistics.png"),
        _save(az.plot_reward_error(reward_error, np.concatenate([g.depths for g in all_games])),
              out / "reward_error_by_depth.png"),
        _save(az.plot_visits(games[variants[-1]][0]), out / "visit_distributions.png"),
    ]
    scores = {f"AlphaZero {name}": score_summary([g.score for g in games[name]]) for name in variants}
    scores.update({name: score_summary(returns) for name, returns in baselines["returns"].items()})
    figures.append(_save(_score_figure(scores), out / "scores.png"))
    shown = games[variants[-1]][0]
    recording = record_frames(out / "evaluation_game.rrd", {"observation": shown.frames},
                              {name: values[:RECORDING_STEPS] for name, values in
                               (("reward", shown.rewards), ("predicted_reward", shown.predicted_rewards),
                                ("root_value", shown.root_values))})
    metrics = {
        "experiment": "boxing-wm-alphazero", "profile": profile, "seed": seed, "variants": list(variants),
        "date": date.today().isoformat(),
        "machine": f"{platform.node()} ({platform.machine()}, {os.cpu_count()} cores)",
        "wall_seconds": round(time.time() - started, 1),
        "score": scores[f"AlphaZero {variants[-1]}"], "scores": scores,
        "evaluation": {"episodes": cfg.eval_episodes, "max_steps": cfg.eval_max_steps, "notes": baselines["notes"]},
        "random_play_in_store": {"max_steps": cfg.max_steps, **score_summary(random_in_store)},
        "reference": ALPHAZERO_REFERENCE,
        "runs": runs,
        "diagnosis": {"reward_error": reward_error, "value_fit_on_random_rollouts": value_fit, "search": {name: {
            "value_return_corr": s["value_return_corr"], "mean_abs_root_value": float(np.abs(s["root_value"]).mean()),
            "mean_abs_return": float(np.abs(s["returns"]).mean()), "median_q_spread": float(np.median(s["q_spread"])),
            "prior_bonus": s["prior_bonus"], "mean_visit_entropy": float(s["visit_entropy"].mean()),
            "top_count_tied": s["tied"],
            "noop_fraction": float(np.mean(np.concatenate([g.actions for g in games[name]]) == 0)),
            "median_search_depth": float(np.median(np.concatenate([g.depths for g in games[name]])))}
            for name, s in search.items()}},
        "memory_history": memory_history,
        "files": {"figures": [str(f) for f in figures], "recording": str(recording)},
    }
    metrics["first_run_wall_seconds"] = _first_run_seconds(out / "metrics.json", metrics["wall_seconds"])
    with atomic_path(out / "metrics.json") as tmp:
        tmp.write_text(json.dumps(metrics, indent=1, default=float))
    return metrics


def _evaluation_seeds(seed: int, episodes: int) -> list[int]:
    """The seed of each evaluation game, shared by every agent compared (through
    :func:`~wmthesis.agents.alphazero.game_seeds`: the same no-op starts)."""
    return [int(derive_seeds(seed, 3, k)[0]) for k in range(episodes)]


def _alphazero_evaluate(run, vision, memory, cfg, work: Path, seed: int) -> list:
    """``cfg.eval_episodes`` greedy games of the trained heads (the first keeps its frames);
    cached in ``evaluation.pkl`` for the run's number of games."""
    import pickle

    from wmthesis.agents import alphazero as az

    path = work / "evaluation.pkl"
    key = {"games": run.games, "episodes": cfg.eval_episodes, "max_steps": cfg.eval_max_steps}
    if path.is_file():
        with open(path, "rb") as f:
            cached = pickle.load(f)
        if cached["key"] == key:
            return cached["games"]
    mind = az.AlphaZeroMind(vision, az.LatentMDP(memory), az.Evaluator(run.heads), cfg)
    env = az.boxing_env(cfg.noop_max)
    games = []
    try:
        for k, game_seed in enumerate(_evaluation_seeds(seed, cfg.eval_episodes)):
            mind.keep_frames = k == 0
            game = az.play(env, mind, game_seed, k, train_mode=False, max_steps=cfg.eval_max_steps)
            if game.frames is not None:
                game.frames = game.frames[:RECORDING_STEPS]
            games.append(game)
    finally:
        env.close()
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        pickle.dump({"key": key, "games": games}, f)
    return games


def _boxing_baselines(profile: str, wm: Path, work: Path, vision, cfg, seed: int) -> dict:
    """Random play and the boxing-wm controller (when its run exists) on the evaluation games;
    cached in ``baselines.json``. Returns ``returns`` by agent and ``notes``."""
    from wmthesis.agents.alphazero import boxing_env, game_seeds
    from wmthesis.agents.controller_training import ControllerMind, _fingerprint, load_run
    from wmthesis.agents.world_models import make_memory
    from wmthesis.core import RandomMind, loop
    from wmthesis.training import load_weights

    controller_path, memory_path = wm / "controller" / "controller.pkl", wm / "memory-mdn.best.pt"
    have_controller = controller_path.is_file() and memory_path.is_file()
    key = {"episodes": cfg.eval_episodes, "max_steps": cfg.eval_max_steps,
           "controller_mtime": controller_path.stat().st_mtime_ns if have_controller else None}
    cached = _read_json(work / "baselines.json")
    if cached is not None and cached["key"] == key:
        return cached
    minds, notes = {}, []
    minds["random"] = lambda agent_seed: RandomMind(18, agent_seed)
    if have_controller:
        run = load_run(controller_path)
        mdn = load_weights(memory_path, make_memory(16, 18, for_profile(MemoryConfig, profile))).eval()
        if _fingerprint(mdn) == run.task["memory"]:
            controller = run.controller("mean")
            minds[f"World Models controller (notebook 02, generation {run.generation})"] = \
                lambda agent_seed: ControllerMind(vision, mdn, controller)
        else:
            notes.append(f"the controller in {controller_path.parent} was trained on another memory: skipped")
    else:
        notes.append(f"no boxing-wm controller under {wm} (run notebook 02 / `reproduce boxing-wm` first): "
                     "the comparison with it is skipped")
    returns = {}
    env = boxing_env(cfg.noop_max)
    try:
        for name, make_mind in minds.items():
            returns[name] = []
            for game_seed in _evaluation_seeds(seed, cfg.eval_episodes):
                env_seed, agent_seed = game_seeds(game_seed)
                mind = make_mind(agent_seed)
                history = loop(env, mind, policy="deterministic", callbacks=[mind] if name != "random" else None,
                               max_steps=cfg.eval_max_steps, seed=env_seed, train_mode=False)
                returns[name].append(float(history[0]["return"]))
    finally:
        env.close()
    result = {"key": key, "returns": returns, "notes": notes}
    with atomic_path(work / "baselines.json") as tmp:
        tmp.write_text(json.dumps(result, indent=1))
    return result


def _score_figure(scores: dict):
    """Evaluation scores (mean +- std) of every agent, beside random (0.1) and human (12.1)."""
    fig, ax = plt.subplots(figsize=(6, 0.5 + 0.45 * len(scores)))
    names = list(scores)
    ax.barh(names, [scores[n]["mean"] for n in names], xerr=[scores[n]["std"] for n in names], capsize=3,
            color=[f"C{i}" for i in range(len(names))])
    for value, style, label in ((0.1, "--", "random (published)"), (12.1, ":", "human (published)")):
        ax.axvline(value, color="0.4", ls=style, lw=1, label=label)
    ax.invert_yaxis()
    ax.set_xlabel("Boxing score (mean ± std)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


# ---------------------------------------------------------------------------- World Models on Sokoban (5.3)
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
        "experiment": "sokoban-wm", "profile": profile, "seed": seed, "date": date.today().isoformat(),
        "machine": f"{platform.node()} ({platform.machine()}, {os.cpu_count()} cores)",
        "wall_seconds": round(time.time() - started, 1),
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


def _jsonable(value):
    """``value`` with numpy arrays and scalars as lists and numbers, NaN as None (strict JSON)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.integer, np.bool_)):
        return value.item()
    if isinstance(value, (float, np.floating)):
        return None if not np.isfinite(value) else float(value)
    return value


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
