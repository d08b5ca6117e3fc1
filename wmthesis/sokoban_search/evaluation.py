"""The table of the Sokoban search's targets: solve rates on unseen levels within the environment's 120 steps.

Rows: random play; the thesis (0 levels, 5.3 and 5.5, on the levels it played: a generator's 10x10
rooms with 4 boxes, 5.1.2; none on levels it never played); the search agent in its learned model;
the same agent, same budget, with the true rules in place of the model (the upper bound: the gap
to it is the model's fault); A* over pushes (``envs.sokoban.solve``, a reference with the rules
and a heuristic written in, not an agent).
"""
from __future__ import annotations

import time

import numpy as np
from tqdm import tqdm

from wmthesis.envs.sokoban import BOX, BOX_ON_TARGET, SokobanEnv, solve
from wmthesis.sokoban_search.agent import Play, grid_env, grid_state, random_play
from wmthesis.utils import derive_seeds

THESIS_SOLVED = 0.0  # 5.3 and 5.5: no level solved
# The levels the thesis played (5.1.2: a generator's 10x10 rooms with 4 boxes): our generator's ``sokoban``.
# It never played our 7x7 ``sokoban-small`` nor Boxoban's files, so it has no figure there.
THESIS_LEVELS = ("sokoban",)
NOT_PLAYED = "not played by the thesis"
THESIS_ROW = "thesis"  # the thesis's row's name in a table of levels solved


def thesis_row(levels: str) -> dict:
    """The thesis's row in a table of ``levels`` (a variant of our generator, or a Boxoban kind):
    no level solved where it played such levels, else no figure (``solve_rate`` None) and a ``note``
    saying so."""
    return {"solve_rate": THESIS_SOLVED} if levels in THESIS_LEVELS else {"solve_rate": None, "note": NOT_PLAYED}


def play_levels(agent, variant: str, seeds, desc: str = "levels", progress: bool = True) -> list[Play]:
    """The agent on the levels ``seeds`` generate, in the real environment."""
    env = agent.env(variant)
    return [agent.play(env, int(s)) for s in tqdm(seeds, desc=desc, disable=not progress)]


def agent_row(plays: list[dict]) -> dict:
    """Solve rate and costs of plays, recorded as :meth:`Play.record` records them."""
    solved = [p for p in plays if p["solved"]]
    moves = sum(p["steps"] for p in plays)
    return {"levels": len(plays), "solved": len(solved), "solve_rate": len(solved) / len(plays),
            "steps_when_solved": float(np.mean([p["steps"] for p in solved])) if solved else None,
            "nodes_per_move": sum(p["expanded"] for p in plays) / max(moves, 1),
            "nodes_per_level": float(np.mean([p["expanded"] for p in plays])),
            "seconds_per_level": float(np.mean([p["seconds"] for p in plays]))}


def random_row(variant: str, seeds) -> dict:
    """Uniformly random play, one episode per level (seeded from the level seed)."""
    start, solved = time.perf_counter(), 0
    env = grid_env(variant)
    for s in seeds:
        rng = np.random.default_rng(derive_seeds(int(s), 1)[0])
        env.reset(seed=int(s))
        done = terminated = False
        while not done:
            _, _, terminated, truncated, _ = env.step(int(rng.integers(8)))
            done = terminated or truncated
        solved += bool(terminated)
    return {"levels": len(seeds), "solved": solved, "solve_rate": solved / len(seeds),
            "seconds_per_level": (time.perf_counter() - start) / len(seeds)}


def astar_row(variant: str, seeds, max_nodes: int = 100_000) -> dict:
    """A* over pushes on each level; solved when its solution fits the 120 steps."""
    env = grid_env(variant)
    start, solved, lengths = time.perf_counter(), 0, []
    for s in seeds:
        env.reset(seed=int(s))
        actions = solve(env.board, max_nodes=max_nodes)
        if actions is not None and len(actions) <= env.max_steps:
            solved += 1
            lengths.append(len(actions))
    return {"levels": len(seeds), "solved": solved, "solve_rate": solved / len(seeds),
            "steps_when_solved": float(np.mean(lengths)) if lengths else None,
            "seconds_per_level": (time.perf_counter() - start) / len(seeds)}


