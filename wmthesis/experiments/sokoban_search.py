"""Sokoban solved by search in a learned model (beyond the thesis; its aim, chapter 1): expert
iteration, then the table on unseen levels, the model's accuracy, solutions saved and replayed."""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from wmthesis.config import SokobanSearchConfig, for_profile, profile_name
from wmthesis.experiments.results import _first_run_seconds, _jsonable, _read_json, _run_header
from wmthesis.metrics import score_summary
from wmthesis.sokoban_search import accuracy
from wmthesis.sokoban_search.agent import level_seeds, random_play
from wmthesis.sokoban_search.evaluation import (THESIS_SOLVED, agent_row, astar_row, check_solutions, play_levels,
                                                random_row, trajectories)
from wmthesis.sokoban_search.figures import plot_plan, plot_rounds, record_solution, results_table
from wmthesis.sokoban_search.iteration import train_search_agent
from wmthesis.sokoban_search.search import Simulator
from wmthesis.utils import atomic_path, data_dir, hold, releasing_holds
from wmthesis.viz import save_figure

# Published figures, recalled (issue 14), not re-checked here.
SOKOBAN_SEARCH_REFERENCE = {
    "thesis": "0 levels solved (5.3, 5.5)",
    "I2A (Racaniere et al. 2017)": "about 85% of unseen 10x10 4-box levels, after about 1e9 environment steps",
    "DRC (Guez et al. 2019)": "about 99% of unfiltered Boxoban, after about 1e9 environment steps",
}
EVAL_PURPOSE = 1000  # level_seeds' stream of the evaluation levels


def work_folder(profile: str, seed: int) -> Path:
    """Where a run's experience and checkpoints live (``solve-sokoban`` reads them)."""
    return data_dir(profile, "sokoban-search", f"seed{seed}")


@releasing_holds
def sokoban_search(profile: str | None = None, seed: int = 0, progress: bool = True) -> dict:
    """Train the search agent (resumable), evaluate it on ``eval_levels`` unseen levels of each
    variant beside random play, the thesis, the true simulator and A*; return the metrics."""
    profile = profile_name(profile)
    started = time.time()
    cfg = for_profile(SokobanSearchConfig, profile, seed=seed)
    work, out = hold(work_folder(profile, seed)), data_dir("results", "sokoban-search", f"{profile}-seed{seed}")
    run = train_search_agent(work, cfg, progress)
    tables, model_accuracy, solutions = {}, {}, {}
    for variant in cfg.variants:
        seeds = level_seeds(seed, EVAL_PURPOSE, cfg.eval_levels)
        agent_plays = play_levels(run.agent(cfg), variant, seeds, f"{variant}: agent", progress)
        simulator_plays = play_levels(run.agent(cfg, Simulator()), variant, seeds, f"{variant}: simulator", progress)
        tables[variant] = {"random play": _cached(work / f"random-{variant}.json", random_row, variant, seeds),
                           "thesis": {"solve_rate": THESIS_SOLVED},
                           "agent, learned model (grid)": agent_row(agent_plays),
                           "agent, true simulator": agent_row(simulator_plays),
                           "A* (reference)": _cached(work / f"astar-{variant}.json", astar_row, variant, seeds)}
        held_out = random_play(variant, 20_000 + seed, max(4, cfg.eval_levels // 10))
        model_accuracy[variant] = {"random play": accuracy.one_step(run.model, held_out),
                                   "open loop": accuracy.open_loop(run.model, trajectories(simulator_plays))}
        solutions[variant] = [p.record() for p in agent_plays if p.solved]
        with atomic_path(out / f"solutions-{variant}.json") as tmp:
            tmp.write_text(json.dumps(solutions[variant]))
    figures, recording = _figures(out, run, cfg, solutions)
    last = cfg.variants[-1]
    replayed = check_solutions(last, solutions[last][:20])
    solved = solutions[last]
    metrics = {
        **_run_header("sokoban-search", profile, seed, time.time() - started),
        "score": score_summary([1.0] * len(solved) + [0.0] * (cfg.eval_levels - len(solved))),
        "summary": f"{last}: {len(solved)} of {cfg.eval_levels} unseen levels solved "
                   f"({100 * len(solved) / cfg.eval_levels:.1f}%)",
        "env_steps": int(sum(h["env_steps"] for h in run.history)),
        "history": run.history, "tables": tables, "accuracy": model_accuracy,
        "replayed_solutions": {"checked": len(replayed), "solved": int(sum(replayed))},
        "reference": SOKOBAN_SEARCH_REFERENCE,
        "files": {"figures": [str(f) for f in figures], "recording": str(recording),
                  "solutions": [str(out / f"solutions-{v}.json") for v in cfg.variants]},
    }
    metrics["first_run_wall_seconds"] = _first_run_seconds(out / "metrics.json", metrics["wall_seconds"])
    with atomic_path(out / "metrics.json") as tmp:
        tmp.write_text(json.dumps(_jsonable(metrics), indent=1))
    return metrics


def _cached(path: Path, fn, *args) -> dict:
    """``fn(*args)``, kept in ``path`` (a re-run reads it)."""
    row = _read_json(path)
    if row is None:
        row = fn(*args)
        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(row))
    return row


def _figures(out: Path, run, cfg, solutions: dict):
    """Solve rate by round; the model's boards against the real ones along the longest saved
    solution of the last variant (the model fed its own predictions); a recording of it."""
    from wmthesis.sokoban_search.agent import grid_env, grid_state

    figures = [save_figure(plot_rounds(run.history), out / "rounds.png")]
    variant = cfg.variants[-1]
    records = solutions[variant] or solutions[cfg.variants[0]]
    variant = variant if solutions[variant] else cfg.variants[0]
    if not records:
        return figures, None
    record = max(records, key=lambda r: r["steps"])
    env = grid_env(variant)
    real = [grid_state(env, env.reset(seed=record["seed"])[0])]
    for action in record["actions"]:
        real.append(grid_state(env, env.step(action)[0]))
    predicted = [real[0]]
    for action in record["actions"]:
        predicted.append(run.model.step(predicted[-1][None], np.array([action]))[0][0])
    every = max(1, len(real) // 10)
    figures.append(save_figure(plot_plan(np.stack(real), np.stack(predicted), every), out / "plan.png"))
    return figures, record_solution(out / "solved.rrd", variant, record)


__all__ = ["sokoban_search", "SOKOBAN_SEARCH_REFERENCE", "work_folder", "results_table"]
