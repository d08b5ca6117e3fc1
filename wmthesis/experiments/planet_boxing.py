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

import numpy as np

from wmthesis.config import PlaNetConfig, profile_name
from wmthesis.data import EpisodeBuffer
from wmthesis.experiments.planet import PLANET_REFERENCE
from wmthesis.planet.profiles import planet_config
from wmthesis.experiments.results import _read_json, _run_header
from wmthesis.utils import atomic_path, check_choice, data_dir, derive_seeds, hold, parallel_calls, releasing_holds
from wmthesis.viz import record_frames, save_figure

GAME = "boxing"
TUNED = "free-nats"
# Per profile: study seeds, held-out bouts, open-loop sequences, context and horizon; the
# agent's evaluation bouts (its budget is the config's ``env_steps``, seed bouts included).
STUDY = {
    "smoke": dict(seeds=2, held_out=2, sequences=4, context=4, horizon=4),
    "quick": dict(seeds=2, held_out=3, sequences=48, context=5, horizon=15),
    "thesis": dict(seeds=2, held_out=5, sequences=64, context=5, horizon=15),
}
AGENT = {"smoke": dict(bouts=2), "quick": dict(bouts=10), "thesis": dict(bouts=10)}
FIRST_STEPS = 500  # 2,000 frames at action repeat 4: the author's episode cap
# The value's variants (issue 31's levers, each on the same frozen model): the default fits the
# sum of the next rewards (notebook 09); ``td`` bootstraps through the model; ``validation-10``
# chooses the round on twice the validation bouts.
VALUE_VARIANTS = {"td": dict(target="td"), "validation-10": dict(validation_bouts=10)}


def boxing_config(profile: str, variant: str | None = None, study: bool = True) -> PlaNetConfig:
    """The profile's PlaNet config for Boxing with ``variant``; for the ``study``, stopping
    after the seed bouts and the updates on them (``env_steps`` = 0)."""
    from wmthesis.planet.train import with_variant

    config = with_variant(planet_config(GAME, profile), variant)
    return dataclasses.replace(config, env_steps=0) if study else config


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
    from wmthesis.planet.figures import study_error_figure, study_label, study_pictures_figure
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
    metrics = {**_run_header("planet-boxing-study", profile, seed, time.time() - started, env=GAME),
               "headline": headline, "seeds": seeds, "updates": config.pretrain_updates, "seed_episodes": config.seed_episodes,
               "summary": summary,
               "runs": {f"{v}-seed{s}": {key: scores[v][i][key] for key in ("errors", "diagnostics", "updates",
                                                                              "kl_scale", "free_nats")}
                        for v in STUDY_VARIANTS for i, s in enumerate(seeds)},
               "files": {"figures": [str(f) for f in figures], "recording": str(recording)}}
    with atomic_path(out / "metrics.json") as tmp:
        tmp.write_text(json.dumps(metrics, indent=1))
    return metrics


# ---------------------------------------------------------------------------- the agent
def play_bout(env_name: str, config: PlaNetConfig, run_dir: Path | None, env_seed: int, mind_seed: int) -> dict:
    """One full episode, greedy PlaNet from ``run_dir`` (random play when None): its
    ``return``, the return of its first :data:`FIRST_STEPS` steps, and its ``steps``."""
    from wmthesis.core import RandomMind, loop
    from wmthesis.planet.train import load_planet, make_planet_env, play_greedy

    env = make_planet_env(env_name, config)
    try:
        if run_dir is None:
            record = EpisodeBuffer()
            loop(env, RandomMind(env.action_space.n, seed=mind_seed), policy="deterministic", callbacks=[record],
                 seed=env_seed, train_mode=False)
            rewards = [float(r) for r in record.episode["rewards"]]
        else:
            model, trained, _ = load_planet(run_dir)
            rewards = play_greedy(env, model, trained, env_seed, mind_seed)
    finally:
        env.close()
    return {"return": float(sum(rewards)), "first": float(sum(rewards[:FIRST_STEPS])), "steps": len(rewards)}


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
    config = boxing_config(profile, TUNED, study=False)
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
    full = scores["agent"]["full"]
    headline = (f"score {full['mean']:.1f} +- {full['std']:.1f} over {full['episodes']} bouts (random play "
                f"{scores['random']['full']['mean']:.1f}); first {FIRST_STEPS} steps {scores['agent']['first']['mean']:.1f}")
    metrics = {**_run_header("planet-boxing-agent", profile, seed, run["seconds"] + time.time() - started, env=GAME),
               "headline": headline, "env_steps": run["env_steps"], "updates": run["updates"], "episodes": run["episodes"],
               **scores, "difference": score_difference(scores["agent"]["returns"], scores["random"]["returns"]),
               "difference_first": score_difference(scores["agent"]["first_returns"], scores["random"]["first_returns"]),
               "bouts": bouts, "curve": meta["curve"], "reference": PLANET_REFERENCE["planet-boxing"],
               "files": {"figures": [str(figure)]}}
    with atomic_path(out / "metrics.json") as tmp:
        tmp.write_text(json.dumps(metrics, indent=1))
    return metrics


