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
import json
import time
from pathlib import Path


from wmthesis.config import PlaNetConfig, for_profile, profile_name
from wmthesis.core import Callback
from wmthesis.experiments.planet import ATARI_CHANGES, PLANET_REFERENCE
from wmthesis.experiments.results import _read_json, _run_header
from wmthesis.utils import atomic_path, data_dir, derive_seeds, hold, parallel_calls, releasing_holds
from wmthesis.viz import save_figure

GAME = "boxing"
TUNED = "free-nats"
# Per profile: study seeds, held-out bouts, open-loop sequences, context and horizon; the
# agent's budget of agent steps (seed bouts included) and its evaluation bouts.
STUDY = {
    "smoke": dict(seeds=2, held_out=2, sequences=4, context=4, horizon=4),
    "quick": dict(seeds=2, held_out=3, sequences=48, context=5, horizon=15),
    "thesis": dict(seeds=2, held_out=5, sequences=64, context=5, horizon=15),
}
AGENT = {"smoke": dict(env_steps=64, bouts=2), "quick": dict(env_steps=26_000, bouts=10),
         "thesis": dict(env_steps=1_000_000, bouts=10)}
FIRST_STEPS = 500  # 2,000 frames at action repeat 4: the author's episode cap


def boxing_config(profile: str, variant: str | None = None) -> PlaNetConfig:
    """The profile's PlaNet config for Boxing with ``variant``, stopping after the seed bouts
    and the updates on them (``env_steps`` = 0): the study's runs."""
    from wmthesis.planet.train import with_variant

    config = for_profile(PlaNetConfig, profile, **ATARI_CHANGES[profile])
    return with_variant(dataclasses.replace(config, env_steps=0), variant)


def _train_study_run(run_dir: Path, config: PlaNetConfig, seed: int) -> dict:
    from wmthesis.planet.train import train_planet

    return train_planet(GAME, config, run_dir, seed=seed, progress=False)


@releasing_holds
def planet_boxing_study(profile: str | None = None, seed: int = 0, progress: bool = True) -> dict:
    """Train and score the study (module docstring); runs go under
    ``data/<profile>/planet-boxing-study/``, figures and ``metrics.json`` under
    ``data/results/planet-boxing-study/<profile>-seed<seed>/``. Returns the metrics:
    ``summary`` (:func:`~wmthesis.planet.study.summarise`), ``errors`` and ``diagnostics`` per
    run, ``files``."""
    from wmthesis.data import EpisodeStore
    from wmthesis.planet.figures import study_error_figure, study_pictures_figure
    from wmthesis.planet.study import STUDY_VARIANTS, held_out_store, scene, score_run, summarise

    profile = profile_name(profile)
    started = time.time()
    sizes = STUDY[profile]
    work = hold(data_dir(profile, "planet-boxing-study"))
    out = data_dir("results", "planet-boxing-study", f"{profile}-seed{seed}")
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
               save_figure(study_pictures_figure({_label(scores[v][0]): scores[v][0]["rollout"] for v in STUDY_VARIANTS},
                                                 columns=sizes["context"] + min(sizes["horizon"], 10)),
                           out / "study_pictures.png")]
    metrics = {**_run_header("planet-boxing-study", profile, seed, time.time() - started, env=GAME),
               "seeds": seeds, "updates": config.pretrain_updates, "seed_episodes": config.seed_episodes,
               "summary": summary,
               "runs": {f"{v}-seed{s}": {key: scores[v][i][key] for key in ("errors", "diagnostics", "updates",
                                                                              "kl_scale", "free_nats")}
                        for v in STUDY_VARIANTS for i, s in enumerate(seeds)},
               "files": {"figures": [str(f) for f in figures]}}
    with atomic_path(out / "metrics.json") as tmp:
        tmp.write_text(json.dumps(metrics, indent=1))
    return metrics


def _label(run: dict) -> str:
    return f"KL {run['kl_scale']:g}\nfree nats {run['free_nats']:g}"


