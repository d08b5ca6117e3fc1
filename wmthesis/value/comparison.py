"""A value run on a frozen PlaNet model, as the Boxing and Freeway value experiments make one
(beyond the thesis): the value fitted (:mod:`~wmthesis.value.rounds`), CEM with it
at the end of its horizon played on the evaluation bouts beside the baselines, the metrics written
(:func:`fit_and_compare`); the planner's levers on validation bouts (:func:`lever_scores`); and
where the value changes the plan (:func:`compare_plans`)."""
from __future__ import annotations

import dataclasses
import shutil
import time
from pathlib import Path

import numpy as np

from wmthesis.data import EpisodeStore
from wmthesis.declarations import NAMES
from wmthesis.metrics import score_difference, score_summary
from wmthesis.planet.bouts import FIRST_STEPS
from wmthesis.value.config import LatentValueConfig, ValuePlannerConfig
from wmthesis.planet.shipped import AGENT_NAME
from wmthesis.planet.figures import learning_curve_figure, plan_choices_figure
from wmthesis.value.agent_file import save_value_agent
from wmthesis.value.own_rewards import fit_for_planners
from wmthesis.planet.train import CHECKPOINT as PLANET_CHECKPOINT, load_planet
from wmthesis.planet.frames import make_planet_env
from wmthesis.value.bouts import cached_plan, value_planner_scores, value_planners_scores
from wmthesis.value.planner import PLANNERS, plan_choices
from wmthesis.value.rounds import CHECKPOINT, STORE, load_value, train_value
from wmthesis import runs as run_store
from wmthesis.runs import atomic_path, first_run_seconds, over_sittings, read_json, run_header, unchanged_run, write_json
from wmthesis.stamp import git_commit
from wmthesis.training import with_added_defaults
from wmthesis.utils import check_choice
from wmthesis.viz import image_grid, save_figure


VALUE_EXPERIMENTS = (NAMES.planet_boxing_value, NAMES.planet_freeway_value)  # their runs' checkpoint is the value's


def frozen_agent(experiment: str, profile: str, seed: int, variant: str | None = None,
                 progress: bool = True) -> tuple[dict, Path]:
    """The metrics and work folder of the run (``experiment``'s ``variant``) a recipe builds on: a
    PlaNet run a value is fitted on, or a value run (:data:`VALUE_EXPERIMENTS`) whose planners are
    played. The agent that ships where the run's checkpoint is not here (its agent file and
    committed metrics: a fresh clone fits a value without training PlaNet again, and plays a
    value's planners without fitting it), else the run, made first or resumed
    (:func:`~wmthesis.runs.built_on`)."""
    work = run_store.work_folder(profile, experiment, seed, variant)
    metrics = read_json(run_store.results_folder(experiment, profile, seed, variant) / "metrics.json")
    checkpoint = CHECKPOINT if experiment in VALUE_EXPERIMENTS else PLANET_CHECKPOINT
    if metrics is None or (work / checkpoint).exists() or not (work / AGENT_NAME).is_file():
        metrics = run_store.built_on(experiment, profile, seed, variant, progress)
    return metrics, work


def checked_levers(kind: str, names: tuple[str, ...] | None, choices: dict, count: int | None,
                   default: int) -> tuple[tuple[str, ...], int]:
    """The levers (or rules) to validate: ``names`` (all of ``choices`` when None), each refused
    unless it is one of ``choices``, and how many validation bouts each plays, ``count``
    (``default`` when None), at least one."""
    names = tuple(choices) if names is None else tuple(names)
    for name in names:
        check_choice(kind, name, tuple(choices))
    count = default if count is None else count
    if count < 1:
        raise ValueError(f"the validation bouts must be >= 1, got {count}")
    return names, count


