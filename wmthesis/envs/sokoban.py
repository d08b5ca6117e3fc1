"""Sokoban, gymnasium-native and procedurally generated (thesis 5.1.2): a new level each reset.

Levels come from :mod:`wmthesis.envs.sokoban_generator` (gym-sokoban's algorithm, its faults fixed).

Board codes (``SokobanEnv.board``): 0 wall, 1 floor, 2 target, 3 box on target, 4 box,
5 player, 6 player on target. ``solve(board)`` finds a solution by A* over pushes.
"""
from __future__ import annotations

import functools
import heapq
from collections import deque

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from wmthesis.envs.actions import check_action, check_order, check_positive
from wmthesis.envs.boxoban import load_levels
from wmthesis.envs.levels import (BOX, BOX_ON_TARGET, CELL_NAMES, FLOOR, PLAYER, PLAYER_ON_TARGET, TARGET, WALL,
                                  check_board, fit_board, parse_level)
from wmthesis.envs.sokoban_generator import generate_level, reachable
from wmthesis.utils import check_choice

MAX_STEPS = 120  # an episode's steps before it is truncated
ACTIONS = ("push up", "push down", "push left", "push right",
           "move up", "move down", "move left", "move right")
MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1))  # up, down, left, right: action % 4

OBSERVATIONS = ("rgb", "grid")
RENDER_MODES = ("rgb_array", None)

STEP_PENALTY = -0.1
BOX_ON_TARGET_REWARD = 1.0
BOX_OFF_TARGET_PENALTY = -1.0
SOLVED_REWARD = 10.0


# Sprite colours (RGB), after gym-sokoban's tiles.
COLOURS = dict(floor=(24, 24, 24), brick=(165, 62, 38), mortar=(110, 104, 96),
               target=(254, 126, 125), box=(214, 160, 62), box_edge=(120, 80, 30),
               box_on_target=(254, 95, 56), box_on_target_edge=(150, 40, 20),
               player=(160, 212, 56), player_on_target=(219, 212, 56))