def random_board_row(boards, seed: int = 0, max_steps: int = 120) -> dict:
    """Uniformly random play, one episode of ``max_steps`` on each of ``boards`` (level i's
    actions seeded from ``(seed, i)``)."""
    start, solved = time.perf_counter(), 0
    for i, board in enumerate(boards):
        env = board_env(board, max_steps, observation="grid")
        env.reset(options={"board": board})
        rng = np.random.default_rng(derive_seeds(seed, i)[0])
        solved += _solves(env, rng.integers(8, size=max_steps))
    return {"levels": len(boards), "solved": solved, "solve_rate": solved / len(boards),
            "seconds_per_level": (time.perf_counter() - start) / len(boards)}


def astar_board_row(boards, max_nodes: int = 100_000, max_steps: int = 120) -> dict:
    """A* over pushes on each of ``boards``; solved when its solution fits ``max_steps``."""
    start, lengths = time.perf_counter(), []
    for board in boards:
        actions = solve(board, max_nodes=max_nodes)
        if actions is not None and len(actions) <= max_steps:
            lengths.append(len(actions))
    return {"levels": len(boards), "solved": len(lengths), "solve_rate": len(lengths) / len(boards),
            "steps_when_solved": float(np.mean(lengths)) if lengths else None,
            "seconds_per_level": (time.perf_counter() - start) / len(boards)}


def replay_states(variant: str, records: list[dict]) -> list[tuple[np.ndarray, np.ndarray]]:
    """The real grid states (T + 1, h', w') and actions (T,) of saved plays (``seed``,
    ``actions``), replayed in the environment."""
    env, out = grid_env(variant), []
    for record in records:
        states = [grid_state(env, env.reset(seed=int(record["seed"]))[0])]
        for action in record["actions"]:
            states.append(grid_state(env, env.step(int(action))[0]))
        out.append((np.stack(states), np.asarray(record["actions"], np.int64)))
    return out


def solve_boards(agent, boards, max_steps: int = 120, progress: bool = True, levels=None, on_level=None) -> list[dict]:
    """The agent on given boards (codes (h, w), any size the model runs on), each in a real
    environment of the board's size that ends the episode after ``max_steps`` steps, every
    replan counted: one ``{"level", "solved", "steps", "actions", "expanded", "seconds", ...}``
    per board (:meth:`Play.record`), ``level`` its index in ``levels`` (default 0, 1, ...);
    ``on_level(record)`` is called as each ends (to save it at once)."""
    results = []
    levels = range(len(boards)) if levels is None else levels
    for index, board in zip(levels, tqdm(boards, desc="levels", disable=not progress)):
        play = agent.play(board_env(board, max_steps, **agent.inputs.env_options), board=board)
        record = play.record()
        del record["seed"]
        results.append({"level": int(index), **record})
        if on_level is not None:
            on_level(results[-1])
    return results


def check_board_solutions(boards, records: list[dict], max_steps: int = 120) -> list[bool]:
    """An independent referee: each record's ``actions`` replayed on its board (``boards[level]``)
    in a fresh environment; whether it ends with every box on a target within ``max_steps``."""
    verdicts = []
    for record in records:
        env = board_env(boards[record["level"]], max_steps, observation="grid")
        env.reset(options={"board": boards[record["level"]]})
        verdicts.append(_solves(env, record["actions"]))
    return verdicts


def _solves(env, actions) -> bool:
    """Whether ``actions`` played from the env's current start end the episode solved."""
    terminated = truncated = False
    for action in actions:
        _, _, terminated, truncated, _ = env.step(int(action))
        if terminated or truncated:
            break
    return bool(terminated)


def board_env(board: np.ndarray, max_steps: int, **options):
    """A real environment for ``board`` (codes (h, w)): its size and box count, ending after ``max_steps``."""
    boxes = int(np.isin(board, (BOX, BOX_ON_TARGET)).sum())
    return SokobanEnv(board.shape, max(boxes, 1), max_steps=max_steps, **options)


def check_solutions(variant: str, records: list[dict]) -> list[bool]:
    """Replay saved solutions (``seed``, ``actions``) in a fresh environment: whether each
    really solves its level."""
    env = grid_env(variant)
    verdicts = []
    for record in records:
        env.reset(seed=int(record["seed"]))
        verdicts.append(_solves(env, record["actions"]))
    return verdicts


__all__ = ["play_levels", "solve_boards", "check_board_solutions", "agent_row", "random_row", "astar_row",
           "random_board_row", "astar_board_row", "replay_states", "check_solutions",
           "THESIS_SOLVED", "THESIS_LEVELS", "NOT_PLAYED", "THESIS_ROW", "thesis_row", "random_play", "board_env"]