# ---------------------------------------------------------------------------- beyond the thesis
def value_planner_bout(planet_run: Path, value_run: Path, planner, env_seed: int, mind_seed: int) -> dict:
    """One full bout of CEM with the chosen value at its end
    (:func:`~wmthesis.planet.value_planner.play_value_planner`) on the PlaNet agent's frozen
    model: its ``return``, the return of its first :data:`FIRST_STEPS` steps and its ``steps``."""
    from wmthesis.planet.train import load_planet, make_planet_env
    from wmthesis.planet.value import load_value
    from wmthesis.planet.value_planner import play_value_planner

    model, planet, _ = load_planet(planet_run)
    env = make_planet_env(GAME, planet)
    try:
        rewards = play_value_planner(env, model, load_value(value_run, model), planet, planner, env_seed, mind_seed)
    finally:
        env.close()
    return {"return": float(sum(rewards)), "first": float(sum(rewards[:FIRST_STEPS])), "steps": len(rewards)}


def _value_planner_scores(planet_run: Path, value_run: Path, planner, bouts: list, best: int, progress: bool) -> dict:
    """The planner with value over the evaluation ``bouts``: full-bout and first-500-step
    scores, cached in ``value_run`` for the chosen round ``best`` and the planner's config."""
    from wmthesis.metrics import score_summary

    key = {"round": best, "planner": dataclasses.asdict(planner), "bouts": [list(b) for b in bouts]}
    cached = _read_json(value_run / "value_planner.json")
    if cached is not None and cached.get("key") == key:
        return cached["scores"]
    plays = parallel_calls([(value_planner_bout, planet_run, value_run, planner, *bout) for bout in bouts], progress)
    scores = {"full": score_summary([p["return"] for p in plays]), "first": score_summary([p["first"] for p in plays]),
              "returns": [p["return"] for p in plays], "first_returns": [p["first"] for p in plays],
              "config": dataclasses.asdict(planner)}
    with atomic_path(value_run / "value_planner.json") as tmp:
        tmp.write_text(json.dumps({"key": key, "scores": scores}, indent=1))
    return scores


