"""Sokoban solved by search in a learned model (beyond the thesis; its aim, chapter 1): expert
iteration, then the table on unseen levels, the model's accuracy, solutions saved and replayed."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from wmthesis.config import for_profile, profile_name
from wmthesis.declarations import NAMES
from wmthesis.envs.boxoban import BOXOBAN_SPLITS, load_levels
from wmthesis.metrics import score_summary
from wmthesis.references import BOXOBAN, published
from wmthesis.runs import (cached, first_run_seconds, hold, jsonable, machine_name, over_sittings, read_json,
                           releasing_holds, results_folder, run_header, run_jobs, work_folder as run_folder, write_json)
from wmthesis.sokoban_search import accuracy
from wmthesis.sokoban_search.agent import EVAL_PURPOSE, level_seeds, random_play
from wmthesis.sokoban_search.cells import code_table, render_cells
from wmthesis.sokoban_search.config import SokobanEvaluationConfig, SokobanSearchConfig
from wmthesis.sokoban_search.evaluation import (agent_row, astar_board_row, astar_row, check_solutions,
                                                random_board_row, random_row, replay_states, THESIS_ROW, thesis_row)
from wmthesis.sokoban_search.figures import plot_plan, plot_rounds, record_solution
from wmthesis.sokoban_search.iteration import (evaluation_search, load_run, policy_afterwards, schedule,
                                               train_search_agent)
from wmthesis.sokoban_search.report import (BOXOBAN_AGENTS, EVAL_PARTS, boxoban_job, boxoban_reference, boxoban_row,
                                            evaluation_record, generated_job, level_plays, merged_parts)
from wmthesis.sokoban_search.variants import GENERATED, LEVERS
from wmthesis.variants import no_variant
from wmthesis.viz import save_figure



def evaluation_levels(profile: str | None) -> SokobanEvaluationConfig:
    """The profile's levels to evaluate on (report, reference, validation)."""
    return for_profile(SokobanEvaluationConfig, profile)


def work_folder(profile: str, seed: int) -> Path:
    """Where a run's experience and checkpoints live (``solve-sokoban`` reads them)."""
    return run_folder(profile, NAMES.sokoban_search, seed)