# ---------------------------------------------------------------------------- the agent
def play_bout(env_name: str, config: PlaNetConfig, run_dir: Path | None, env_seed: int, mind_seed: int) -> dict:
    """One full episode, greedy PlaNet from ``run_dir`` (random play when None): its
    ``return``, the return of its first :data:`FIRST_STEPS` steps, and its ``steps``."""
    from wmthesis.core import RandomMind, loop
    from wmthesis.planet.train import PlanetMind, load_planet, make_planet_env

    env = make_planet_env(env_name, config)
    rewards = []
    try:
        if run_dir is None:
            mind, callbacks = RandomMind(env.action_space.n, seed=mind_seed), []
        else:
            model, trained, _ = load_planet(run_dir)
            mind = PlanetMind.from_config(model, trained, mind_seed)
            callbacks = [mind]
        record = _Rewards(rewards)
        loop(env, mind, policy="deterministic", callbacks=[*callbacks, record], seed=env_seed, train_mode=False)
    finally:
        env.close()
    return {"return": float(sum(rewards)), "first": float(sum(rewards[:FIRST_STEPS])), "steps": len(rewards)}


class _Rewards(Callback):
    """A loop callback that appends every step's reward to a list."""

    def __init__(self, rewards: list):
        self.rewards = rewards

    def on_step_taken(self, step, transition, info):
        self.rewards.append(float(transition.reward))


@releasing_holds
def planet_boxing_agent(profile: str | None = None, seed: int = 0, progress: bool = True) -> dict:
    """The tuned study model (seed ``seed``) goes on as a PlaNet agent until the store holds the
    profile's agent steps; then full bouts of the agent and of random play on the same bouts.
    Returns the metrics: ``agent`` and ``random`` (scores over full bouts and over their first
    500 steps), ``difference`` (:func:`~wmthesis.metrics.score_difference`), the learning
    ``curve`` and ``files``."""
    from wmthesis.metrics import score_difference, score_summary
    from wmthesis.planet.figures import learning_curve_figure
    from wmthesis.planet.train import load_planet, train_planet

    profile = profile_name(profile)
    started = time.time()
    sizes = AGENT[profile]
    study = data_dir(profile, "planet-boxing-study", f"{TUNED}-seed{seed}")
    _train_study_run(study, boxing_config(profile, TUNED), seed)
    work = hold(data_dir(profile, "planet-boxing-agent", f"seed{seed}"))
    out = data_dir("results", "planet-boxing-agent", f"{profile}-seed{seed}")
    config = dataclasses.replace(boxing_config(profile, TUNED), env_steps=sizes["env_steps"])
    run = train_planet(GAME, config, work, seed=seed, progress=progress, start_from=study)
    cached = _read_json(out / "metrics.json")
    if cached is not None and cached.get("updates") == run["updates"] and len(cached["agent"]["returns"]) == sizes["bouts"]:
        return cached
    bouts = [tuple(int(v) for v in derive_seeds(seed, 3, k, n=2)) for k in range(sizes["bouts"])]
    plays = parallel_calls([(play_bout, GAME, config, who, env_seed, mind_seed)
                            for who in (work, None) for env_seed, mind_seed in bouts], progress)
    agent, random = plays[:len(bouts)], plays[len(bouts):]
    scores = {name: {"full": score_summary([p["return"] for p in plays_]),
                     "first": score_summary([p["first"] for p in plays_]),
                     "returns": [p["return"] for p in plays_], "first_returns": [p["first"] for p in plays_]}
              for name, plays_ in (("agent", agent), ("random", random))}
    _, _, meta = load_planet(work)
    references = {"random (published)": PLANET_REFERENCE["planet-boxing"]["random"],
                  "human": PLANET_REFERENCE["planet-boxing"]["human"], "thesis PlaNet (around 30)": 30.0}
    figure = save_figure(learning_curve_figure({"PlaNet, KL scale 0.03, free nats 12": meta["curve"]},
                                               references=references, title="PlaNet on Boxing: test score"),
                         out / "learning_curve.png")
    metrics = {**_run_header("planet-boxing-agent", profile, seed, run["seconds"] + time.time() - started, env=GAME),
               "env_steps": run["env_steps"], "updates": run["updates"], "episodes": run["episodes"],
               **scores, "difference": score_difference(scores["agent"]["returns"], scores["random"]["returns"]),
               "difference_first": score_difference(scores["agent"]["first_returns"], scores["random"]["first_returns"]),
               "bouts": bouts, "curve": meta["curve"], "reference": PLANET_REFERENCE["planet-boxing"],
               "files": {"figures": [str(figure)]}}
    with atomic_path(out / "metrics.json") as tmp:
        tmp.write_text(json.dumps(metrics, indent=1))
    return metrics


__all__ = ["planet_boxing_study", "planet_boxing_agent", "boxing_config", "play_bout", "STUDY", "AGENT", "FIRST_STEPS"]
