"""Sokoban's notation: the board codes, and levels as text in the common notation (the XSB
format the public Boxoban set uses).

``#`` wall, `` `` (space, also ``-`` or ``_``) floor, ``.`` target, ``$`` box, ``*`` box on
target, ``@`` player, ``+`` player on target. A file holds one level, or several, each after a
``; N`` line (Boxoban) or separated by blank lines; other ``;`` lines are comments.

Floor outside the outer walls (classic levels indent their rows with spaces) becomes wall, rows
are padded with wall to a rectangle, and :func:`fit_board` pads a level with wall up to a room
size (``SokobanEnv.reset(options={"board": ...})`` needs the env's ``dim_room``)::

    >>> board = parse_level('''
    ... #####
    ... #@$.#
    ... #####''')
    >>> board.tolist()
    [[0, 0, 0, 0, 0], [0, 5, 4, 2, 0], [0, 0, 0, 0, 0]]
    >>> print(board_to_text(board))
    #####
    #@$.#
    #####
"""
from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
from scipy import ndimage

# Board codes (``SokobanEnv.board``), the one place they are defined.
WALL, FLOOR, TARGET, BOX_ON_TARGET, BOX, PLAYER, PLAYER_ON_TARGET = range(7)
CELL_NAMES = ("wall", "floor", "target", "box on target", "box", "player", "player on target")

SYMBOLS = {"#": WALL, " ": FLOOR, "-": FLOOR, "_": FLOOR, ".": TARGET, "*": BOX_ON_TARGET,
           "$": BOX, "@": PLAYER, "+": PLAYER_ON_TARGET}
TEXT = {WALL: "#", FLOOR: " ", TARGET: ".", BOX_ON_TARGET: "*", BOX: "$", PLAYER: "@",
        PLAYER_ON_TARGET: "+"}


class LevelError(ValueError):
    """A level that is not a playable Sokoban board; the message names the level and why."""


_CODES = np.zeros(128, np.uint8)  # an ASCII symbol -> its cell code
_CODES[[ord(char) for char in SYMBOLS]] = list(SYMBOLS.values())


def parse_level(text: str, name: str = "level") -> np.ndarray:
    """One level's text -> its board, uint8 (h, w) codes, wall-bordered (:func:`check_board`)."""
    rows = [line.rstrip("\n\r") for line in text.splitlines()]
    rows = [row for row in rows if row.strip() and not row.lstrip().startswith(";")]
    if not rows:
        raise LevelError(f"{name}: no rows")
    width = max(len(row) for row in rows)
    if not set("".join(rows)) <= SYMBOLS.keys():
        r, c, char = next((r, c, char) for r, row in enumerate(rows) for c, char in enumerate(row) if char not in SYMBOLS)
        raise LevelError(f"{name}: row {r + 1} column {c + 1} holds {char!r}; valid: "
                         + " ".join(repr(s) for s in SYMBOLS))
    board = np.full((len(rows) + 2, width + 2), FLOOR, np.uint8)  # a ring of outside floor
    text = "".join(row.ljust(width) for row in rows).encode("ascii")  # short rows: floor (' ') after them
    board[1:-1, 1:-1] = _CODES[np.frombuffer(text, np.uint8)].reshape(len(rows), width)
    board = _wall_outside(board, name)
    check_board(board, name)
    return board


def parse_levels(text: str, name: str = "levels") -> list[np.ndarray]:
    """Every level in ``text``: blocks after ``; N`` lines, or separated by blank lines."""
    blocks, current = [], []
    for line in text.splitlines():
        if line.lstrip().startswith(";") or not line.strip():
            if current:
                blocks.append(current)
            current = []
        else:
            current.append(line)
    if current:
        blocks.append(current)
    if not blocks:
        raise LevelError(f"{name}: no levels")
    return [parse_level("\n".join(block), f"{name}, level {i}") for i, block in enumerate(blocks)]