@releasing_holds
def sokoban_search(profile: str | None = None, seed: int = 0, variant: str | None = None,
                   progress: bool = True) -> dict:
    """Train the search agent from pixels (resumable), evaluate it on ``eval_levels`` unseen
    levels of each of our generator's variants (:data:`GENERATED`) and on Boxoban's report files
    beside random play, the thesis, and its search with the true rules and A* (the reference rows,
    on the first reference levels of them: :func:`evaluation_levels`); return the metrics."""
    no_variant(NAMES.sokoban_search, variant)
    profile = profile_name(profile)
    started = time.time()
    cfg = for_profile(SokobanSearchConfig, profile, seed=seed, inputs="pixels")
    work, out = hold(work_folder(profile, seed)), results_folder(NAMES.sokoban_search, profile, seed)
    runs = {"pixels": _trained_run(work / "pixels", cfg, progress)}
    trained_at = time.time()
    tables, model_accuracy, solutions = {}, {}, {}
    seeds = level_seeds(seed, EVAL_PURPOSE, cfg.eval_levels)
    generated = list(GENERATED)  # unseen levels of our generator; Boxoban's below
    agents = {"pixels": (work / "pixels", cfg, False),
              "simulator": (work / "pixels", cfg, True)}  # its search and value with the true rules
    played_on = {"pixels": seeds, "simulator": seeds[:evaluation_levels(profile).reference_levels]}  # the reference: the first
    evaluations = {(name, variant, part): generated_job(work, name, agents[name], variant, played_on[name], part)
                   for variant in reversed(generated) for name in agents
                   for part in range(EVAL_PARTS)}  # the larger boards first: the pool ends together
    boxoban = _boxoban_jobs(work, agents, profile)
    run_jobs({**evaluations, **boxoban}, progress)
    for variant in generated:
        played = {name: merged_parts([read_json(evaluations[name, variant, part][0]) for part in range(EVAL_PARTS)], seeds)
                  for name in agents}
        tables[variant] = {"random play": cached(work / f"random-{variant}.json", random_row, variant, seeds),
                           THESIS_ROW: thesis_row(variant),
                           "agent, learned model (pixels)": played["pixels"]["row"],
                           "agent, true simulator (pixels)": played["simulator"]["row"],
                           "A* (reference)": cached(work / f"astar-{variant}-{len(played_on['simulator'])}.json",
                                                     astar_row, variant, played_on["simulator"])}
        model_accuracy[variant] = {name: _accuracy(run, variant, seed, cfg.eval_levels,
                                                   played["simulator"]["solutions"])
                                   for name, run in runs.items()}
        solutions[variant] = played["pixels"]["solutions"]
        for name in runs:
            write_json(out / f"solutions-{name}-{variant}.json", played[name]["solutions"], indent=None)
    boxoban_tables = {kind: _boxoban_table(kind, boxoban, profile) for kind in BOXOBAN_SPLITS["report"]}
    figures, recording = _figures(out, runs, generated, solutions)
    last = generated[-1]
    replayed = check_solutions(last, solutions[last][:20])
    solved = len(solutions[last])
    metrics = {
        **run_header(NAMES.sokoban_search, profile, seed, time.time() - started),
        "score": score_summary([1.0] * solved + [0.0] * (cfg.eval_levels - solved)),
        "summary": f"{last} from pixels: {solved} of {cfg.eval_levels} unseen levels solved "
                   f"({100 * solved / cfg.eval_levels:.1f}%)",
        "env_steps": {name: int(sum(h["env_steps"] for h in run.history)) for name, run in runs.items()},
        "history": {name: run.history for name, run in runs.items()}, "tables": tables,
        "boxoban": {"tables": boxoban_tables, "splits": BOXOBAN_SPLITS,
                    "reference": {kind: f"{ref.name}: {ref.value}% ({ref.source})" for kind, ref in BOXOBAN.items()}},
        "accuracy": model_accuracy, "replayed_solutions": {"checked": len(replayed), "solved": int(sum(replayed))},
        "reference": published(NAMES.sokoban_search),
        "files": {"figures": [str(f) for f in figures], "recording": str(recording),
                  "solutions": [str(out / f"solutions-{n}-{v}.json") for n in runs for v in generated]},
    }
    metrics["training_wall_seconds"] = training_seconds(runs["pixels"].history)  # its stages', over every sitting
    metrics["first_run_wall_seconds"] = first_run_seconds(out / "metrics.json", over_sittings(
        metrics["wall_seconds"], (metrics["training_wall_seconds"], trained_at - started)))
    metrics["search"] = evaluation_record(cfg)
    metrics["evaluation_wall_seconds"] = evaluation_seconds(read_json(out / "metrics.json"), metrics["search"],
                                                             time.time() - trained_at)
    write_json(out / "metrics.json", jsonable(metrics))
    return metrics


AFTERWARDS = ("prior-afterwards",)  # on the baseline's run with a policy prior fitted after it
SEARCH_FIELDS = ("budget", "eval_budget", "batch", "weights", "doubt", "replans")  # a lever of these alone needs no training


@releasing_holds
def validate(lever: str, profile: str | None = None, seed: int = 0, levels: int | None = None,
             progress: bool = True) -> dict:
    """The pixel agent with a lever of :data:`LEVERS` (trained if need be, resumable) on the first
    ``levels`` levels of each validation set (:data:`BOXOBAN_SPLITS`); the rows (solve rate,
    nodes and seconds per level), also written to the run's results folder as
    ``validation-LEVER.json``."""
    changes = LEVERS.changes(LEVERS.check(lever).name)
    profile = profile_name(profile)
    levels = evaluation_levels(profile).validation_levels if levels is None else int(levels)
    cfg = for_profile(SokobanSearchConfig, profile, seed=seed, inputs="pixels", **changes)
    search_only = set(changes) <= set(SEARCH_FIELDS) or lever in AFTERWARDS  # the baseline's run
    trained = for_profile(SokobanSearchConfig, profile, seed=seed, inputs="pixels") if search_only else cfg
    folder = hold(work_folder(profile, seed) / ("pixels" if search_only else f"lever-{lever}"))
    run = _trained_run(folder, trained, progress)
    if lever in AFTERWARDS:
        policy_afterwards(folder, run, trained, progress)  # once, before the jobs share it
    name = "validation" if lever == "baseline" or not search_only else f"validation-{lever}"
    jobs = {(kind, part): boxoban_job(folder / f"{name}-{kind}-{levels}-{part}.json",
                                       folder, trained, source, levels, part, False, evaluation_search(cfg))
            for kind, source in BOXOBAN_SPLITS["validation"].items() for part in range(EVAL_PARTS)}
    run_jobs(jobs, progress)
    rows = {kind: {**agent_row(level_plays(jobs, kind)), "source": f"{source}, its first {levels} levels"}
            for kind, source in BOXOBAN_SPLITS["validation"].items()}
    result = {"lever": lever, "changes": changes, "profile": profile, "seed": seed, "rows": rows,
              "search": evaluation_record(cfg),
              "env_steps": int(sum(h["env_steps"] for h in run.history)), "history": run.history}
    out = results_folder(NAMES.sokoban_search, profile, seed)
    write_json(out / f"validation-{lever}.json", jsonable(result))
    return result


