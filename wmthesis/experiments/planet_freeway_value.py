"""Beyond the thesis on PlaNet's Freeway model: the model of ``planet-freeway`` in its
tuned variant (:func:`~wmthesis.experiments.planet.planet_experiment`, thesis 5.6.5-5.6.6)
frozen, a latent action value fitted on it, and CEM with that value at the end of its horizon,
beside the thesis's CEM, random play and pressing UP at every step (a reference that knows the
game, as A* is for Sokoban: whatever a planner adds beyond it is dodging cars) on the same 10
evaluation episodes (:func:`~wmthesis.value.comparison.fit_and_compare`).

Freeway pays one point per crossing, about 90 agent steps apart, and random play hardly ever
crosses. So the value differs from Boxing's in two ways (:data:`FREEWAY_VALUE`): its target is
the discounted sum of the next 150 rewards (``discounted-sum``: a crossing 90 steps ahead still
counts 0.97^90 = 0.06 of a point), and its first data are the PlaNet agent's own episodes (its
seed episodes and the bouts it collected), copied from the PlaNet run, not random play.

Two checks ask what holds the planners back. :func:`lookahead_ceiling` plans with a perfect model,
the emulator itself (:mod:`wmthesis.envs.freeway`), at several horizons; :func:`when_to_wait` asks
the learned model's planners, along that lookahead's own episode, whether they hold back where it
waits for a car.
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
from gymnasium.wrappers import TimeLimit
from scipy.stats import fisher_exact

from wmthesis.config import for_profile, profile_name
from wmthesis.data import EpisodeStore
from wmthesis.declarations import NAMES
from wmthesis.envs.freeway import play_lookahead
from wmthesis.metrics import paired_difference
from wmthesis.planet.bouts import bout_result, bout_scores, play_bout
from wmthesis.value.config import LatentValueConfig, ValueEvaluationConfig, ValuePlannerConfig
from wmthesis.planet.figures import study_error_figure
from wmthesis.planet.profiles import planet_config
from wmthesis.planet.study import study_sizes, held_out_store, scene, score_run
from wmthesis.planet.train import load_planet
from wmthesis.planet.frames import make_planet_env
from wmthesis.value.planner import plan_choices
from wmthesis.value.play import evaluation_seeds, validation_seeds
from wmthesis.value.rounds import STORE, load_value
from wmthesis.value.comparison import (BASELINE_LABELS, checked_levers, compare_plans, fit_and_compare,
                                        lever_scores, start_from)
from wmthesis.references import human
from wmthesis.runs import (built_on, hold, played_bouts, read_json, releasing_holds, results_folder, work_folder,
                           write_json)
from wmthesis.training import with_added_defaults
from wmthesis.utils import data_dir
from wmthesis.value.variants import FREEWAY_MODEL, FREEWAY_PLANNER_LEVERS, FREEWAY_VALUE_VARIANTS
from wmthesis.viz import save_figure

GAME = "freeway"
REFERENCES = {"human": human(GAME)}  # lines in its figures
FREEWAY_VALUE = dict(target="discounted-sum", reward_steps=150, discount=0.97)
UP = 1  # Freeway's actions: NOOP, UP, DOWN
BASELINES = ("planet", "random", "always-up")  # in the order their episodes are saved


def model_variant(variant: str | None = None) -> str:
    """The ``planet-freeway`` variant whose model a value ``variant`` is fitted on (its first
    data: that agent's episodes, or those of the variant's ``data``)."""
    return FREEWAY_VALUE_VARIANTS.changes(variant).get("model", FREEWAY_MODEL)


def base_variant(variant: str | None = None) -> str | None:
    """The value run whose model a ``variant`` shares and whose baselines it copies: the first of
    its lineage (None for the default's, on ``freeway-tuned``'s model)."""
    root = FREEWAY_VALUE_VARIANTS.lineage(variant)[0].name
    return None if root == "default" else root


def value_variant(variant: str | None = None) -> str | None:
    """The run whose value a ``variant`` plays with: itself where it fits one (a ``value`` of its
    own, or a base), else the base it copies the value from."""
    name = None if FREEWAY_VALUE_VARIANTS.check(variant).name == "default" else variant
    return name if "value" in FREEWAY_VALUE_VARIANTS[variant or "default"].changes or name == base_variant(name) \
        else base_variant(name)


def frozen_model(profile: str, seed: int, model: str = FREEWAY_MODEL, progress: bool = True) -> Path:
    """The frozen run of ``planet-freeway``'s variant ``model``, trained first if need be."""
    built_on(NAMES.planet_freeway, profile, seed, model, progress)
    return work_folder(profile, NAMES.planet_freeway, seed, model)


