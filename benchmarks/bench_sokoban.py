"""Sokoban level generation: time and difficulty per level, ours against gym-sokoban's search.

    python benchmarks/bench_sokoban.py [--levels 200] [--seed 0] [--reference 40] [--solve 50] [--out PATH]

Generates `--levels` levels per variant (10x10 with 4 boxes, 7x7 with 2) from one seed through
``SokobanEnv.reset``, then prints per variant: seconds per level (median, 95th percentile, max)
and difficulty (mean total box displacement, pulls and box swaps of the kept reverse-play state;
mean pushes of an optimal solution found by ``solve`` on the first `--solve` levels, with the
share solved within its node budget).

The ``same rooms`` rows compare, on `--reference` identical rooms (topology, targets, player),
our reverse play (``reverse_play``: seconds without the room drawing and retries) with a port of
gym-sokoban's exhaustive depth-first reverse search (``room_utils.depth_first_search``: depth
300, at most 300,000 states, every pull counted as a swap), for the difficulty each reaches. The
port's seconds are its own, not gym-sokoban's numpy original's (measured at a median 1.9 s, max
11 s per 10x10 level). Writes ``benchmarks/results/sokoban.json``.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[1])]  # _results, wmthesis

from wmthesis.envs.sokoban import SokobanEnv, solve  # noqa: E402
from wmthesis.envs.sokoban_generator import (box_displacement, count_box_swaps, make_board,  # noqa: E402
                                             place_player_and_targets, reverse_play, room_topology)
from _results import machine_meta, print_table, write_results  # noqa: E402

VARIANTS = {"sokoban": ((10, 10), 4), "sokoban-small": ((7, 7), 2)}
RESULTS = Path(__file__).resolve().parent / "results" / "sokoban.json"
SOLVER_NODES = 50_000


def ours(dim_room, num_boxes, levels, seed):
    """Generation info and board of `levels` successive levels of one env seeded once."""
    env = SokobanEnv(dim_room, num_boxes, observation="grid")
    env.reset(seed=seed)
    rows = [(dict(env.generation_info), env.board.copy())]
    for _ in range(levels - 1):
        env.reset()
        rows.append((dict(env.generation_info), env.board.copy()))
    return rows


def same_rooms(dim_room, num_boxes, rooms, seed):
    """Ours and the gym-sokoban search port on the same `rooms` (room, targets, player) draws.

    Rooms where either finds no state scoring above 0 are drawn again. Returns two lists of
    (generation info, board).
    """
    rng = np.random.default_rng(seed)
    ours_rows, gym_rows = [], []
    while len(ours_rows) < rooms:
        room = room_topology(dim_room, rng)
        if np.count_nonzero(room) <= num_boxes + 1:
            continue
        player, targets = place_player_and_targets(room, num_boxes, rng)
        start = time.perf_counter()
        boxes, ours_player, pulled, ours_score = reverse_play(room, targets, player, rng)
        ours_seconds = time.perf_counter() - start
        start = time.perf_counter()
        score, gym_boxes, gym_player, pulls = gym_sokoban_search(room, targets, player)
        gym_seconds = time.perf_counter() - start
        if ours_score > 0 and score > 0:
            swaps, displacement = count_box_swaps(pulled), box_displacement(boxes, targets)
            ours_rows.append((dict(box_swaps=swaps, displacement=displacement, pulls=len(pulled),
                                   seconds=ours_seconds), make_board(room, targets, boxes, ours_player)))
            gym_rows.append((dict(box_swaps=pulls, displacement=box_displacement(gym_boxes, targets),
                                  pulls=pulls, seconds=gym_seconds),
                             make_board(room, targets, gym_boxes, gym_player)))
    return ours_rows, gym_rows


def gym_sokoban_search(room, targets, player, ttl=300, max_states=300_000):
    """gym-sokoban's depth-first reverse search, ported to tuples; its quirks kept.

    Explores gym-sokoban's eight reverse actions in order to depth `ttl`, never revisiting a room
    state, until `max_states` states; keeps the state maximising pulls on the path x displacement,
    scored 0 unless every target is empty (no box, no player). Returns (score, boxes, player, pulls).
    """
    h, w = room.shape
    free = (room.ravel() != 0).tolist()
    goal = [r * w + c for r, c in targets]
    steps = (-w, w, -1, 1)
    seen, best = set(), [-1, None, None, 0]

    def displacement(boxes):
        return sum(abs(b // w - t // w) + abs(b % w - t % w) for b, t in zip(boxes, goal))

    def search(boxes, moved, player, pulls, ttl):
        ttl -= 1
        if ttl <= 0 or len(seen) >= max_states:
            return
        # gym-sokoban hashes the room, whose codes tell boxes pulled before from unmoved ones
        key = (player, frozenset(b for k, b in enumerate(boxes) if moved >> k & 1),
               frozenset(b for k, b in enumerate(boxes) if not moved >> k & 1))
        if key in seen:
            return
        seen.add(key)
        empty = sum(t not in boxes and t != player for t in goal)
        score = pulls * displacement(boxes) if empty == len(goal) else 0
        if score > best[0]:
            best[:] = score, boxes, player, pulls
        for action in range(8):
            step = steps[action % 4]
            nxt = player + step
            if not free[nxt] or nxt in boxes:
                continue  # blocked: gym-sokoban recurses into the same, already seen state
            behind = player - step
            if action < 4 and behind in boxes:
                k = boxes.index(behind)
                pulled = boxes[:k] + (player,) + boxes[k + 1:]
                search(pulled, moved | (1 << k), nxt, pulls + 1, ttl)
            else:
                search(boxes, moved, nxt, pulls, ttl)

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * ttl + 100))
    try:
        search(tuple(goal), 0, player[0] * w + player[1], 0, ttl)
    finally:
        sys.setrecursionlimit(limit)
    score, boxes, player, pulls = best
    return max(score, 0), [divmod(b, w) for b in boxes], divmod(player, w), pulls


def summarise(name, rows, solve_levels):
    """Timing and difficulty statistics of generated levels."""
    info = [r[0] for r in rows]
    seconds = np.array([i["seconds"] for i in info])
    solutions = [solve(board, SOLVER_NODES) for _, board in rows[:solve_levels]]
    pushes = [sum(a < 4 for a in s) for s in solutions if s is not None]
    return dict(variant=name, levels=len(rows), median_s=float(np.median(seconds)),
                p95_s=float(np.percentile(seconds, 95)), max_s=float(seconds.max()),
                mean_displacement=float(np.mean([i["displacement"] for i in info])),
                mean_pulls=float(np.mean([i["pulls"] for i in info])),
                mean_box_swaps=float(np.mean([i["box_swaps"] for i in info])),
                solved=f"{len(pushes)}/{len(solutions)}",
                mean_optimal_pushes=float(np.mean(pushes)) if pushes else float("nan"))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--levels", type=int, default=200, help="levels per variant (ours)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--reference", type=int, default=40,
                        help="rooms per variant for ours against the gym-sokoban search port (0: skip)")
    parser.add_argument("--solve", type=int, default=50, help="levels per generator solved by A*")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)

    results = []
    for variant, (dim_room, num_boxes) in VARIANTS.items():
        results.append(summarise(variant, ours(dim_room, num_boxes, args.levels, args.seed), args.solve))
    for variant, (dim_room, num_boxes) in VARIANTS.items():
        if args.reference > 0:
            ours_rows, gym_rows = same_rooms(dim_room, num_boxes, args.reference, args.seed)
            results.append(summarise(f"{variant}, same rooms: ours", ours_rows, args.solve))
            results.append(summarise(f"{variant}, same rooms: gym-sokoban search", gym_rows, args.solve))

    print_table(results)
    write_results(args.out, machine_meta(seed=args.seed, solver_nodes=SOLVER_NODES), results)


if __name__ == "__main__":
    main()
