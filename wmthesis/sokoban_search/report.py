"""A trained search agent evaluated on many levels, resumable level by level: our generator's
unseen levels (:func:`evaluate_levels`) and Boxoban's files (:func:`evaluate_boxoban`), each
evaluation in :data:`EVAL_PARTS` parts that two processes share, each part saving its levels as
they end (:func:`~wmthesis.runs.partial_path`), and a play reused wherever another evaluation of
the same run searched as this one would (:func:`saved_plays`)."""
from __future__ import annotations

import json
import re
from pathlib import Path

from wmthesis.envs.boxoban import load_levels
from wmthesis.runs import partial_path, read_json, write_json
from wmthesis.sokoban_search.evaluation import agent_row, check_board_solutions, solve_boards
from wmthesis.sokoban_search.iteration import evaluation_search, load_run, policy_afterwards
from wmthesis.sokoban_search.search import Simulator


EVAL_PARTS = 2  # each evaluation in parts (every other level), so that two processes share them evenly

RECORDED_SEARCH = ("budget", "batch", "weights", "doubt", "replans", "prior_weight")  # what a play depends on, beyond the run

BOXOBAN_AGENTS = {"pixels": "agent, learned model (pixels)", "simulator": "agent, true simulator (pixels)"}

def search_agent(run, search, simulator: bool):
    """``run``'s agent searching as ``search`` says, with the true rules over its own inputs in
    place of its model if ``simulator`` (the reference that tells what is the model's fault)."""
    return run.agent(search, Simulator(run.inputs.type_codes())) if simulator else run.agent(search)

def evaluate_levels(folder: Path, cfg, variant: str, seeds, simulator: bool = False, partial: Path | None = None) -> dict:
    """The run in ``folder`` (with the true rules in place of its model if ``simulator``) on the
    levels: ``plays``, one record (seed, solved, actions, ...) per level. Each level is saved in
    ``partial`` as it ends, and a job cut off plays only the levels it had not (a level is played
    the same whenever it is played: the agent's random numbers come from its seed)."""
    search = evaluation_search(cfg)
    agent, record = search_agent(load_run(folder, cfg), search, simulator), search_record(search)
    done = {r["seed"]: r for r in saved_plays(partial, record)} if partial is not None else {}
    env = agent.env(variant)
    for seed in map(int, seeds):
        if seed not in done:
            done[seed] = agent.play(env, seed).record()
            if partial is not None:
                write_json(partial, {"plays": list(done.values()), "search": record}, indent=None)
    return {"plays": [done[int(seed)] for seed in seeds], "search": record}

def search_record(search) -> dict:
    """What a play depends on beyond the trained run: the search's settings, as JSON keeps them.
    A saved evaluation is reused only by an evaluation with the same record."""
    return json.loads(json.dumps({field: getattr(search, field) for field in RECORDED_SEARCH}))

def evaluation_record(cfg) -> dict:
    """The :func:`search_record` of ``cfg``'s search at evaluation (:func:`evaluation_search`)."""
    return search_record(evaluation_search(cfg))

def saved_plays(path: Path, record: dict) -> list[dict]:
    """The plays saved at ``path`` (``{"plays", "search"}``) that an evaluation searching as
    ``record`` says would play the same: all of them if it searched so (a level is played the same
    every time); if its search differed in the budget alone, each play that expanded fewer nodes
    than either budget (no search in it reached a budget, so each search ends as it did); else none."""
    saved = read_json(path) or {}
    search, plays = saved.get("search"), saved.get("plays", [])
    if search == record:
        return plays
    if search is None or {**search, "budget": None} != {**record, "budget": None}:
        return []
    return [play for play in plays if play["expanded"] < min(search["budget"], record["budget"])]

def generated_job(work: Path, name: str, agent: tuple, variant: str, seeds, part: int) -> tuple:
    """A :func:`run_jobs` job: agent ``name`` (``(folder, cfg, simulator)``) on part ``part``
    (every :data:`EVAL_PARTS`-th) of the levels ``seeds`` of our generator's ``variant``, with
    :func:`evaluate_levels`, saved level by level in its file's :func:`partial_path`."""
    folder, cfg, simulator = agent
    path = work / f"eval-{name}-{variant}-{len(seeds)}-{part}.json"
    return path, (evaluate_levels, folder, cfg, variant, seeds[part::EVAL_PARTS], simulator, partial_path(path)), \
        evaluation_record(cfg)