class SokobanEnv(gym.Env):
    """Procedurally generated Sokoban with gym-sokoban's rules; a new level every ``reset()``.

    Actions, ``Discrete(8)``: 0 push up, 1 push down, 2 push left, 3 push right, 4 move up,
    5 move down, 6 move left, 7 move right. A push moves the player, pushing the box in the way
    when the cell behind it is floor or target; a move only steps onto floor or target.

    Observations: ``rgb``: uint8 (h * tile_size, w * tile_size, 3) sprites, the same image as
    ``render()``; ``grid``: uint8 ((h - 2) * (w - 2),), the board codes of the inner cells
    (``board[1:-1, 1:-1].ravel()``). ``frame_size=S`` (``rgb`` only) makes World Models frames
    instead (thesis 4.2.4, :func:`world_models_frame`): the outer ring, always wall, cropped and
    the rest resized to uint8 (S, S, 3); for 10x10 and S = 64, 8x8 pixels a cell.

    Rewards: -0.1 a step, +1 when a box goes onto a target, -1 when one goes off, +10 when all
    boxes are on targets (terminated). Truncated after ``max_steps`` steps.

    State: ``board``, (h, w) integer codes (module docstring); it may be replaced between steps
    (wall-bordered, one player). ``generation_info``: score, box_swaps, displacement, pulls,
    tries and seconds of the latest generated level.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 8}

    def __init__(self, dim_room=(10, 10), num_boxes=4, max_steps=MAX_STEPS, observation="rgb",
                 render_mode="rgb_array", tile_size=16, frame_size=None, levels=None):
        check_choice("observation", observation, OBSERVATIONS)
        check_choice("render_mode", render_mode, RENDER_MODES)
        for name, value in (("dim_room's height", dim_room[0]), ("dim_room's width", dim_room[1]),
                            ("num_boxes", num_boxes), ("max_steps", max_steps), ("tile_size", tile_size)):
            check_positive(name, value)
        h, w = (int(n) for n in dim_room)
        if min(h, w) < 3 or num_boxes < 1 or max_steps < 1 or tile_size < 1:
            raise ValueError(f"need dim_room >= (3, 3), num_boxes >= 1, max_steps >= 1 and "
                             f"tile_size >= 1; got {dim_room}, {num_boxes}, {max_steps}, {tile_size}")
        if (h - 2) * (w - 2) < num_boxes + 2:  # generate_level needs more floor than boxes + player
            raise ValueError(f"{num_boxes} boxes cannot fit a {h}x{w} room: its {(h - 2) * (w - 2)} inner cells "
                             f"must hold the boxes, the player and at least one free cell ({num_boxes + 2})")
        self.dim_room, self.num_boxes, self.max_steps = (h, w), int(num_boxes), int(max_steps)
        self.observation, self.render_mode, self.tile_size = observation, render_mode, int(tile_size)
        if frame_size is not None and (observation != "rgb" or int(frame_size) < 1):
            raise ValueError(f"frame_size (World Models frames) needs rgb observations and a positive size; "
                             f"got {frame_size} with {observation!r} observations")
        self.frame_size = None if frame_size is None else int(frame_size)
        self.action_space = spaces.Discrete(len(ACTIONS))
        if self.frame_size is not None:
            self.observation_space = spaces.Box(0, 255, (self.frame_size, self.frame_size, 3), np.uint8)
        elif observation == "rgb":
            shape = (h * self.tile_size, w * self.tile_size, 3)
            self.observation_space = spaces.Box(0, 255, shape, np.uint8)
        else:
            self.observation_space = spaces.Box(0, len(CELL_NAMES) - 1, ((h - 2) * (w - 2),), np.uint8)
        self.levels = None if levels is None else [fit_board(b, (h, w), f"level {i}")
                                                   for i, b in enumerate(load_levels(levels))]
        self._tiles = make_tiles(self.tile_size)
        self.board = np.zeros((h, w), np.uint8)
        self.generation_info: dict = {}
        self.steps = 0
        self._episode = "new"  # new -> running -> ended (see wmthesis.envs.actions.check_order)

    def reset(self, *, seed=None, options=None):
        """A new level: generated from ``self.np_random``; or, with a level source (``levels``),
        level ``options["level"]`` of it, else one drawn from ``self.np_random`` (its index in
        ``info["level"]``); or ``options["board"]``: board codes (h, w) or a level as text
        (:mod:`wmthesis.envs.levels`), padded with wall up to ``dim_room``. An unplayable or
        larger board, or a level index outside the source, raises a ``ValueError`` naming why."""
        super().reset(seed=seed)
        options, info = options or {}, {}
        if options.get("board") is not None:
            board = options["board"]
            board = parse_level(board) if isinstance(board, str) else np.array(board, dtype=np.int64)
            check_board(board)
            self.board = fit_board(board.astype(np.uint8), self.dim_room)
        elif self.levels is not None:
            index = options.get("level")
            if index is not None and (isinstance(index, bool) or not isinstance(index, (int, np.integer))):
                raise TypeError(f"options['level'] is a level's index, an integer; got {index!r}")
            index = int(self.np_random.integers(len(self.levels))) if index is None else int(index)
            if not 0 <= index < len(self.levels):
                raise ValueError(f"level {index} is outside the level source (levels 0 to {len(self.levels) - 1})")
            self.board, info["level"] = self.levels[index].copy(), index
        else:
            self.board, self.generation_info = generate_level(self.dim_room, self.num_boxes, self.np_random)
        self.steps, self._episode = 0, "running"
        return self._observe(), {"boxes_on_target": self.boxes_on_target(), **info}

    def step(self, action):
        """Play ``action`` (an integer in ``[0, 8)``; anything else raises a ``ValueError``)."""
        check_order(self._episode)
        box_change = apply_action(self.board, check_action(action, self.action_space.n))
        self.steps += 1
        terminated = not np.any(self.board == BOX)
        reward = step_reward(box_change, terminated)
        truncated = not terminated and self.steps >= self.max_steps
        self._episode = "ended" if terminated or truncated else "running"
        info = {"boxes_on_target": self.boxes_on_target()}
        return self._observe(), float(reward), terminated, truncated, info

    def render(self):
        """The board as an RGB image, uint8 (h * tile_size, w * tile_size, 3); None without render mode."""
        return render_board(self.board, self._tiles) if self.render_mode == "rgb_array" else None

    def boxes_on_target(self) -> int:
        return int(np.count_nonzero(self.board == BOX_ON_TARGET))

    def _observe(self) -> np.ndarray:
        if self.frame_size is not None:
            return world_models_frame(self.board, self._tiles, self.frame_size)
        if self.observation == "rgb":
            return render_board(self.board, self._tiles)
        return self.board[1:-1, 1:-1].ravel().astype(np.uint8)


# ---------------------------------------------------------------------------- game rules

def step_reward(box_change: int, solved: bool) -> float:
    """The reward of a step: -0.1, +1 when a box went onto a target (``box_change`` > 0), -1
    when one went off (< 0), +10 when the level is solved."""
    reward = STEP_PENALTY
    if box_change > 0:
        reward += BOX_ON_TARGET_REWARD
    elif box_change < 0:
        reward += BOX_OFF_TARGET_PENALTY
    return reward + (SOLVED_REWARD if solved else 0.0)


def apply_action(board: np.ndarray, action: int) -> int:
    """Play `action` on `board` (h, w codes, in place). Returns +1 when a box went onto a target,
    -1 when one went off, else 0. A blocked action leaves the board as it was."""
    dr, dc = MOVES[action % 4]
    r, c = (int(x) for x in np.argwhere((board == PLAYER) | (board == PLAYER_ON_TARGET))[0])
    nr, nc = r + dr, c + dc
    box_change = 0
    if board[nr, nc] in (BOX, BOX_ON_TARGET):
        br, bc = nr + dr, nc + dc
        if action >= 4 or board[br, bc] not in (FLOOR, TARGET):
            return 0
        box_change = int(board[br, bc] == TARGET) - int(board[nr, nc] == BOX_ON_TARGET)
        board[br, bc] = BOX_ON_TARGET if board[br, bc] == TARGET else BOX
        board[nr, nc] = TARGET if board[nr, nc] == BOX_ON_TARGET else FLOOR
    if board[nr, nc] not in (FLOOR, TARGET):
        return 0
    board[r, c] = TARGET if board[r, c] == PLAYER_ON_TARGET else FLOOR
    board[nr, nc] = PLAYER_ON_TARGET if board[nr, nc] == TARGET else PLAYER
    return box_change



# ---------------------------------------------------------------------------- rendering

def make_tiles(tile_size: int) -> np.ndarray:
    """The seven cell sprites, uint8 (7, tile_size, tile_size, 3), indexed by board code.

    Below 4 pixels a sprite is its main colour.
    """
    if tile_size < 4:
        main = [COLOURS[name] for name in ("brick", "floor", "target", "box_on_target", "box",
                                           "player", "player_on_target")]
        return np.broadcast_to(np.array(main, np.uint8)[:, None, None], (7, tile_size, tile_size, 3)).copy()
    v, u = np.meshgrid((np.arange(tile_size) + 0.5) / tile_size,
                       (np.arange(tile_size) + 0.5) / tile_size, indexing="ij")  # row, column in (0, 1)
    square = np.maximum(abs(u - 0.5), abs(v - 0.5))  # 0 at the centre, 0.5 at the edge

    def paint(base, mask, colour):
        out = base.copy()
        out[mask] = colour
        return out

    floor = np.empty((tile_size, tile_size, 3), np.uint8)
    floor[:] = COLOURS["floor"]
    course = np.floor(v * 4)  # four brick courses, every other one shifted by half a brick
    mortar = (v * 4 % 1 < 0.2) | ((u * 2 + course % 2 / 2) % 1 < 0.1)
    wall = paint(paint(floor, square >= 0, COLOURS["brick"]), mortar, COLOURS["mortar"])
    target = paint(floor, ((square > 0.22) & (square < 0.38)) | (square < 0.13), COLOURS["target"])

    def box(base, fill, edge):
        cross = (abs(u - v) < 0.07) | (abs(u + v - 1) < 0.07)
        out = paint(base, square < 0.42, fill)
        return paint(out, (square < 0.42) & ((square > 0.32) | cross), edge)

    def player(base, colour):
        head = (u - 0.5) ** 2 + (v - 0.28) ** 2 < 0.16 ** 2
        body = (abs(u - 0.5) < 0.2) & (v > 0.42) & (v < 0.7)
        legs = (abs(abs(u - 0.5) - 0.11) < 0.06) & (v >= 0.7) & (v < 0.9)
        return paint(base, head | body | legs, colour)

    return np.stack([wall, floor, target,
                     box(target, COLOURS["box_on_target"], COLOURS["box_on_target_edge"]),
                     box(floor, COLOURS["box"], COLOURS["box_edge"]),
                     player(floor, COLOURS["player"]),
                     player(target, COLOURS["player_on_target"])])


def render_board(board: np.ndarray, tiles: np.ndarray) -> np.ndarray:
    """RGB image, uint8 (h * t, w * t, 3), of board (h, w) codes with tiles (7, t, t, 3)."""
    h, w = board.shape
    t = tiles.shape[1]
    return tiles[board].transpose(0, 2, 1, 3, 4).reshape(h * t, w * t, 3)


def world_models_frame(board: np.ndarray, tiles: np.ndarray, size: int = 64) -> np.ndarray:
    """The World Models frame of a wall-bordered ``board`` (h, w): its sprites without the outer
    ring (always wall: the border that informs nothing, thesis 4.2.4), resized to (size, size, 3)
    uint8 with :func:`~wmthesis.envs.preprocessing.crop_resize` (area interpolation)."""
    return inner_frame(board[1:-1, 1:-1], tiles, size)


def inner_frame(inner: np.ndarray, tiles: np.ndarray, size: int = 64) -> np.ndarray:
    """The World Models frame of the inner cells (h - 2, w - 2) of a board (any codes, so
    also a model's predicted grid): (size, size, 3) uint8."""
    from wmthesis.envs.preprocessing import crop_resize

    return crop_resize(render_board(np.asarray(inner), tiles), None, size)


def grid_frames(grids: np.ndarray, inner_shape=(8, 8), size: int = 64, tile_size: int = 16) -> np.ndarray:
    """Grid observations (N, h' * w') of codes (e.g. a model's predictions, clipped to the
    seven codes) -> their World Models frames (N, size, size, 3) uint8, exactly what
    ``SokobanEnv(frame_size=size, tile_size=tile_size)`` shows for those boards."""
    grids = np.clip(np.asarray(grids), 0, len(CELL_NAMES) - 1).astype(np.intp)
    tiles = make_tiles(tile_size)
    return np.stack([inner_frame(g.reshape(inner_shape), tiles, size) for g in grids]).reshape(
        *grids.shape[:-1], size, size, 3)


def read_grid(frames: np.ndarray, inner_shape=(8, 8), tile_size: int = 16) -> np.ndarray:
    """The inverse of :func:`grid_frames`: World Models frames (N, S, S, 3) -> the code of each
    inner cell (N, h' * w') uint8, the block type whose frame is nearest (squared error) on
    the pixels that fall in the cell. Exact on the env's frames; on a model's decoded
    predictions, it reads which block type each cell looks most like."""
    frames = np.asarray(frames)
    size = frames.shape[-2]
    weights, offsets = _grid_reader(tuple(inner_shape), int(size), int(tile_size))
    flat = frames.reshape(-1, size * size * 3).astype(np.float32)
    # Squared error of cell k against type c, less the frame's own energy (the same for every c):
    # sum over the cell's pixels of r_c^2 - 2 x . r_c.
    scores = offsets - 2 * (flat @ weights).reshape(len(flat), len(CELL_NAMES), -1)
    return scores.argmin(1).astype(np.uint8).reshape(*frames.shape[:-3], -1)


@functools.lru_cache(maxsize=4)
def _grid_reader(inner_shape: tuple, size: int, tile_size: int) -> tuple[np.ndarray, np.ndarray]:
    """For :func:`read_grid`: ``weights`` (S * S * 3, C * cells), the reference frame of type c
    (type c drawn in every cell) masked to cell k, and ``offsets`` (C, cells), its energy."""
    tiles = make_tiles(tile_size)
    cells = inner_shape[0] * inner_shape[1]
    references = np.stack([inner_frame(np.full(inner_shape, code), tiles, size)
                           for code in range(len(CELL_NAMES))]).astype(np.float32)  # (C, S, S, 3)
    rows = np.minimum(np.arange(size) * inner_shape[0] // size, inner_shape[0] - 1)
    cols = np.minimum(np.arange(size) * inner_shape[1] // size, inner_shape[1] - 1)
    cell_of_pixel = np.repeat((rows[:, None] * inner_shape[1] + cols[None, :]).ravel(), 3)  # (S * S * 3,)
    mask = np.zeros((size * size * 3, cells), np.float32)
    mask[np.arange(size * size * 3), cell_of_pixel] = 1
    flat = references.reshape(len(CELL_NAMES), -1)  # (C, S * S * 3)
    weights = (flat.T[:, :, None] * mask[:, None, :]).reshape(size * size * 3, -1)
    offsets = (flat ** 2) @ mask  # (C, cells)
    return weights, offsets


# ---------------------------------------------------------------------------- solver

def solve(board: np.ndarray, max_nodes: int = 100_000):
    """Actions that solve `board` (h, w codes, wall-bordered), or None.

    A* over pushes (optimal in pushes; the walks between pushes are shortest paths), with the
    sum of each box's push distance to its nearest target as heuristic and cells from which no
    target can be reached pruned. None when unsolvable or after expanding `max_nodes` states.
    """
    h, w = board.shape
    cells = np.asarray(board).ravel().tolist()
    free = [c != WALL for c in cells]
    steps = (-w, w, -1, 1)
    goal = frozenset(i for i, c in enumerate(cells) if c in (TARGET, BOX_ON_TARGET, PLAYER_ON_TARGET))
    boxes = frozenset(i for i, c in enumerate(cells) if c in (BOX, BOX_ON_TARGET))
    player = next(i for i, c in enumerate(cells) if c in (PLAYER, PLAYER_ON_TARGET))
    distance = _push_distances(free, steps, goal)
    if any(distance[b] < 0 for b in boxes):
        return None  # a box that no push brings to a target
    start = (boxes, player)
    parent, pushes_to = {start: None}, {start: 0}
    closed = set()
    frontier = [(sum(distance[b] for b in boxes), 0, 0, start)]
    while frontier:
        _, pushes, _, state = heapq.heappop(frontier)
        if pushes > pushes_to[state]:
            continue
        if state[0] == goal:
            return _actions(free, steps, parent, state, player)
        reach = reachable(free, steps, *state)
        key = (state[0], min(reach))
        if key in closed:
            continue
        closed.add(key)
        if len(closed) > max_nodes:
            return None
        for child, move in _pushes(free, steps, state[0], reach, distance):
            if pushes + 1 < pushes_to.get(child, float("inf")):
                parent[child], pushes_to[child] = (state, *move), pushes + 1
                cost = pushes + 1 + sum(distance[x] for x in child[0])
                heapq.heappush(frontier, (cost, pushes + 1, len(parent), child))
    return None


def _pushes(free, steps, boxes, reach, distance):
    """Pushes from a state: ((boxes after, player after), (box cell, direction)) pairs."""
    for b in boxes:
        for k, step in enumerate(steps):
            to = b + step
            if b - step in reach and free[to] and to not in boxes and distance[to] >= 0:
                yield (boxes - {b} | {to}, b), (b, k)


def _push_distances(free, steps, goal):
    """Per cell, the fewest pushes that bring a lone box there to a target (-1: never)."""
    distance = [-1] * len(free)
    queue = deque(goal)
    for t in goal:
        distance[t] = 0
    while queue:
        x = queue.popleft()
        for step in steps:  # a box pushed by `step` from x - step; the player stood at x - 2 step
            y = x - step
            if free[y] and free[y - step] and distance[y] < 0:
                distance[y] = distance[x] + 1
                queue.append(y)
    return distance


def _walk(free, steps, boxes, start, goal) -> list:
    """Move actions (4-7) along a shortest path from start to goal avoiding boxes."""
    came = {start: None}
    queue = deque([start])
    while goal not in came:
        x = queue.popleft()
        for k, step in enumerate(steps):
            y = x + step
            if free[y] and y not in boxes and y not in came:
                came[y] = (x, k)
                queue.append(y)
    path = []
    while came[goal] is not None:
        goal, k = came[goal]
        path.append(4 + k)
    return path[::-1]


def _actions(free, steps, parent, state, player) -> list:
    """Replay the pushes leading to `state` as walks and pushes from the real start `player`."""
    pushes = []
    while parent[state] is not None:
        state, b, k = parent[state]
        pushes.append((b, k))
    boxes, actions = set(state[0]), []
    for b, k in reversed(pushes):
        actions += _walk(free, steps, boxes, player, b - steps[k]) + [k]
        boxes.remove(b)
        boxes.add(b + steps[k])
        player = b
    return actions
