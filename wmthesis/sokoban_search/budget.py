"""The Sokoban agent's score against its search budget (the thesis's promise, chapter 1:
more search, more score): the same trained run on the same Boxoban levels under each node budget,
and without search, each evaluation resumable level by level.

Without search the agent keeps its model and value and looks one step ahead (:func:`greedy_play`):
each step it takes the action its model predicts to solve the level, else the one whose predicted
next state its value puts nearest the goal, states it has already stood in last (a run whose value
never trained, as in ``smoke``, takes the first action to a new state). A budget is the
nodes one search may expand (:func:`~wmthesis.sokoban_search.search.best_first`).
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from wmthesis.budget_curves import NO_SEARCH
from wmthesis.envs.boxoban import load_levels
from wmthesis.runs import partial_path, read_json, write_json
from wmthesis.sokoban_search.evaluation import board_env
from wmthesis.sokoban_search.iteration import evaluation_search, load_run
from wmthesis.sokoban_search.report import EVAL_PARTS, boxoban_job

MAX_STEPS = 120  # Boxoban's step limit, as every evaluation plays it


def greedy_play(agent, board: np.ndarray, max_steps: int = MAX_STEPS) -> dict:
    """``agent`` (a :class:`~wmthesis.sokoban_search.agent.SearchAgent`) on ``board`` (codes
    (h, w)) without search: one model call and one value call a step (see the module docstring).
    Returns a record as a search's play has (``solved``, ``steps``, ``actions``, ``expanded`` = 0,
    ``seconds``)."""
    start = time.perf_counter()
    env = board_env(board, max_steps, **agent.inputs.env_options)
    observation, _ = env.reset(options={"board": board})
    state = agent.inputs.observe(env, observation)
    visited, actions, solved, over = {state.tobytes()}, [], False, False
    while not (solved or over):
        children, _, dones, _ = agent.model.expand(state[None])
        children, dones = children[0], np.asarray(dones[0], bool)
        if dones.any():
            action = int(np.flatnonzero(dones)[0])
        else:
            estimate = (np.zeros(len(children)) if agent.heuristic is None  # a run that never solved: no value
                        else np.asarray(agent.heuristic(children), np.float64))
            seen = np.array([child.tobytes() in visited for child in children])
            action = int(np.lexsort((estimate, seen))[0])  # unvisited first, then nearest the goal
        observation, _, solved, over, _ = env.step(action)
        state = agent.inputs.observe(env, observation)
        visited.add(state.tobytes())
        actions.append(action)
    return {"solved": bool(solved), "steps": len(actions), "actions": actions, "expanded": 0, "generated": 0,
            "searches": 0, "seconds": round(time.perf_counter() - start, 4)}


def evaluate_greedy(folder: Path, cfg, source: str, count: int, part: int, partial: Path | None = None) -> dict:
    """The run in ``folder`` without search on part ``part`` (every :data:`EVAL_PARTS`-th) of the
    first ``count`` levels of a Boxoban source, saved level by level in ``partial``."""
    levels, boards = list(range(count))[part::EVAL_PARTS], load_levels(source)
    agent = load_run(folder, cfg).agent(evaluation_search(cfg))
    record = {"budget": NO_SEARCH}
    saved = (read_json(partial) or {}) if partial is not None else {}
    done = {r["level"]: r for r in saved.get("plays", [])} if saved.get("search") == record else {}
    for level in levels:
        if level not in done:
            done[level] = {"level": level, **greedy_play(agent, boards[level])}
            if partial is not None:
                write_json(partial, {"plays": list(done.values()), "search": record}, indent=None)
    return {"plays": [done[i] for i in levels], "search": record}


def budget_jobs(work: Path, folder: Path, cfg, source: str, count: int, budgets) -> dict:
    """The evaluations of the curve as :func:`~wmthesis.runs.run_jobs` jobs, keyed (budget, part):
    each budget's search (budget :data:`NO_SEARCH`: :func:`evaluate_greedy`) on the same levels."""
    jobs = {}
    for budget in budgets:
        for part in range(EVAL_PARTS):
            path = work / f"budget-{budget}-{count}-{part}.json"
            if budget == NO_SEARCH:
                jobs[budget, part] = (path, (evaluate_greedy, folder, cfg, source, count, part, partial_path(path)),
                                      {"budget": NO_SEARCH})
            else:
                search = dataclasses.replace(evaluation_search(cfg), budget=int(budget))
                jobs[budget, part] = boxoban_job(path, folder, cfg, source, count, part, search=search)
    return jobs


def budget_plays(jobs: dict, budget: int) -> list[dict]:
    """A budget's plays from its saved parts, in level order."""
    return sorted((r for part in range(EVAL_PARTS) for r in read_json(jobs[budget, part][0])["plays"]),
                  key=lambda r: r["level"])


def ms_per_action(plays: list[dict]) -> float:
    """Milliseconds of thinking per action taken, over all ``plays`` (a failed search's time counts)."""
    return 1000.0 * sum(p["seconds"] for p in plays) / max(1, sum(p["steps"] for p in plays))


__all__ = ["NO_SEARCH", "MAX_STEPS", "greedy_play", "evaluate_greedy", "budget_jobs", "budget_plays", "ms_per_action"]
