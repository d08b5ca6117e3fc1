"""PlaNet on Boxing (thesis 5.6.1-5.6.4) in two parts, each resumable.

1. :func:`planet_boxing_study`: the three configurations of :data:`~wmthesis.planet.study.STUDY_VARIANTS`
   trained on the same random bouts for the same number of updates, two seeds each, scored on
   held-out bouts by the open-loop error on the moving pixels against two baselines.
2. :func:`planet_boxing_agent`: the tuned configuration's model (KL scale 0.03, free nats 12)
   goes on as a PlaNet agent, planning and collecting bouts; then 10 full bouts against random
   play on the same bouts, with the score over the first 500 agent steps (the author's runs
   capped episodes at 2,000 frames: 500 agent steps) beside the full-bout score.
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from wmthesis.config import for_profile, profile_name
from wmthesis.data import EpisodeStore
from wmthesis.declarations import NAMES
from wmthesis.metrics import score_difference
from wmthesis.planet.agent_file import AGENT_NAME, save_agent
from wmthesis.planet.bouts import FIRST_STEPS, bout_scores, play_bout
from wmthesis.planet.config import PlaNetConfig, PlanetEvaluationConfig
from wmthesis.planet.figures import learning_curve_figure, study_error_figure, study_label, study_pictures_figure
from wmthesis.planet.profiles import planet_config
from wmthesis.planet.study import study_sizes, STUDY_VARIANTS, held_out_store, scene, score_run, summarise
from wmthesis.planet.train import load_planet, same_training, train_planet, with_variant
from wmthesis.references import THESIS_PLANET_BOXING_SCORE, human, published, random_play
from wmthesis.runs import (hold, played_bouts, read_json, releasing_holds, results_folder, run_header, work_folder,
                           write_json)
from wmthesis.stamp import git_commit
from wmthesis.utils import data_dir, derive_seeds, parallel_calls
from wmthesis.variants import no_variant
from wmthesis.viz import record_frames, save_figure

GAME = "boxing"
TUNED = "free-nats"


def boxing_config(profile: str, variant: str | None = None, study: bool = True) -> PlaNetConfig:
    """The profile's PlaNet config for Boxing with ``variant``; for the ``study``, stopping
    after the seed bouts and the updates on them (``env_steps`` = 0)."""
    config = with_variant(planet_config(GAME, profile), variant)
    return dataclasses.replace(config, env_steps=0) if study else config


def _train_study_run(run_dir: Path, config: PlaNetConfig, seed: int) -> dict:
    return train_planet(GAME, config, run_dir, seed=seed, progress=False)


@releasing_holds
def planet_boxing_study(profile: str | None = None, seed: int = 0, variant: str | None = None,
                        progress: bool = True) -> dict:
    """Train and score the study (module docstring); runs go under
    ``data/<profile>/planet-boxing-study/``, figures and ``metrics.json`` under
    ``data/results/planet-boxing-study/<profile>-seed<seed>/``. Returns the metrics:
    ``summary`` (:func:`~wmthesis.planet.study.summarise`), ``errors`` and ``diagnostics`` per
    run, ``files``."""
    no_variant(NAMES.planet_boxing_study, variant)
    profile = profile_name(profile)
    started = time.time()
    sizes = study_sizes(profile)
    work = hold(data_dir(profile, NAMES.planet_boxing_study))
    out = results_folder(NAMES.planet_boxing_study, profile, seed)
    seeds = [seed + k for k in range(sizes["seeds"])]
    runs = {(variant, s): work / f"{variant}-seed{s}" for variant in STUDY_VARIANTS for s in seeds}
    parallel_calls([(_train_study_run, path, boxing_config(profile, variant), s)
                    for (variant, s), path in runs.items()], progress)
    config = boxing_config(profile)
    held_path = held_out_store(work / f"held-out-seed{seed}.h5", GAME, config, 10_000 + seed, sizes["held_out"])
    with EpisodeStore(runs[STUDY_VARIANTS[0], seed] / "episodes.h5") as store:
        background, mean_frame = scene(store)
    with EpisodeStore(held_path) as held:
        scores = {variant: [score_run(runs[variant, s], held, background, mean_frame, context=sizes["context"],
                                      horizon=sizes["horizon"], sequences=sizes["sequences"], seed=seed)
                            for s in seeds] for variant in STUDY_VARIANTS}
    summary = summarise(scores, horizons=sorted({1, min(5, sizes["horizon"]), sizes["horizon"]}
                                                | ({10} if sizes["horizon"] >= 10 else set())))
    figures = [save_figure(study_error_figure(scores, title="Boxing: open-loop error on the moving pixels "
                                                           f"(held-out bouts, {len(seeds)} seeds)"),
                           out / "study_error.png"),
               save_figure(study_pictures_figure({study_label(scores[v][0], "\n"): scores[v][0]["rollout"] for v in STUDY_VARIANTS},
                                                 columns=sizes["context"] + min(sizes["horizon"], 10)),
                           out / "study_pictures.png")]
    rollouts = {v: scores[v][0]["rollout"] for v in STUDY_VARIANTS}
    recording = record_frames(out / "open_loop.rrd", {"truth": rollouts[TUNED]["truth"][0],
                                                      **{v: r["prediction"][0] for v, r in rollouts.items()}})
    tuned, h5 = summary[TUNED], min(5, sizes["horizon"])
    headline = (f"tuned error on moving pixels +1 {tuned['model'][1]['mean']:.4f}, +{h5} {tuned['model'][h5]['mean']:.4f} "
                f"(repeat last {tuned['repeat last'][1]:.4f}, {tuned['repeat last'][h5]:.4f}; unchanged "
                f"{summary['unchanged']['model'][1]['mean']:.4f}, {summary['unchanged']['model'][h5]['mean']:.4f}); "
                f"beats both baselines: {tuned['beats_baselines']}")
    metrics = {**run_header(NAMES.planet_boxing_study, profile, seed, time.time() - started, env=GAME),
               "headline": headline, "seeds": seeds, "updates": config.pretrain_updates, "seed_episodes": config.seed_episodes,
               "summary": summary,
               "runs": {f"{v}-seed{s}": {key: scores[v][i][key] for key in ("errors", "diagnostics", "updates",
                                                                              "kl_scale", "free_nats")}
                        for v in STUDY_VARIANTS for i, s in enumerate(seeds)},
               "files": {"figures": [str(f) for f in figures], "recording": str(recording)}}
    write_json(out / "metrics.json", metrics)
    return metrics


# ---------------------------------------------------------------------------- the agent


@releasing_holds
def planet_boxing_agent(profile: str | None = None, seed: int = 0, variant: str | None = None,
                        progress: bool = True) -> dict:
    """The tuned study model (seed ``seed``) goes on as a PlaNet agent until the store holds the
    profile's agent steps; then full bouts of the agent and of random play on the same bouts.
    Returns the metrics: ``agent`` and ``random`` (scores over full bouts and over their first
    500 steps), ``difference`` (:func:`~wmthesis.metrics.score_difference`), the learning
    ``curve`` and ``files``."""
    no_variant(NAMES.planet_boxing_agent, variant)
    profile = profile_name(profile)
    bouts_scored = for_profile(PlanetEvaluationConfig, profile).agent_bouts
    study = work_folder(profile, NAMES.planet_boxing_study, seed, TUNED)
    _train_study_run(study, boxing_config(profile, TUNED), seed)
    work = hold(work_folder(profile, NAMES.planet_boxing_agent, seed))
    out = results_folder(NAMES.planet_boxing_agent, profile, seed)
    config = boxing_config(profile, TUNED, study=False)
    run = train_planet(GAME, config, work, seed=seed, progress=progress, start_from=study)
    started = time.time()  # run["seconds"] holds the training, over every resume; the evaluation is added
    cached = read_json(out / "metrics.json")
    if same_training(cached, run) and len(cached["agent"]["returns"]) == bouts_scored:
        return cached
    bouts = [tuple(int(v) for v in derive_seeds(seed, 3, k, n=2)) for k in range(bouts_scored)]
    key = {"updates": run["updates"], "seconds": run["seconds"], "bouts": [list(b) for b in bouts]}  # this training's
    plays = played_bouts(work / "evaluation-bouts.json", key,
                         progress, [(play_bout, GAME, config, who, env_seed, mind_seed)
                                    for who in (work, None) for env_seed, mind_seed in bouts])  # each saved as it ends
    agent, random = plays[:len(bouts)], plays[len(bouts):]
    save_agent(work / AGENT_NAME, "boxing", work, bouts, git_commit())  # for `play`
    scores = {"agent": bout_scores(agent), "random": bout_scores(random)}
    _, _, meta = load_planet(work)
    references = {"random (published)": random_play(GAME), "human": human(GAME),
                  "thesis PlaNet (around 30)": THESIS_PLANET_BOXING_SCORE}
    figure = save_figure(learning_curve_figure({"PlaNet, KL scale 0.03, free nats 12": meta["curve"]},
                                               references=references, title="PlaNet on Boxing: test score"),
                         out / "learning_curve.png")
    full = scores["agent"]["full"]
    headline = (f"score {full['mean']:.1f} +- {full['std']:.1f} over {full['episodes']} bouts (random play "
                f"{scores['random']['full']['mean']:.1f}); first {FIRST_STEPS} steps {scores['agent']['first']['mean']:.1f}")
    metrics = {**run_header(NAMES.planet_boxing_agent, profile, seed, run["seconds"] + time.time() - started, env=GAME),
               "headline": headline, "env_steps": run["env_steps"], "updates": run["updates"], "episodes": run["episodes"],
               **scores, "difference": score_difference(scores["agent"]["returns"], scores["random"]["returns"]),
               "difference_first": score_difference(scores["agent"]["first_returns"], scores["random"]["first_returns"]),
               "bouts": bouts, "curve": meta["curve"], "reference": published(NAMES.planet_boxing),
               "files": {"figures": [str(figure)]}}
    write_json(out / "metrics.json", metrics)
    return metrics


__all__ = ["planet_boxing_study", "planet_boxing_agent", "boxing_config", 
           "GAME"]