@releasing_holds
def planet_boxing_value(profile: str | None = None, seed: int = 0, progress: bool = True,
                        variant: str | None = None) -> dict:
    """The PlaNet agent's model (:func:`planet_boxing_agent`, trained first if need be) frozen,
    and a latent action value (:mod:`~wmthesis.planet.value`) fitted on random bouts and then on
    its own; after each round, greedy bouts on the agent's evaluation bouts. The round chosen on
    validation bouts of its own (:func:`~wmthesis.planet.value.best_round`) compares with random
    play and with the CEM planner on the evaluation bouts, and so does CEM with that value at the
    end of its horizon (:mod:`~wmthesis.planet.value_planner`). Returns the metrics:
    ``value`` and ``random`` (scores over full bouts), ``difference``
    (:func:`~wmthesis.metrics.score_difference`), ``planet`` (the CEM agent's), ``value_planner``
    (CEM with the value: full bouts and their first 500 steps), the ``curve`` (one entry per
    round) and ``files``. A ``variant`` of :data:`VALUE_VARIANTS` fits its value in a folder of
    its own, on the same model and bouts (a ``td`` value is discounted in the planner as in its
    targets)."""
    from wmthesis.config import LatentValueConfig, ValuePlannerConfig, for_profile
    from wmthesis.metrics import score_difference, score_summary
    from wmthesis.planet.figures import learning_curve_figure
    from wmthesis.planet.train import load_planet, make_planet_env
    from wmthesis.planet.value import train_value

    if variant is not None:
        check_choice("planet-boxing-value variant", variant, tuple(VALUE_VARIANTS))
    profile = profile_name(profile)
    started = time.time()
    agent = planet_boxing_agent(profile, seed, progress)
    planet_run = data_dir(profile, "planet-boxing-agent", f"seed{seed}")
    work = hold(data_dir(profile, "planet-boxing-value", f"seed{seed}" if variant is None else f"{variant}-seed{seed}"))
    out = data_dir("results", "planet-boxing-value", f"{profile}-seed{seed}", *(() if variant is None else (variant,)))
    model, planet, _ = load_planet(planet_run)
    config = for_profile(LatentValueConfig, profile, test_bouts=AGENT[profile]["bouts"], **VALUE_VARIANTS.get(variant, {}))
    env = make_planet_env(GAME, planet)
    try:
        run = train_value(model, planet.bits, env, config, work, seed=seed, progress=progress, first_steps=FIRST_STEPS)
    finally:
        env.close()
    chosen = run["curve"][run["best_round"]]
    returns = chosen["returns"]
    discount = {"discount": config.discount} if config.target == "td" else {}
    planner = _value_planner_scores(planet_run, work, for_profile(ValuePlannerConfig, profile, **discount), agent["bouts"],
                                    run["best_round"], progress)
    references = {"random play": agent["random"]["full"]["mean"], "PlaNet (CEM)": agent["agent"]["full"]["mean"],
                  f"CEM, H{planner['config']['horizon']}, with the value at its end": planner["full"]["mean"],
                  "human": PLANET_REFERENCE["planet-boxing"]["human"], "thesis PlaNet (around 30)": 30.0}
    figure = save_figure(learning_curve_figure({"latent value on the PlaNet model": {"test": run["curve"]}},
                                               references=references, x="episodes",
                                               title="Boxing: the value agent after each round"),
                         out / "value_curve.png")
    value = score_summary(returns)
    metrics = {**_run_header("planet-boxing-value", profile, seed, time.time() - started, env=GAME,
                             **({} if variant is None else {"variant": variant})),
               "headline": f"score {value['mean']:.1f} +- {value['std']:.1f} over {value['episodes']} bouts "
                           f"(the value of round {chosen['round']}, chosen on {len(chosen['validation'])} validation bouts) "
                           f"(random play {agent['random']['full']['mean']:.1f}, PlaNet's CEM "
                           f"{agent['agent']['full']['mean']:.1f})",
               "value": value, "returns": returns, "random": agent["random"]["full"],
               **({"value_first": score_summary(chosen["first_returns"])} if "first_returns" in chosen else {}),
               "difference": score_difference(returns, agent["random"]["returns"]), "planet": agent["agent"]["full"],
               "value_planner": planner,
               "bouts": agent["bouts"], "curve": run["curve"], "best_round": run["best_round"],
               "config": dataclasses.asdict(config),
               "files": {"figures": [str(figure)]}}
    with atomic_path(out / "metrics.json") as tmp:
        tmp.write_text(json.dumps(metrics, indent=1))
    return metrics


PLAN_STEPS = {"smoke": 5, "quick": 300, "thesis": 500}  # steps of a bout on which the planners are compared


