"""Sokoban levels, procedurally generated (thesis 5.1.2).

Levels follow gym-sokoban's algorithm (M. Schrader, MIT, ``room_utils.py``):

1. room topology: a random walk of ``int(1.7 * (h + w))`` steps that changes direction with
   probability 0.35 and stamps one of gym-sokoban's five 3x3 floor masks at every step; the
   outer ring stays wall;
2. the player and ``num_boxes`` targets go on random floor cells;
3. reverse play from the solved state (every box on its target): the player moves and pulls
   boxes; the state that maximises ``box swaps x total box displacement`` is the level. A level
   whose best score is 0 (or whose room has too few floor cells) is generated again.

Each pull is a push played backwards, so every level is solvable by construction.

Fixed here, against gym-sokoban: all randomness comes from the generator that gymnasium's
``reset(seed=...)`` seeds (the same seed gives the same level in any process); a box swap counts
only when the pulled box differs from the previously pulled one (gym-sokoban counted every pull);
and the exhaustive depth-first reverse search (depth 300, a median 1.9 s per 10x10 level with 4
boxes) is replaced by a beam search over pulls with a fixed budget (tens of milliseconds; the
budget counts states, not seconds, so levels do not depend on the machine's speed).
"""
from __future__ import annotations

import time


import numpy as np

from wmthesis.envs.levels import BOX, BOX_ON_TARGET, PLAYER, PLAYER_ON_TARGET, TARGET, WALL


# Room topology (gym-sokoban): walk directions, direction change probability, floor masks
# whose centre sits on the walker.
WALK_DIRECTIONS = ((1, 0), (0, 1), (-1, 0), (0, -1))


P_CHANGE_DIRECTION = 0.35


FLOOR_MASKS = (((0, 0, 0), (1, 1, 1), (0, 0, 0)),   # horizontal bar
               ((0, 1, 0), (0, 1, 0), (0, 1, 0)),   # vertical bar
               ((0, 0, 0), (1, 1, 0), (0, 1, 0)),   # L (left, down)
               ((0, 0, 0), (1, 1, 0), (1, 1, 0)),   # 2x2 square
               ((0, 0, 0), (0, 1, 1), (0, 1, 0)))   # L (right, down)


# Reverse play budget: a beam of WIDTH states, DEPTH pulls deep (gym-sokoban searched
# exhaustively, 300 actions deep, up to 300,000 states).
REVERSE_WIDTH = 40


REVERSE_DEPTH = 80


MAX_TRIES = 1000


def generate_level(dim_room, num_boxes: int, rng: np.random.Generator,
                   width: int = REVERSE_WIDTH, depth: int = REVERSE_DEPTH):
    """A new solvable level drawn from `rng` alone.

    Returns (board, info): board, uint8 (h, w) codes; info, dict with score (box_swaps x
    displacement), box_swaps, displacement (sum over boxes of the Manhattan distance to its
    target), pulls, tries (rooms generated) and seconds.
    """
    start = time.perf_counter()
    for tries in range(1, MAX_TRIES + 1):
        room = room_topology(dim_room, rng)
        if np.count_nonzero(room) <= num_boxes + 1:  # gym-sokoban's "not enough free spots"
            continue
        player, targets = place_player_and_targets(room, num_boxes, rng)
        boxes, player, pulled, score = reverse_play(room, targets, player, rng, width, depth)
        if score > 0:
            break
    else:
        raise RuntimeError(f"no level with a positive score in {MAX_TRIES} rooms of {dim_room}")
    info = dict(score=score, box_swaps=count_box_swaps(pulled),
                displacement=box_displacement(boxes, targets), pulls=len(pulled), tries=tries,
                seconds=time.perf_counter() - start)
    return make_board(room, targets, boxes, player), info


def room_topology(dim_room, rng: np.random.Generator) -> np.ndarray:
    """Walls (0) and floor (1), uint8 (h, w), carved by gym-sokoban's random walk."""
    h, w = dim_room
    room = np.zeros((h, w), np.uint8)
    masks = np.array(FLOOR_MASKS, np.uint8)
    direction = WALK_DIRECTIONS[rng.integers(4)]
    r, c = int(rng.integers(1, h)), int(rng.integers(1, w))
    for _ in range(int(1.7 * (h + w))):
        if rng.random() < P_CHANGE_DIRECTION:
            direction = WALK_DIRECTIONS[rng.integers(4)]
        r = min(max(r + direction[0], 1), h - 2)
        c = min(max(c + direction[1], 1), w - 2)
        room[r - 1:r + 2, c - 1:c + 2] |= masks[rng.integers(len(masks))]
    room[[0, -1], :] = 0
    room[:, [0, -1]] = 0
    return room


def place_player_and_targets(room: np.ndarray, num_boxes: int, rng: np.random.Generator):
    """Distinct random floor cells: the player's (row, col) and a list of num_boxes targets."""
    cells = rng.choice(np.flatnonzero(room), size=num_boxes + 1, replace=False)
    rows, cols = np.unravel_index(cells, room.shape)
    cells = list(zip(rows.tolist(), cols.tolist()))
    return cells[0], cells[1:]