def lever_scores(planet_run: Path, work: Path, metrics: dict, planners: dict, bouts: list, progress: bool,
                 game: str = "boxing", executor=None, folder: str = "planner-validation") -> dict[str, dict]:
    """CEM with the value agent of the finished value run in ``work`` (its ``metrics``) under
    each lever of ``planners`` (name -> ValuePlannerConfig) on ``bouts``, all in one pool
    (:func:`value_planners_scores`), each cached in
    ``work/<folder>/<the lever's name, lower case, dashes>/scores.json``. Returns
    name -> the planner's ``config`` and its ``full`` and ``first``-500-step scores."""
    config = LatentValueConfig(**with_added_defaults(LatentValueConfig, metrics["config"]))
    agent = agent_key(chosen_rounds(metrics), config)
    fit_for_planners(planet_run, work, planners.values(), config, int(metrics["seed"]))
    caches = [(planner, work / folder / slug(name) / "scores.json") for name, planner in planners.items()]
    return dict(zip(planners, value_planners_scores(planet_run, work, caches, bouts, agent, progress, game, executor)))


def slug(name: str) -> str:
    """A lever's or rule's name as a folder or file name: lower case, dashes for the rest."""
    return "".join(c if c.isalnum() else "-" for c in name.lower()).strip("-")


def start_from(work: Path, default: Path, names: tuple[str, ...] | None = None) -> None:
    """Start a value run in ``work`` from a copy of files of ``default`` (by default a value
    run's bouts and values: a variant that only adds rounds; the rounds it shares are the same
    rounds), once: never over a checkpoint of its own. The last name marks the copy done."""
    names = (STORE, CHECKPOINT) if names is None else names
    if (work / names[-1]).exists() or not (default / names[-1]).exists():
        return
    for name in names:
        with atomic_path(work / name) as tmp:
            shutil.copyfile(default / name, tmp)


BASELINE_LABELS = {"planet": "PlaNet (CEM)", "random": "random play", "always-up": "UP at every step"}


def fit_and_compare(experiment: str, game: str, planet_run: Path, work: Path, out: Path, config, planner,
                    baselines: dict, bouts: list, *, profile: str, seed: int, progress: bool,
                    references: dict, variant: str | None = None, started: float | None = None) -> dict:
    """Fit the value (``config``, :func:`~wmthesis.value.rounds.train_value`) on the frozen
    model of ``planet_run`` in ``work``; play CEM with the chosen value at its end (``planner``)
    on the evaluation ``bouts``; write and return ``out/metrics.json``: ``value`` (the chosen
    round's evaluation bouts) and ``value_first`` (their first 500 steps), ``random`` and
    ``planet`` (``baselines``' full-episode scores on the same bouts), ``baselines`` (each of
    :data:`BASELINE_LABELS` played, full and first 500 steps), ``difference`` (value - random),
    ``value_planner``, the ``curve`` of rounds and its figure (with ``references``)."""
    started = time.time() if started is None else started
    model, planet, _ = load_planet(planet_run)
    env = make_planet_env(game, planet)
    fitting = time.time()
    try:
        run = train_value(model, planet.bits, env, config, work, seed=seed, progress=progress, first_steps=FIRST_STEPS,
                          make_env=(make_planet_env, game, planet))
    finally:
        env.close()
    fitting = time.time() - fitting  # this call's share of the rounds' seconds, which every sitting adds to
    chosen = run["agent"]
    returns = chosen["returns"]
    fit_for_planners(planet_run, work, [planner], config, seed)
    scores = value_planner_scores(planet_run, work, planner, bouts, agent_key(chosen["rounds"], config),
                                  progress, game=game)
    value, unit = score_summary(returns), "bouts" if game == "boxing" else "episodes"
    seconds = time.time() - started
    # an earlier run's time counts if it fitted on the same frozen model (the thesis's CEM played it alike)
    first = first_run_seconds(out / "metrics.json", over_sittings(seconds, (run["seconds"], fitting)),
                              lambda earlier: earlier.get("planet") == baselines["planet"]["full"])
    metrics = {**run_header(experiment, profile, seed, seconds, env=game,
                             **({} if variant is None else {"variant": variant})),
               "first_run_wall_seconds": round(first, 1),
               "headline": f"score {value['mean']:.1f} +- {value['std']:.1f} over {value['episodes']} {unit} "
                           f"({_agent_words(chosen, config, unit)}) (random play {baselines['random']['full']['mean']:.1f}, PlaNet's CEM "
                           f"{baselines['planet']['full']['mean']:.1f})",
               "value": value, "returns": returns, "random": baselines["random"]["full"],
               **({"value_first": score_summary(chosen["first_returns"])} if "first_returns" in chosen else {}),
               "difference": score_difference(returns, baselines["random"]["returns"]),
               "planet": baselines["planet"]["full"], "value_planner": scores,
               "baselines": {name: {k: b[k] for k in ("full", "first", "returns", "first_returns") if k in b}
                             for name, b in baselines.items()},
               "bouts": [list(b) for b in bouts], "curve": run["curve"], "best_round": run["best_round"],
               "agent_rounds": chosen["rounds"],
               "config": dataclasses.asdict(config)}
    earlier = unchanged_run(out / "metrics.json", metrics)
    if earlier is not None and (work / AGENT_NAME).is_file():
        return earlier  # a finished run asked again (by validate, a budget curve): its files stay as they are
    save_value_agent(work / AGENT_NAME, game, planet_run, bouts, git_commit(), value_run=work, planner=planner)  # for `play`
    metrics["files"] = {"figures": [str(save_figure(value_curve_figure(metrics, references), out / "value_curve.png"))]}
    write_json(out / "metrics.json", metrics)
    return metrics


