"""PlaNet (thesis 5.5.1 on Sokoban-small, 5.6.1-5.6.6 on Boxing and Freeway): the thesis's
variants per game, the changes to the profiles, training, greedy evaluation and open-loop rollouts."""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import torch

from wmthesis.config import for_profile, profile_name
from wmthesis.data import EpisodeStore
from wmthesis.declarations import NAMES
from wmthesis.envs import ATARI_GAMES
from wmthesis.metrics import error_at, horizon_errors, score_summary
from wmthesis.planet.agent import play_greedy
from wmthesis.planet.agent_file import AGENT_NAME, save_agent
from wmthesis.planet.config import PlanetEvaluationConfig
from wmthesis.planet.figures import horizon_error_figure, learning_curve_figure, open_loop_figure
from wmthesis.planet.prediction import open_loop
from wmthesis.planet.profiles import planet_config
from wmthesis.planet.train import load_planet, same_training, train_planet, with_variant
from wmthesis.planet.frames import make_planet_env
from wmthesis.planet.variants import ENVIRONMENTS, REGISTRIES
from wmthesis.references import HUMAN, RANDOM, published
from wmthesis.runs import hold, read_json, releasing_holds, results_folder, run_header, work_folder, write_json
from wmthesis.stamp import git_commit
from wmthesis.utils import check_choice, derive_seeds
from wmthesis.viz import record_frames, save_figure

# Experiment -> (environment, its variants' names, the default's name), from its registry.
PLANET_GAMES = {name: (ENVIRONMENTS[name], tuple(registry), registry.default.name) for name, registry in REGISTRIES.items()}




def planet_variants(name: str) -> tuple[str, ...]:
    """The variants of PlaNet experiment ``name`` (:mod:`~wmthesis.planet.variants`)."""
    check_choice("PlaNet experiment", name, PLANET_GAMES)
    return PLANET_GAMES[name][1]