@releasing_holds
def evaluate_report(profile: str | None = None, seed: int = 0, levels: int = 1000, progress: bool = True) -> dict:
    """The pixel agent that :func:`sokoban_search` trains (trained here first, alone, if the
    experiment has not) on the first ``levels`` levels of each report set (:data:`BOXOBAN_SPLITS`),
    beyond the experiment's own report levels: the closing figures. Resumable level by
    level, and each level another evaluation of the same run played as this one would (the same
    search, or a play under a smaller budget that never reached it) is taken from it. Returns,
    and writes to the run's results folder as ``boxoban-report-LEVELS.json``, each kind's row
    (solve rate, nodes and seconds per level, solutions replayed, failed levels)."""
    profile = profile_name(profile)
    cfg = for_profile(SokobanSearchConfig, profile, seed=seed, inputs="pixels")
    work = hold(work_folder(profile, seed))
    run = _trained_run(work / "pixels", cfg, progress)  # the experiment's own pixel run, alone if need be
    jobs = {("pixels", kind, part): boxoban_job(work / f"eval-boxoban-pixels-{kind}-{levels}-{part}.json",
                                                 work / "pixels", cfg, source, levels, part)
            for kind, source in BOXOBAN_SPLITS["report"].items() for part in range(EVAL_PARTS)}
    run_jobs(jobs, progress)
    result = {"profile": profile, "seed": seed, "levels": levels, "search": evaluation_record(cfg),
              "env_steps": int(sum(h["env_steps"] for h in run.history)),
              "training_wall_seconds": training_seconds(run.history),
              "machine": machine_name(),
              "rows": {kind: boxoban_row(level_plays(jobs, "pixels", kind), source, load_levels(source))
                       for kind, source in BOXOBAN_SPLITS["report"].items()}}
    out = results_folder(NAMES.sokoban_search, profile, seed)
    write_json(out / f"boxoban-report-{levels}.json", jsonable(result))
    return result


def _boxoban_jobs(work: Path, agents: dict, profile: str) -> dict:
    """The Boxoban evaluations as :func:`run_jobs` jobs, keyed (row, kind, part): each agent
    of ``agents`` (name: (folder, cfg, simulator)) on the first levels of each report file set
    (:func:`evaluation_levels`: the report levels for pixels, the reference levels for the true rules), in parts;
    random play on the pixel agent's levels and A* on the reference's, whole."""
    jobs, sizes = {}, evaluation_levels(profile)
    for kind, source in BOXOBAN_SPLITS["report"].items():
        for name, (folder, cfg, simulator) in agents.items():
            count = sizes.report_levels if name == "pixels" else sizes.reference_levels
            jobs.update({(name, kind, part): boxoban_job(work / f"eval-boxoban-{name}-{kind}-{count}-{part}.json",
                                                          folder, cfg, source, count, part, simulator)
                         for part in range(EVAL_PARTS)})
        for name, row, count in (("random", random_board_row, sizes.report_levels),
                                 ("astar", astar_board_row, sizes.reference_levels)):
            jobs[name, kind, 0] = (work / f"{name}-boxoban-{kind}-{count}.json", (boxoban_reference, row, source, count),
                                   None)
    return jobs