def value_curve_figure(metrics: dict, references: dict[str, float]):
    """The value agent after each round of a value run (its ``metrics``, :func:`fit_and_compare`'s):
    the rounds that were scored, the agent where it is a mean of rounds (a run that scored no round:
    that one point, titled so), and as lines the baselines, CEM with the value and ``references``
    (label -> score)."""
    planner = metrics["value_planner"]
    lines = {BASELINE_LABELS[name]: b["full"]["mean"] for name, b in metrics["baselines"].items()}
    lines.update({f"CEM, H{planner['config']['horizon']}, with the value at its end": planner["full"]["mean"], **references})
    rounds = chosen_rounds(metrics)
    scored = any("mean" in entry for entry in metrics["curve"])  # a lean run scores no round: one point, its agent
    if not scored:
        return agent_beside_figure(metrics, rounds, lines)
    return learning_curve_figure(_value_curves(metrics["curve"], rounds, metrics["value"]),
                                 references=lines, x="episodes",
                                 title=f"{metrics['env'].capitalize()}: the value agent" + (
                                     " after each round" if scored else f", the mean of rounds {rounds[0]}-{rounds[-1]}"
                                     if len(rounds) > 1 else f" of round {rounds[0]}"))


def agent_beside_figure(metrics: dict, rounds: list[int], lines: dict[str, float]):
    """A run that scored no round: its agent (the mean of ``rounds``' values, mean ± std over the
    evaluation bouts) as one row beside ``lines`` (label -> score), best at the top."""
    import matplotlib.pyplot as plt

    value = metrics["value"]
    agent = f"the value agent (mean of rounds {rounds[0]}-{rounds[-1]})" if len(rounds) > 1 else \
        f"the value agent (round {rounds[0]})"
    rows = sorted([(agent, value["mean"], value["std"]), *((name, score, None) for name, score in lines.items())],
                  key=lambda row: row[1])
    fig, ax = plt.subplots(figsize=(7.5, 0.35 * len(rows) + 1.0))
    for y, (name, score, std) in enumerate(rows):
        ax.errorbar(score, y, xerr=std, fmt="o", color="C0" if std is not None else "gray", capsize=3)
        ax.annotate(f"{score:.1f}", (score, y), textcoords="offset points", xytext=(0, 6), ha="center", fontsize=7)
    ax.set_yticks(range(len(rows)), [name for name, _, _ in rows], fontsize=8)
    ax.set_xlabel("score over the evaluation bouts (the agent: mean ± std)")
    ax.set_ylim(-0.6, len(rows) - 0.3)
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    return fig