def baseline_scores(planet_run: Path, bouts: list, work: Path, progress: bool) -> dict:
    """The thesis's CEM (the model of ``planet_run``), random play and UP at every step on the
    same ``bouts``: :data:`BASELINES`, each ``full`` and ``first``-500-step scores with their
    returns; cached in ``work/baselines.json`` for the bouts, each episode saved in
    ``work/baseline-bouts.json`` as it ends (a run cut off plays only the rest, and a baseline
    added later plays only its own)."""
    key = {"bouts": [list(b) for b in bouts], "planet_run": str(planet_run)}
    cached = read_json(work / "baselines.json")
    if cached is not None and cached.get("key") == key and set(cached["scores"]) == set(BASELINES):
        return cached["scores"]
    _, config, _ = load_planet(planet_run)
    players = {"planet": (planet_run, None), "random": (None, None), "always-up": (None, UP)}  # (run, action)
    plays = played_bouts(work / "baseline-bouts.json", key, progress,
                         [(play_bout, GAME, config, players[name][0], *bout, players[name][1])
                          for name in BASELINES for bout in bouts])
    parts = {name: plays[i * len(bouts):(i + 1) * len(bouts)] for i, name in enumerate(BASELINES)}
    scores = {name: bout_scores(part) for name, part in parts.items()}
    write_json(work / "baselines.json", {"key": key, "scores": scores})
    return scores


def value_folders(profile: str, seed: int, variant: str | None = None) -> tuple[Path, Path]:
    """A run's work folder (``data/<profile>/planet-freeway-value/[<variant>-]seed<seed>``) and
    its results folder (``data/results/planet-freeway-value/<profile>-seed<seed>[/<variant>]``)."""
    return (work_folder(profile, NAMES.planet_freeway_value, seed, variant),
            results_folder(NAMES.planet_freeway_value, profile, seed, variant))


@releasing_holds
def planet_freeway_value(profile: str | None = None, seed: int = 0, variant: str | None = None,
                         progress: bool = True) -> dict:
    """PlaNet's Freeway agent (``planet-freeway``, ``freeway-tuned`` or the variant's
    :func:`model_variant`, trained first if need be)
    frozen; a value fitted on its episodes, then rounds of its own (:data:`FREEWAY_VALUE`); the
    value alone, CEM with the value and the thesis's CEM on :data:`EPISODES` evaluation episodes
    beside random play and UP at every step. A ``variant`` of :data:`FREEWAY_VALUE_VARIANTS` changes the
    value or the planner in a folder of its own, beside the run on the same model
    (:func:`base_variant`): its baselines are copied from that run, not played again, and one that keeps the
    value starts from a copy of its value. Returns the metrics of :func:`~wmthesis.value.comparison.fit_and_compare`."""
    own = FREEWAY_VALUE_VARIANTS.check(variant).changes
    variant = FREEWAY_VALUE_VARIANTS.folder_name(variant)
    changes = FREEWAY_VALUE_VARIANTS.changes(variant)
    profile = profile_name(profile)
    started = time.time()
    planet_run = frozen_model(profile, seed, model_variant(variant), progress)
    work, out = value_folders(profile, seed, variant)
    work = hold(work)
    base = base_variant(variant)
    if variant != base:  # the base run's model: its baselines, and its value unless this one changes it
        default, _ = value_folders(profile, seed, base)
        start_from(work, default, ("baseline-bouts.json", "baselines.json"))  # the same episodes, played once
        if "value" not in own:
            start_from(work, default)  # the base's value, its rounds and bouts
    data = frozen_model(profile, seed, changes["data"], progress) if "data" in changes else planet_run
    start_from(work, data, (STORE,))  # a PlaNet agent's episodes are the value's first data
    with EpisodeStore(data / STORE) as store:  # a finished run's store: it holds no more
        first = len(store)
    config = for_profile(LatentValueConfig, profile, test_bouts=for_profile(ValueEvaluationConfig, profile).freeway_episodes, random_bouts=first,
                         **{**FREEWAY_VALUE, **changes.get("value", {})})
    bouts = [evaluation_seeds(seed, k) for k in range(for_profile(ValueEvaluationConfig, profile).freeway_episodes)]
    baselines = baseline_scores(planet_run, bouts, work, progress)
    planner = for_profile(ValuePlannerConfig, profile, discount=config.discount, **changes.get("planner", {}))
    return fit_and_compare(NAMES.planet_freeway_value, GAME, planet_run, work, out, config, planner, baselines, bouts,
                           profile=profile, seed=seed, progress=progress, references=REFERENCES, variant=variant,
                           started=started)