def _boxoban_table(kind: str, jobs: dict, profile: str) -> dict:
    """A kind's Boxoban rows (random play, the thesis, the agents, A*), each agent's parts
    merged in level order, with its source and how many solutions an independent replay
    confirmed."""
    source, rows = BOXOBAN_SPLITS["report"][kind], {}
    boards = load_levels(source)
    rows["random play"] = read_json(jobs["random", kind, 0][0])
    rows[THESIS_ROW] = thesis_row(kind)  # the thesis never played Boxoban
    for name, title in BOXOBAN_AGENTS.items():
        rows[title] = boxoban_row(level_plays(jobs, name, kind), source, boards)
    rows["A* (reference)"] = read_json(jobs["astar", kind, 0][0])
    return rows


def evaluation_seconds(previous: dict | None, search: dict, seconds: float) -> float | None:
    """The evaluation's wall time: the first complete one's with this ``search`` (``previous``, the
    metrics a run wrote before), else this call's ``seconds``; None when an evaluation with another
    search came before, since this one took the plays it would play the same from it and is no
    timing from scratch."""
    if previous is None:
        return seconds
    return previous.get("evaluation_wall_seconds") if previous.get("search") == search else None


def _trained(folder: Path, cfg) -> bool:
    run = load_run(folder, cfg)
    return run is not None and run.rounds_done == len(schedule(cfg))


def training_seconds(history: list[dict]) -> float | None:
    """A run's training wall time: the sum of its stages' (None for a run with a stage saved before
    stages were timed)."""
    seconds = [stage.get("wall_seconds") for stage in history]
    return None if None in seconds else float(sum(seconds))


def _trained_run(folder: Path, cfg, progress: bool):
    """The run in ``folder`` trained with ``cfg``, trained (or finished: it resumes) here first if need be."""
    if not _trained(folder, cfg):
        train_search_agent(folder, cfg, progress)
    return load_run(folder, cfg)


def _accuracy(run, variant: str, seed: int, levels: int, plans: list[dict]) -> dict:
    """The model on random play of unseen levels, and open loop along the simulator agent's
    plans (the planner's own actions), in the model's states (codes for pixels)."""
    held_out = random_play(variant, 20_000 + seed, max(4, levels // 10))
    rows = {**held_out, "states": run.inputs.from_grid(held_out["states"]),
            "next_states": run.inputs.from_grid(held_out["next_states"])}
    to_types = None
    if run.inputs.name == "pixels":
        table = code_table(rows["states"], held_out["states"], run.model.n_codes)
        to_types = lambda codes: table[codes]  # noqa: E731  (measuring only)
    sequences = [(run.inputs.from_grid(states), actions) for states, actions in replay_states(variant, plans)]
    return {"one_step": accuracy.one_step(run.model, rows, to_types),
            "open_loop": accuracy.open_loop(run.model, sequences, to_types=to_types)}


def _figures(out: Path, runs: dict, generated: list, solutions: dict):
    """Solve rate by round (both inputs); the pixel model's boards against the real ones along
    the longest solution of the last variant (the model fed its own predictions, decoded to
    frames); a recording of it."""
    figures = [save_figure(plot_rounds({name: run.history for name, run in runs.items()}), out / "rounds.png")]
    variant = next((v for v in reversed(generated) if solutions[v]), None)
    if variant is None:
        return figures, None
    record = max(solutions[variant], key=lambda r: r["steps"])
    (real, actions), = replay_states(variant, [record])
    inputs, model = runs["pixels"].inputs, runs["pixels"].model
    predicted = [inputs.from_grid(real[:1])[0]]
    for action in actions:
        predicted.append(model.step(predicted[-1][None], np.array([action]))[0][0])
    every = max(1, len(real) // 10)
    figures.append(save_figure(plot_plan(render_cells(real), inputs.coder.decode(np.stack(predicted)), every),
                               out / "plan.png"))
    return figures, record_solution(out / "solved.rrd", variant, record)


__all__ = ["sokoban_search", "validate", "evaluate_report", "work_folder", "training_seconds", "evaluation_seconds",
           "evaluation_levels"]