def _value_curves(curve: list[dict], rounds: list[int], value: dict) -> dict[str, dict]:
    """The rounds that were scored (a lean run scores none) and the agent, when it is the mean of
    ``rounds``, as :func:`~wmthesis.planet.figures.learning_curve_figure`'s curves."""
    curves = {"latent value on the PlaNet model": {"test": [entry for entry in curve if "mean" in entry]}}
    if len(rounds) > 1:
        curves[f"the mean of rounds {rounds[0]}-{rounds[-1]}"] = {
            "test": [{"episodes": curve[-1]["episodes"], "mean": value["mean"], "std": value["std"]}]}
    return curves


def chosen_rounds(metrics: dict) -> list[int]:
    """The rounds whose values make a value run's agent (its ``metrics``; a run written before an
    agent could be several rounds' mean names its chosen round alone)."""
    return metrics["agent_rounds"] if "agent_rounds" in metrics else [metrics["best_round"]]


def agent_key(rounds: list[int], config) -> int | list[int]:
    """The value agent in a cache key: its chosen round (as keys were written before the agent
    could be several rounds' mean), or the rounds it averages."""
    return rounds if config.agent_rounds else rounds[0]


def _agent_words(agent: dict, config, unit: str) -> str:
    """The value agent in a headline: its round and the validation that chose it, or its rounds."""
    rounds = agent["rounds"]
    if config.agent_rounds:
        return f"the mean of the values of rounds {rounds[0]}-{rounds[-1]}"
    return f"the value of round {rounds[0]}, chosen on {len(agent['validation'])} validation {unit}"


def compare_plans(game: str, planet_run: Path, work: Path, out: Path, metrics: dict, steps: int, seed: int) -> dict:
    """Where the value changes the plan (:func:`~wmthesis.value.planner.plan_choices`):
    on the first ``steps`` steps of the value agent's last bout of its own (in ``work``), the
    action the thesis's CEM, CEM with the chosen value (the planner of ``metrics``, a
    :func:`fit_and_compare` run) and the value alone would take from the same belief; cached in
    ``work/plan_choices.json``. Returns ``choices`` (planner -> actions), ``agreement`` (pair ->
    share of steps), ``action_names``, ``steps`` and ``files`` (the bars, and the frames where CEM
    and CEM with the value part, in ``out``)."""
    model, planet, _ = load_planet(planet_run)
    planner = ValuePlannerConfig(**with_added_defaults(ValuePlannerConfig, metrics["value_planner"]["config"]))
    with EpisodeStore(work / STORE, "r") as store:
        bout = store.episode(-1)
    frames, taken = bout["observations"][:steps], bout["actions"][:steps]
    agent = metrics["best_round"] if metrics["best_round"] is not None else metrics["agent_rounds"]  # lean: its rounds
    key = {"round": agent, "steps": len(taken), "planner": dataclasses.asdict(planner)}
    cached = cached_plan(work / "plan_choices.json", key)
    if cached is None:
        choices = plan_choices(model, load_value(work, model), planet, planner, frames, taken, seed)
        cached = {"key": key, "choices": {name: c.tolist() for name, c in choices.items()}}
        write_json(work / "plan_choices.json", cached, indent=None)
    choices = {name: np.asarray(c) for name, c in cached["choices"].items()}
    env = make_planet_env(game, planet)
    names = env.unwrapped.get_action_meanings()
    env.close()
    unit = "bout" if game == "boxing" else "episode"
    bars = save_figure(plan_choices_figure(choices, names, title=f"{game.capitalize()}, the first {len(taken)} steps of "
                                                                 f"one {unit}: the action each planner picks from the same belief"),
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


__all__ = ["BASELINE_LABELS", "VALUE_EXPERIMENTS", "agent_key", "chosen_rounds", "checked_levers", "compare_plans", "fit_and_compare", "frozen_agent", "value_curve_figure",
           "lever_scores", "slug", "start_from"]