def value_rows(by_variant: dict[str | None, dict]) -> list[list[str]]:
    """The players of :func:`planet_freeway_value` runs (``by_variant``: variant, None for the
    default, or its name -> its metrics; all on the same model and episodes) as table rows: player, full
    episodes mean ± std, first 500 steps, and what it adds over UP at every step episode for
    episode (:func:`~wmthesis.metrics.paired_difference`, ± its standard error). The baselines come
    once, from the first run; a variant that keeps the value gives only its planner's row."""
    first = next(iter(by_variant.values()))
    up = first["baselines"]["always-up"].get("returns")  # runs saved since 2026-11-26 keep them

    def row(player: str, full: dict, first_mean: float, returns) -> list[str]:
        gain = "" if up is None or returns is None else "{difference:+.1f} ± {standard_error:.1f}".format(
            **paired_difference(returns, up))
        return [player, f"{full['mean']:.1f} ± {full['std']:.1f}", f"{first_mean:.1f}", gain]

    rows = [row(BASELINE_LABELS[name] + (", H12 (thesis)" if name == "planet" else ""), b["full"], b["first"]["mean"],
                b.get("returns")) for name, b in first["baselines"].items()]
    for variant, m in by_variant.items():
        label = variant or "default"
        if label == "default" or {"value", "model"} & set(FREEWAY_VALUE_VARIANTS[label].changes):
            rows.append(row(f"value alone ({label})", m["value"], m.get("value_first", {}).get("mean", float("nan")),
                            m["returns"]))
        planner = m["value_planner"]
        rows.append(row(f"CEM, H{planner['config']['horizon']}, with the value at its end ({label})", planner["full"],
                        planner["first"]["mean"], planner["returns"]))
    return rows


def validate_planners(profile: str | None = None, seed: int = 0, levers: tuple[str, ...] | None = None,
                      bouts: int | None = None, progress: bool = True, variant: str | None = None,
                      executor=None) -> dict[str, dict]:
    """CEM with the value agent of ``variant``'s run (:func:`planet_freeway_value`, run first if
    need be) under each of ``levers`` (names in :data:`FREEWAY_PLANNER_LEVERS`; all by default) on
    ``bouts`` (the profile's ``ValueEvaluationConfig.freeway_lever_episodes`` by default) of the value's validation
    episodes (:func:`~wmthesis.value.play.validation_seeds`: apart from the evaluation
    episodes), in one pool (``executor``, :func:`~wmthesis.utils.process_pool`; two at a time by default), each lever cached in the folder of the run that fitted the value
    (:func:`value_variant`: a variant that changes the planner alone shares its base's levers).
    Returns lever -> the planner's ``config`` and its ``full`` and ``first``-500-step scores."""
    profile = profile_name(profile)
    levers, episodes = checked_levers("Freeway planner lever", levers, FREEWAY_PLANNER_LEVERS, bouts, for_profile(ValueEvaluationConfig, profile).freeway_lever_episodes)
    fitted = value_variant(variant)
    metrics = planet_freeway_value(profile, seed, fitted, progress)
    work, _ = value_folders(profile, seed, fitted)
    planners = {lever: for_profile(ValuePlannerConfig, profile, discount=metrics["config"]["discount"], **FREEWAY_PLANNER_LEVERS[lever])
                for lever in levers}
    return lever_scores(frozen_model(profile, seed, model_variant(fitted), progress), work, metrics, planners,
                        [validation_seeds(seed, k) for k in range(episodes)], progress, game=GAME, executor=executor)


CHECK_VERSION = 2  # open_loop_check's cache: 2 added the diagnostics' embedding_spread