def reverse_play(room: np.ndarray, targets, player, rng: np.random.Generator,
                 width: int = REVERSE_WIDTH, depth: int = REVERSE_DEPTH):
    """Pull the boxes away from their targets by a beam search over reverse play.

    From the solved state (box k on targets[k], the player on `player`), each of `depth` rounds
    expands every state in the beam by all its pulls (the player walks to a cell it reaches next
    to a box and steps straight away from it, pulling the box one cell) and keeps the `width`
    children with the most box swaps x displacement, ties broken at random; a state (boxes,
    player's region) is expanded once. Returns (boxes, player, pulled, score) of the best state
    seen by ``level_score`` (no box on a target; the first found on ties): box k's (row, col),
    the player's, the ids of the boxes pulled on the way, and its score (empty and 0, with the
    solved state, when no state scores above 0).
    """
    h, w = room.shape
    free = (room.ravel() != WALL).tolist()
    steps = (-w, w, -1, 1)
    flat_targets = tuple(r * w + c for r, c in targets)
    distance = [[abs(i // w - t // w) + abs(i % w - t % w) for i in range(h * w)] for t in flat_targets]
    # a state: (boxes (cell of box k), player, box swaps, displacement, pulled as (k, earlier) links)
    beam = [(flat_targets, player[0] * w + player[1], 0, 0, None)]
    best, expanded, target_cells = beam[0], set(), set(flat_targets)
    for _ in range(depth):
        children = [child for state in beam for child in _pulls(free, steps, state, distance, expanded)]
        if not children:
            break
        for child in children:
            if child[2] * child[3] > best[2] * best[3] and not target_cells.intersection(child[0]):
                best = child
        noise = rng.random(len(children)).tolist()
        ranked = sorted(range(len(children)), key=lambda i: (-children[i][2] * children[i][3], noise[i]))
        beam = [children[i] for i in ranked[:width]]
    boxes, flat_player, swaps, displacement, links = best
    pulled = []
    while links is not None:
        k, links = links
        pulled.append(k)
    return [divmod(b, w) for b in boxes], divmod(flat_player, w), pulled[::-1], swaps * displacement


def _pulls(free, steps, state, distance, expanded):
    """The states one pull away from `state` (flat cells), unless its region was expanded before."""
    boxes, player, swaps, displacement, links = state
    occupied = set(boxes)
    reach = reachable(free, steps, occupied, player)
    key = (boxes, min(reach))
    if key in expanded:
        return []
    expanded.add(key)
    last = links[0] if links is not None else -1
    children = []
    for k, box in enumerate(boxes):
        for step in steps:
            stand, away = box + step, box + 2 * step  # player: from next to the box, one cell away
            if stand in reach and free[away] and away not in occupied:
                moved = boxes[:k] + (stand,) + boxes[k + 1:]
                children.append((moved, away, swaps + (k != last),
                                 displacement + distance[k][stand] - distance[k][box], (k, links)))
    return children


def reachable(free, steps, boxes, player) -> set:
    """Cells the player reaches without pushing."""
    seen, stack = {player}, [player]
    while stack:
        x = stack.pop()
        for step in steps:
            y = x + step
            if free[y] and y not in boxes and y not in seen:
                seen.add(y)
                stack.append(y)
    return seen


def count_box_swaps(pulled) -> int:
    """Pulls whose box differs from the previously pulled box; the first pull counts.

    ``[0, 0, 0] -> 1``, ``[0, 1, 0, 1] -> 4``. (gym-sokoban counted every pull as a swap.)
    """
    return sum(1 for i, k in enumerate(pulled) if i == 0 or k != pulled[i - 1])


def box_displacement(boxes, targets) -> int:
    """Sum over boxes of the Manhattan distance between box k's (row, col) and targets[k]."""
    return sum(abs(r - tr) + abs(c - tc) for (r, c), (tr, tc) in zip(boxes, targets))


def level_score(pulled, boxes, targets) -> int:
    """box swaps x total box displacement; 0 while any box is on a target.

    (gym-sokoban's rule; it also scored 0 while the player stood on a target, an accident of its
    encoding, dropped here.)
    """
    if set(map(tuple, boxes)) & set(map(tuple, targets)):
        return 0
    return count_box_swaps(pulled) * box_displacement(boxes, targets)


def make_board(room: np.ndarray, targets, boxes, player) -> np.ndarray:
    """Board codes, uint8 (h, w), from the room (0/1) and (row, col) cells."""
    board = room.astype(np.uint8)
    for cell in targets:
        board[cell] = TARGET
    for cell in boxes:
        board[cell] = BOX_ON_TARGET if board[cell] == TARGET else BOX
    board[player] = PLAYER_ON_TARGET if board[player] == TARGET else PLAYER
    return board


__all__ = ["generate_level", "room_topology", "place_player_and_targets", "reverse_play", "reachable", "count_box_swaps",
           "box_displacement", "level_score", "make_board"]