def boxoban_job(path: Path, folder: Path, cfg, source: str, count: int, part: int, simulator: bool = False,
                 search=None) -> tuple:
    """A :func:`run_jobs` job saving to ``path``: :func:`evaluate_boxoban` with these
    arguments, level by level in ``path``'s :func:`partial_path` file."""
    search = evaluation_search(cfg) if search is None else search
    return path, (evaluate_boxoban, folder, cfg, source, count, part, simulator, search, partial_path(path)), \
        search_record(search)

def evaluate_boxoban(folder: Path, cfg, source: str, count: int, part: int, simulator: bool = False,
                      search=None, partial: Path | None = None) -> dict:
    """The run in ``folder`` (trained with ``cfg``; with the true rules in place of its model if
    ``simulator``) on part ``part`` (every :data:`EVAL_PARTS`-th) of the first ``count`` levels of
    a Boxoban source, searching as ``search`` says (a config; ``cfg``'s :func:`evaluation_search`
    by default): ``plays``, one record (level, solved, actions, ...) per level, and the search's
    record. Each level is saved in ``partial`` as it ends, and a part cut off plays only the
    levels it had not."""
    levels = list(range(count))[part::EVAL_PARTS]
    boards = load_levels(source)
    run, search = load_run(folder, cfg), evaluation_search(cfg) if search is None else search
    record = search_record(search)
    if search.prior_weight > 0 and run.policy is None:  # a run trained without a prior: the one fitted after it
        run.policy = policy_afterwards(folder, run, cfg, progress=False)
    agent = search_agent(run, search, simulator)
    done = {}
    if partial is not None:  # what this part, or another evaluation of the same, has played as it would
        earlier = {**other_evaluations(partial, record), **{r["level"]: r for r in saved_plays(partial, record)}}
        done = {level: earlier[level] for level in levels if level in earlier}

    def keep(play: dict) -> None:
        done[play["level"]] = play
        if partial is not None:
            write_json(partial, {"plays": list(done.values()), "search": record}, indent=None)

    todo = [i for i in levels if i not in done]
    solve_boards(agent, [boards[i] for i in todo], progress=False, levels=todo, on_level=keep)
    return {"plays": [done[i] for i in levels], "search": record}

def other_evaluations(partial: Path, record: dict) -> dict:
    """The plays, by level, of the finished evaluations of the same run, source and part as the
    one keeping ``partial`` (``STEM-COUNT-PART.partial.json``), over any number of levels (level i
    of a source is the same level in each), that a search as ``record`` says would play the same
    (:func:`saved_plays`)."""
    match = re.fullmatch(r"(.+)-(\d+)-(\d+)\.partial\.json", partial.name)
    if match is None:
        return {}
    stem, part = match.group(1), match.group(3)
    found = {}
    for path in sorted(partial.parent.glob(f"{stem}-*-{part}.json")):
        if re.fullmatch(rf"{re.escape(stem)}-\d+-{part}\.json", path.name):
            found.update({r["level"]: r for r in saved_plays(path, record)})
    return found

def boxoban_reference(row, source: str, count: int) -> dict:
    """``row(boards)`` (random play, A*) on the first ``count`` levels of a Boxoban source."""
    return row(load_levels(source)[:count])

def level_plays(jobs: dict, *key) -> list[dict]:
    """The plays of an evaluation saved in :data:`EVAL_PARTS` parts (``jobs[(*key, part)]``), in level order."""
    return sorted((r for part in range(EVAL_PARTS) for r in read_json(jobs[(*key, part)][0])["plays"]),
                  key=lambda r: r["level"])

def boxoban_row(plays: list[dict], source: str, boards) -> dict:
    """An agent's row on the first levels of a Boxoban source: solve rate and costs, how many of
    its solutions an independent replay confirmed, and the levels it failed."""
    solved = [r for r in plays if r["solved"]]
    return {**agent_row(plays), "source": f"{source}, its first {len(plays)} levels",
            "replayed": int(sum(check_board_solutions(boards, solved))),
            "failed_levels": [r["level"] for r in plays if not r["solved"]]}

def merged_parts(parts: list[dict], seeds) -> dict:
    """An evaluation's parts together: the table row, the solutions, in the order of ``seeds``."""
    order = {s: i for i, s in enumerate(seeds)}
    plays = sorted((r for part in parts for r in part["plays"]), key=lambda r: order[r["seed"]])
    return {"row": agent_row(plays), "solutions": [r for r in plays if r["solved"]]}


__all__ = ["EVAL_PARTS", "RECORDED_SEARCH", "BOXOBAN_AGENTS", "search_agent", "evaluate_levels", "search_record",
           "evaluation_record", "saved_plays", "generated_job", "boxoban_job", "evaluate_boxoban", "other_evaluations",
           "boxoban_reference", "level_plays", "boxoban_row", "merged_parts"]