def open_loop_check(profile: str | None = None, seed: int = 0, progress: bool = True,
                    model: str = FREEWAY_MODEL) -> dict:
    """Can the frozen Freeway model imagine the cars a planner must dodge? Its open-loop error on
    the moving pixels of held-out random episodes (:func:`~wmthesis.planet.study.score_run`, as in
    notebook 05's model study: the profile's context frames filtered, then its horizon predicted
    from the actions alone) beside the baselines "repeat last" and "mean frame", with the KL per
    step to set against the free nats (below them the prior learns nothing from that step), and
    the error of the context frames' reconstructions (``filtered``: does the model see the cars in
    the frames it is given?).
    ``model``: a ``planet-freeway`` variant (trained first if need be). Cached in the results
    folder of the value fitted on that model, for the model's updates. Returns
    ``errors`` (name -> (horizon,) errors), ``filtered`` (``model`` and ``mean frame`` -> (context,)
    errors), ``diagnostics``, ``kl_scale``, ``free_nats``,
    ``updates``, ``below_mean_frame`` (the horizons where the model beats the mean frame) and
    ``files`` (the figure)."""
    profile = profile_name(profile)
    planet_run = frozen_model(profile, seed, model, progress)
    _, out = value_folders(profile, seed, None if model == FREEWAY_MODEL else model)
    sizes, (_, config, meta) = study_sizes(profile), load_planet(planet_run)
    key = {"updates": meta["updates"], "sizes": sizes, "version": CHECK_VERSION}
    cached = read_json(out / "open_loop_check.json")
    if cached is None or cached.get("key") != key:
        held = held_out_store(data_dir(profile, NAMES.planet_freeway_value) / f"held-out-seed{seed}.h5", GAME, config,
                              10_000 + seed, sizes["held_out"])
        with EpisodeStore(planet_run / STORE) as store:
            background, mean_frame = scene(store)
        with EpisodeStore(held) as episodes:
            score = score_run(planet_run, episodes, background, mean_frame, context=sizes["context"],
                              horizon=sizes["horizon"], sequences=sizes["sequences"], seed=seed)
        cached = {"key": key, "score": {k: v for k, v in score.items() if k != "rollout"}}
        write_json(out / "open_loop_check.json", cached)
    score = cached["score"]
    figure = save_figure(study_error_figure({model: [score]}, title="Freeway: open-loop error on the moving pixels "
                                                                   "(held-out random episodes)"),
                         out / "open_loop_check.png")
    errors, mean = score["errors"]["model"], score["errors"]["mean frame"]
    return {**score, "below_mean_frame": [h + 1 for h, (a, b) in enumerate(zip(errors, mean)) if a < b],
            "files": [str(figure)]}


# What would a planner with a perfect model score? Horizon 1 is UP at every step; the episodes
# are the first of the evaluation episodes (Freeway is deterministic: the same cars on each).
LOOKAHEAD_HORIZONS = (1, 3, 6, 12)


def lookahead_bout(profile: str, horizon: int, env_seed: int) -> dict:
    """One episode of Freeway with the profile's PlaNet settings, planned in the emulator itself
    (:func:`~wmthesis.envs.freeway.play_lookahead`, ``horizon`` steps): its ``return``, the
    return of its first 500 steps and its ``steps``."""
    env = make_planet_env(GAME, planet_config(GAME, profile))
    try:
        return bout_result(play_lookahead(env, horizon, env_seed)["rewards"])
    finally:
        env.close()


def lookahead_ceiling(profile: str | None = None, seed: int = 0, horizons: tuple[int, ...] = LOOKAHEAD_HORIZONS,
                      progress: bool = True) -> dict[int, dict]:
    """The ceiling of planning on Freeway: a planner whose model is the emulator itself
    (:mod:`wmthesis.envs.freeway`: "wait, then UP" plans of ``horizon`` steps, scored by crossings
    and the chicken's height) on the first ``ValueEvaluationConfig.lookahead_episodes`` of the evaluation episodes
    (:func:`~wmthesis.value.play.evaluation_seeds`), for each of ``horizons``. Each episode is
    saved as it ends in the default value's results folder (``lookahead-bouts.json``). Returns
    horizon -> ``full`` and ``first``-500-step scores with their returns."""
    profile = profile_name(profile)
    _check_horizons(horizons)
    seeds = [evaluation_seeds(seed, k)[0] for k in range(for_profile(ValueEvaluationConfig, profile).lookahead_episodes)]
    _, out = value_folders(profile, seed)
    plays = played_bouts(out / "lookahead-bouts.json", {"seeds": seeds, "horizons": list(horizons)}, progress,
                         [(lookahead_bout, profile, h, s) for h in horizons for s in seeds])
    return {h: bout_scores(plays[i * len(seeds):(i + 1) * len(seeds)]) for i, h in enumerate(horizons)}


def _check_horizons(horizons: tuple[int, ...]) -> None:
    """Refuse lookahead ``horizons`` that are not all positive integers (or none at all), before
    anything is played or fitted."""
    if not horizons or any(isinstance(h, bool) or not isinstance(h, int) or h < 1 for h in horizons):
        raise ValueError(f"lookahead horizons must be positive integers, got {tuple(horizons)!r}")