def value_plan_choices(profile: str | None = None, seed: int = 0, progress: bool = True) -> dict:
    """Where the value changes the plan (:func:`~wmthesis.planet.value_planner.plan_choices`):
    on the first :data:`PLAN_STEPS` steps of the value agent's last bout of its own, the action
    the thesis's CEM, CEM with the chosen value and the value alone would take from the same
    belief. Runs :func:`planet_boxing_value` first if need be; cached. Returns ``choices``
    (planner -> actions), ``agreement`` (pair -> share of steps), ``action_names`` and
    ``files`` (the bars, and the frames where CEM and CEM with value part)."""
    from wmthesis.config import ValuePlannerConfig, for_profile
    from wmthesis.data import EpisodeStore
    from wmthesis.planet.figures import plan_choices_figure
    from wmthesis.planet.train import load_planet, make_planet_env
    from wmthesis.planet.value import STORE, load_value
    from wmthesis.planet.value_planner import PLANNERS, plan_choices
    from wmthesis.viz import image_grid

    profile = profile_name(profile)
    metrics = planet_boxing_value(profile, seed, progress)
    planet_run = data_dir(profile, "planet-boxing-agent", f"seed{seed}")
    work = data_dir(profile, "planet-boxing-value", f"seed{seed}")
    out = data_dir("results", "planet-boxing-value", f"{profile}-seed{seed}")
    model, planet, _ = load_planet(planet_run)
    planner, steps = for_profile(ValuePlannerConfig, profile), PLAN_STEPS[profile]
    with EpisodeStore(work / STORE, "r") as store:
        bout = store.episode(-1)
    frames, taken = bout["observations"][:steps], bout["actions"][:steps]
    key = {"round": metrics["best_round"], "steps": len(taken), "planner": dataclasses.asdict(planner)}
    cached = _read_json(work / "plan_choices.json")
    if cached is None or cached.get("key") != key:
        choices = plan_choices(model, load_value(work, model), planet, planner, frames, taken, seed)
        cached = {"key": key, "choices": {name: c.tolist() for name, c in choices.items()}}
        with atomic_path(work / "plan_choices.json") as tmp:
            tmp.write_text(json.dumps(cached))
    choices = {name: np.asarray(c) for name, c in cached["choices"].items()}
    env = make_planet_env(GAME, planet)
    names = env.unwrapped.get_action_meanings()
    env.close()
    bars = save_figure(plan_choices_figure(choices, names, title=f"Boxing, the first {len(taken)} steps of one bout: "
                                                                 "the action each planner picks from the same belief"),
                       out / "plan_choices.png")
    thesis, ours = choices[PLANNERS[0]], choices[PLANNERS[1]]
    parted = np.flatnonzero(thesis != ours)[:12]
    files = [bars]
    if len(parted):
        files.append(save_figure(image_grid([frames[t] for t in parted], 6, [f"step {t}: CEM {names[thesis[t]]}\n"
                                                                           f"+ value {names[ours[t]]}" for t in parted],
                                            scale=1.9), out / "plan_choices_frames.png"))
    agreement = {f"{a} = {b}": float(np.mean(choices[a] == choices[b]))
                 for i, a in enumerate(PLANNERS) for b in PLANNERS[i + 1:]}
    return {"choices": cached["choices"], "agreement": agreement, "action_names": names, "steps": len(taken),
            "files": [str(f) for f in files]}


def planner_rows(by_seed: dict[int, dict]) -> list[list[str]]:
    """The planners over seeds (``by_seed``: seed -> :func:`planet_boxing_value`'s metrics), one
    row each: every seed's mean over its bouts, then the mean over seeds with its 95% t-interval
    (:func:`~wmthesis.experiments.summary.aggregate`)."""
    from wmthesis.experiments.summary import aggregate

    players = {"random play": lambda m: m["random"]["mean"], "PlaNet's CEM (thesis), full bouts": lambda m: m["planet"]["mean"],
               "value alone, full bouts": lambda m: m["value"]["mean"],
               "value alone, first 500 steps": lambda m: m.get("value_first", {}).get("mean"),  # runs since 2026-11-24
               "CEM with the value, full bouts": lambda m: m["value_planner"]["full"]["mean"],
               "CEM with the value, first 500 steps": lambda m: m["value_planner"]["first"]["mean"]}
    rows = []
    for name, score in players.items():
        scores = [score(m) for m in by_seed.values()]
        if None in scores:  # not measured in an older run
            continue
        summary = aggregate(scores)
        interval = "" if summary["ci_low"] is None else f" [{summary['ci_low']:.1f}, {summary['ci_high']:.1f}]"
        rows.append([name, *(f"{x:.1f}" for x in scores), f"{summary['mean']:.1f}{interval}"])
    return rows


def _score_cell(summary: dict) -> str:
    """A :func:`~wmthesis.metrics.score_summary` as a table cell: mean ± std (n)."""
    return f"{summary['mean']:.1f} ± {summary['std']:.1f} (n={summary['episodes']})"