@releasing_holds
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
    env_name = ENVIRONMENTS[name]
    variant = REGISTRIES[name].check(variant).name
    profile = profile_name(profile)
    work = hold(work_folder(profile, name, seed, variant))
    out = results_folder(name, profile, seed, variant)
    config = planet_config(env_name, profile)
    repeat = with_variant(config, variant).action_repeat
    if env_name in ATARI_GAMES and repeat != config.action_repeat:      # the same frames
        config = dataclasses.replace(config, env_steps=config.env_steps * config.action_repeat // repeat)

    run = train_planet(env_name, config, work, seed=seed, variant=variant, progress=progress)
    started = time.time()  # run["seconds"] holds the training, over every resume; the evaluation is added
    scoring = for_profile(PlanetEvaluationConfig, profile)
    n_eval = scoring.episodes
    cached = read_json(out / "metrics.json")
    if (same_training(cached, run) and cached.get("env_steps") == run["env_steps"]
            and cached["score"]["episodes"] == n_eval
            and all(Path(f).is_file() and Path(f).stat().st_size > 0
                    for f in [*cached["files"]["figures"], cached["files"]["recording"]])):
        return cached

    model, trained_config, meta = load_planet(work)
    returns = _planet_evaluate(model, trained_config, env_name, work, seed, n_eval, run["updates"])
    save_agent(work / AGENT_NAME, env_name, work, _evaluation_bouts(seed, n_eval), git_commit())  # for `play`
    context, horizon, cutoff = scoring.open_loop(env_name in ATARI_GAMES)
    with EpisodeStore(work / "episodes.h5") as store:
        random_returns = [float(store.episode(i)["rewards"].sum()) for i in range(trained_config.seed_episodes)]
        rollout = _planet_open_loop(model, store, context + horizon, context, trained_config, seed)
    title = {NAMES.planet_sokoban: "Fig. 58", NAMES.planet_boxing: "Fig. 59/510", NAMES.planet_freeway: "Fig. 511"}[name]
    label = f"{env_name}, {variant}"
    figures = [
        save_figure(open_loop_figure(rollout, sequences=scoring.figure_sequences,
                               columns=min(context + horizon, 20),
                               title=f"{title}: {label}, open-loop after {context} context frames"),
              out / "open_loop.png"),
        save_figure(horizon_error_figure({label: rollout["mse"]}, title=f"open-loop error, {label}"),
              out / "horizon_error.png"),
    ]
    references = {ref.name: ref.value for ref in (RANDOM.get(env_name), HUMAN.get(env_name)) if ref is not None}
    if not references:
        references = {"random (seed episodes)": float(np.mean(random_returns))}
    figures.append(save_figure(learning_curve_figure({label: meta["curve"]}, references=references,
                                               title=f"PlaNet {label}: test score"), out / "learning_curve.png"))
    recording = record_frames(out / "open_loop.rrd",
                              {"truth": rollout["truth"][0], "prediction": rollout["prediction"][0]},
                              {"pixel_error": horizon_errors(rollout["truth"][0], rollout["prediction"][0])})
    metrics = {
        **run_header(name, profile, seed, run["seconds"] + time.time() - started, env=env_name, variant=variant),
        "env_steps": run["env_steps"], "updates": run["updates"], "episodes": run["episodes"],
        "score": score_summary(returns),
        "final_test": run["final_test"],
        "random_play_in_store": score_summary(random_returns),
        "open_loop": {"context": context, "horizon": horizon, "cutoff": cutoff,
                      "error_at_cutoff": error_at(rollout["mse"], cutoff),
                      "mse": [float(v) for v in rollout["mse"]]},
        "reference": published(name),
        "config": run["config"], "curve": meta["curve"],
        "files": {"figures": [str(f) for f in figures], "recording": str(recording)},
    }
    write_json(out / "metrics.json", metrics, default=float)
    return metrics


def _planet_evaluate(model, config, env_name: str, work: Path, seed: int, n_eval: int, updates: int) -> list[float]:
    """``n_eval`` greedy planner episodes (seeds from (seed, 2, k), apart from training's
    tests); cached in ``evaluation.json`` for the checkpoint's number of updates."""
    path = work / "evaluation.json"
    cached = read_json(path)
    if cached is not None and cached["updates"] == updates and len(cached["returns"]) == n_eval:
        return cached["returns"]
    env = make_planet_env(env_name, config)
    returns = []
    try:
        for env_seed, mind_seed in _evaluation_bouts(seed, n_eval):
            returns.append(float(sum(play_greedy(env, model, config, env_seed, mind_seed))))
    finally:
        env.close()
    write_json(path, {"updates": updates, "returns": returns}, indent=None)
    return returns


def _evaluation_bouts(seed: int, n_eval: int) -> list[tuple[int, int]]:
    """The (env seed, mind seed) of each evaluation episode: from (seed, 2, k), apart from training's tests."""
    return [tuple(int(v) for v in derive_seeds(seed, 2, k, n=2)) for k in range(n_eval)]


def _planet_open_loop(model, store, length: int, context: int, config, seed: int, sequences: int = 6) -> dict:
    """:func:`~wmthesis.planet.prediction.open_loop` on chunks of the most recent planner episodes
    long enough (the last one was collected after the final update: never trained on)."""

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


def planet_sokoban(profile: str | None = None, seed: int = 0, variant: str | None = None, progress: bool = True) -> dict:
    """Thesis 5.5.1: :func:`planet_experiment` on Sokoban."""
    return planet_experiment(NAMES.planet_sokoban, profile, seed, variant, progress)


def planet_boxing(profile: str | None = None, seed: int = 0, variant: str | None = None, progress: bool = True) -> dict:
    """Thesis 5.6.1-5.6.4: :func:`planet_experiment` on Boxing."""
    return planet_experiment(NAMES.planet_boxing, profile, seed, variant, progress)


def planet_freeway(profile: str | None = None, seed: int = 0, variant: str | None = None, progress: bool = True) -> dict:
    """Thesis 5.6.5-5.6.6: :func:`planet_experiment` on Freeway."""
    return planet_experiment(NAMES.planet_freeway, profile, seed, variant, progress)