def when_to_wait(profile: str | None = None, seed: int = 0, variant: str | None = "adam-log", horizon: int = 6,
                 progress: bool = True) -> dict:
    """Does a learned model know when to wait? Along the first ``ValueEvaluationConfig.plan_steps`` steps of the
    emulator lookahead's own episode (:func:`~wmthesis.envs.freeway.play_lookahead`, ``horizon``
    steps, the first evaluation episode: it waits, NOOP, where going on would meet a car), the
    action each planner of :func:`~wmthesis.value.planner.plan_choices` takes from the
    same belief, filtered from the same frames: the thesis's CEM on the model of ``variant``'s
    value run (:func:`planet_freeway_value`, run first if need be), CEM with its value and the
    value alone. Cached in that run's results folder (``when_to_wait.json``). Returns ``steps``,
    ``waits`` (the lookahead's NOOPs among them), ``choices`` (planner -> actions, the
    lookahead's under ``lookahead``) and per planner :func:`hold_back_shares`."""
    profile = profile_name(profile)
    _check_horizons((horizon,))
    metrics = planet_freeway_value(profile, seed, variant, progress)
    work, _ = value_folders(profile, seed, value_variant(variant))
    planner = ValuePlannerConfig(**with_added_defaults(ValuePlannerConfig, metrics["value_planner"]["config"]))
    steps = for_profile(ValueEvaluationConfig, profile).plan_steps
    key = {"horizon": horizon, "steps": steps, "planner": dataclasses.asdict(planner),
           "agent": metrics.get("agent_rounds", metrics["best_round"])}
    _, out = value_folders(profile, seed, variant)
    cached = read_json(out / "when_to_wait.json")
    if cached is None or cached.get("key") != key:
        model, planet, _ = load_planet(frozen_model(profile, seed, model_variant(variant), progress))
        env = TimeLimit(make_planet_env(GAME, planet), max_episode_steps=steps)  # the steps compared, no more
        try:
            episode = play_lookahead(env, horizon, evaluation_seeds(seed, 0)[0])
        finally:
            env.close()
        frames, taken = episode["observations"][:steps], episode["actions"][:steps]
        choices = plan_choices(model, load_value(work, model), planet, planner, frames, taken, seed)
        cached = {"key": key, "choices": {"lookahead": taken.tolist(), **{n: c.tolist() for n, c in choices.items()}}}
        write_json(out / "when_to_wait.json", cached, indent=None)
    lookahead = np.asarray(cached["choices"]["lookahead"])
    shares = {name: hold_back_shares(lookahead, np.asarray(c)) for name, c in cached["choices"].items() if name != "lookahead"}
    return {"steps": len(lookahead), "waits": int((lookahead != UP).sum()), "choices": cached["choices"], "planners": shares}


def hold_back_shares(lookahead, picks) -> dict[str, float]:
    """A planner's ``picks`` (T,) beside the ``lookahead``'s actions (T,) on the same steps:
    ``waits_kept`` (the share of the lookahead's waits, any action but UP, on which it does not
    press UP either; NaN without a wait), ``ups_kept`` (the share of its UPs on which it presses
    UP), and Fisher's exact test of holding back against the lookahead's waiting (scipy):
    ``odds_ratio`` and its two-sided ``p``."""
    wait, held = np.asarray(lookahead) != UP, np.asarray(picks) != UP
    table = [[int((held & wait).sum()), int((~held & wait).sum())], [int((held & ~wait).sum()), int((~held & ~wait).sum())]]
    test = fisher_exact(table)
    return {"waits_kept": float(held[wait].mean()) if wait.any() else float("nan"),
            "ups_kept": float((~held[~wait]).mean()) if (~wait).any() else float("nan"),
            "odds_ratio": float(test.statistic), "p": float(test.pvalue)}


def freeway_plan_choices(profile: str | None = None, seed: int = 0, variant: str | None = None,
                         progress: bool = True) -> dict:
    """Where the value changes the plan on Freeway
    (:func:`~wmthesis.value.comparison.compare_plans` on a :func:`planet_freeway_value`
    run of ``variant``, run first if need be; cached)."""
    profile = profile_name(profile)
    metrics = planet_freeway_value(profile, seed, variant, progress)
    work, out = value_folders(profile, seed, variant)
    return compare_plans(GAME, frozen_model(profile, seed, model_variant(variant), progress), work, out, metrics,
                         for_profile(ValueEvaluationConfig, profile).plan_steps, seed)


__all__ = ["planet_freeway_value", "value_folders", "model_variant", "base_variant", "value_variant", "validate_planners",
           "frozen_model", "value_rows", "freeway_plan_choices", "open_loop_check", "lookahead_ceiling", "lookahead_bout", "when_to_wait", "hold_back_shares", "LOOKAHEAD_HORIZONS", "baseline_scores", "BASELINES", "UP", "FREEWAY_VALUE", "GAME", "REFERENCES"]