def value_table(metrics: dict) -> str:
    """The value agent's chosen round beside random play and the CEM planner on the same bouts (markdown)."""
    diff, chosen = metrics["difference"], metrics["curve"][metrics["best_round"]]
    return "\n".join([
        "| player | full bout |", "|---|---|",
        f"| latent value on the PlaNet model (round {chosen['round']}, {chosen['episodes']} bouts of its own; "
        f"chosen on {len(chosen['validation'])} validation bouts) | {_score_cell(metrics['value'])} |",
        f"| PlaNet (CEM planner), same model | {_score_cell(metrics['planet'])} |",
        *([f"| CEM with the value at the end of its {metrics['value_planner']['config']['horizon']} steps, same model "
           f"| {_score_cell(metrics['value_planner']['full'])} |"] if "value_planner" in metrics else []),
        f"| random play, same bouts | {_score_cell(metrics['random'])} |",
        f"| value - random | {diff['difference']:.1f} ± {diff['standard_error']:.1f} (s.e.) |",
        f"| human (standard reference) | {PLANET_REFERENCE['planet-boxing']['human']} |"])


__all__ = ["planet_boxing_study", "planet_boxing_agent", "planet_boxing_value", "value_plan_choices", "PLAN_STEPS", "planner_rows", "VALUE_VARIANTS", "value_planner_bout", "value_table", "boxing_config", "play_bout", "study_table", "agent_table", "STUDY", "AGENT", "FIRST_STEPS"]


# ---------------------------------------------------------------------------- tables
def study_table(metrics: dict) -> str:
    """The study's summary as a markdown table: per configuration, the model's error on the
    moving pixels at each horizon (seed mean, [min, max]) beside the baselines, and the
    latent diagnostics."""
    summary = metrics["summary"]
    first = next(iter(summary.values()))
    horizons = list(first["model"])
    rows = ["| configuration | " + " | ".join(f"+{h}" for h in horizons)
            + " | beats both baselines at +1..+5 | KL (nats) | free nats | posterior / prior entropy |",
            "|---" * (len(horizons) + 5) + "|"]
    for variant, entry in summary.items():
        run = metrics["runs"][f"{variant}-seed{metrics['seeds'][0]}"]
        cells = [f"{v['mean']:.4f} [{v['min']:.4f}, {v['max']:.4f}]" for v in entry["model"].values()]
        diag = entry["diagnostics"]
        rows.append(f"| {variant}: KL scale {run['kl_scale']:g}, free nats {run['free_nats']:g} | " + " | ".join(cells)
                    + f" | {'yes' if entry['beats_baselines'] else 'no'} | {diag['kl']:.2f} | {run['free_nats']:g} | "
                    f"{diag['posterior_entropy']:.1f} / {diag['prior_entropy']:.1f} |")
    for name in ("repeat last", "mean frame"):
        rows.append(f"| baseline: {name} | " + " | ".join(f"{first[name][h]:.4f}" for h in horizons) + " | | | | |")
    return "\n".join(rows)


def agent_table(metrics: dict) -> str:
    """The agent's bouts beside random play on the same bouts and the references (markdown)."""
    diff, first = metrics["difference"], metrics["difference_first"]
    reference = metrics["reference"]
    return "\n".join([
        "| player | full bout | first 500 agent steps |", "|---|---|---|",
        f"| PlaNet (KL scale 0.03, free nats 12), {metrics['env_steps']:,} agent steps, {metrics['updates']:,} updates "
        f"| {_score_cell(metrics['agent']['full'])} | {_score_cell(metrics['agent']['first'])} |",
        f"| random play, same bouts | {_score_cell(metrics['random']['full'])} | {_score_cell(metrics['random']['first'])} |",
        f"| agent - random | {diff['difference']:.1f} ± {diff['standard_error']:.1f} (s.e.) "
        f"| {first['difference']:.1f} ± {first['standard_error']:.1f} (s.e.) |",
        f"| human (standard reference) | {reference['human']} | |",
        f"| thesis PlaNet (5.6.4) | {reference['thesis PlaNet (5.6.4)']} | |"])