def read_levels(path) -> list[np.ndarray]:
    """The levels of a text file (:func:`parse_levels`), gzipped when its name ends in ``.gz``."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{path} is a folder, not a levels file: name a text file of levels in it")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such levels file")
    try:
        if path.suffix == ".gz":
            with gzip.open(path, "rt") as f:
                return parse_levels(f.read(), str(path))
        return parse_levels(path.read_text(), str(path))
    except (UnicodeDecodeError, gzip.BadGzipFile, EOFError) as error:
        raise LevelError(f"{path} is not a text file of levels (# wall, . target, $ box, @ player; "
                         f"'; N' lines between levels): {error}") from None


def board_to_text(board: np.ndarray) -> str:
    """A board (h, w) codes -> its text, one line per row."""
    return "\n".join("".join(TEXT[int(code)] for code in row) for row in np.asarray(board))


def fit_board(board: np.ndarray, dim_room, name: str = "level") -> np.ndarray:
    """``board`` padded with wall (below and to the right) to ``dim_room`` (h, w); a larger
    board is refused with both sizes named."""
    h, w = (int(n) for n in dim_room)
    bh, bw = board.shape
    if bh > h or bw > w:
        raise LevelError(f"{name} is {bh}x{bw}, larger than the {h}x{w} room this agent plays")
    out = np.full((h, w), WALL, np.uint8)
    out[:bh, :bw] = board
    return out


def check_board(board: np.ndarray, name: str = "level") -> None:
    """Refuse a board that cannot be played: codes outside 0..6, an outer ring that is not
    wall, not exactly one player, no box, or not one target per box (the game is solved when every
    target holds a box, so a spare target could never be filled)."""
    board = np.asarray(board)
    if board.ndim != 2 or min(board.shape) < 3:
        raise LevelError(f"{name}: a board is 2-D, at least 3x3; got shape {board.shape}")
    if board.min() < WALL or board.max() > PLAYER_ON_TARGET:
        raise LevelError(f"{name}: board codes are 0..6, got {int(board.min())}..{int(board.max())}")
    ring = np.concatenate([board[0], board[-1], board[:, 0], board[:, -1]])
    if np.any(ring != WALL):
        raise LevelError(f"{name}: the outer ring must be wall (the level is not enclosed)")
    count = np.bincount(board.ravel(), minlength=PLAYER_ON_TARGET + 1)  # cells of each code
    players = int(count[PLAYER] + count[PLAYER_ON_TARGET])
    boxes = int(count[BOX] + count[BOX_ON_TARGET])
    targets = int(count[TARGET] + count[BOX_ON_TARGET] + count[PLAYER_ON_TARGET])
    if players != 1:
        raise LevelError(f"{name}: needs exactly one player ('@' or '+'), found {players}")
    if boxes == 0 or targets != boxes:
        raise LevelError(f"{name}: needs at least one box and exactly one target per box; "
                         f"found {boxes} boxes and {targets} targets")


def _wall_outside(board: np.ndarray, name: str) -> np.ndarray:
    """Floor connected to the outside ring becomes wall; then drop the added ring (the level keeps
    its own size, wall rows included: a Boxoban level stays 10x10). Anything
    else (a box, target or player) reachable from outside means the level is not enclosed.
    ``board`` (h, w) carries the added ring of floor, so the outside is the region of non-wall
    cells (4-connected) that holds its corner."""
    regions, _ = ndimage.label(board != WALL)
    outside = regions == regions[0, 0]
    inside_things = np.argwhere(outside & (board != FLOOR))
    if len(inside_things):
        nr, nc = inside_things[0]
        raise LevelError(f"{name}: row {nr} column {nc} is reachable from outside the walls "
                         "(the level is not enclosed)")
    board = np.where(outside, WALL, board).astype(np.uint8)
    if not np.any(board != WALL):
        raise LevelError(f"{name}: no floor inside the walls")
    return board[1:-1, 1:-1].copy()


__all__ = ["WALL", "FLOOR", "TARGET", "BOX_ON_TARGET", "BOX", "PLAYER", "PLAYER_ON_TARGET", "CELL_NAMES", "parse_level", "parse_levels", "read_levels", "board_to_text", "fit_board", "check_board",
           "LevelError", "SYMBOLS"]
