"""The rules of a Sokoban step, as invariants on random boards (hypothesis): a move never
pushes, a push moves exactly the one box in front of the player one cell on, in every direction,
and nothing else on the board changes. A rule off by one (a move that pushes, a push of two boxes,
a push through a wall) fails here. Every rule also runs on boards written by hand (``@example``),
whatever boards the draw brings: each action with a box ahead, a push into a wall and into a box,
a push onto a target and off one."""
import numpy as np
from hypothesis import example, given, settings, strategies as st

from wmthesis.envs.levels import BOX, BOX_ON_TARGET, FLOOR, PLAYER, PLAYER_ON_TARGET, TARGET, WALL
from wmthesis.envs.sokoban import ACTIONS, MOVES, apply_action

INNER = (FLOOR, FLOOR, FLOOR, WALL, TARGET, BOX, BOX_ON_TARGET)  # floor drawn more often


@st.composite
def boards(draw):
    """A board of 3-6 x 3-6 inner cells inside a wall, one player somewhere inside."""
    h, w = draw(st.integers(3, 6)), draw(st.integers(3, 6))
    cells = draw(st.lists(st.sampled_from(INNER), min_size=h * w, max_size=h * w))
    board = np.full((h + 2, w + 2), WALL, np.uint8)
    board[1:-1, 1:-1] = np.array(cells, np.uint8).reshape(h, w)
    r, c = draw(st.integers(1, h)), draw(st.integers(1, w))
    board[r, c] = PLAYER_ON_TARGET if board[r, c] in (TARGET, BOX_ON_TARGET) else PLAYER
    return board


def written(text: str) -> np.ndarray:
    """A board from its lines (# wall, space floor, . target, $ box, * box on target, @ player)."""
    code = {"#": WALL, " ": FLOOR, ".": TARGET, "$": BOX, "*": BOX_ON_TARGET, "@": PLAYER, "+": PLAYER_ON_TARGET}
    rows = text.strip("\n").split("\n")
    return np.array([[code[ch] for ch in row.ljust(max(map(len, rows)), "#")] for row in rows], np.uint8)


BOXED_IN = written("#######\n#  .  #\n#  $  #\n# $@$ #\n#  $  #\n#     #\n#######")  # a box ahead every way
INTO_WALL, INTO_BOX = written("#####\n#$@ #\n#####"), written("######\n#$$@ #\n######")
ONTO_TARGET, OFF_TARGET = written("######\n#.$@ #\n######"), written("######\n# *@ #\n######")
LEFT = ACTIONS.index("push left")


def player(board):
    return tuple(int(x) for x in np.argwhere((board == PLAYER) | (board == PLAYER_ON_TARGET))[0])


def boxes(board):
    return {tuple(int(x) for x in p) for p in np.argwhere((board == BOX) | (board == BOX_ON_TARGET))}


def targets(board):
    return {tuple(int(x) for x in p) for p in np.argwhere(np.isin(board, (TARGET, BOX_ON_TARGET, PLAYER_ON_TARGET)))}


@settings(max_examples=300, deadline=None)
@given(boards(), st.integers(0, len(ACTIONS) - 1))
@example(INTO_WALL, LEFT)
@example(INTO_BOX, LEFT)
@example(ONTO_TARGET, LEFT)
@example(OFF_TARGET, LEFT)
@example(BOXED_IN, 0)
@example(BOXED_IN, 1)
@example(BOXED_IN, 2)
@example(BOXED_IN, 3)
@example(BOXED_IN, 4)
@example(BOXED_IN, 5)
@example(BOXED_IN, 6)
@example(BOXED_IN, 7)
def test_a_step_moves_the_player_one_cell_and_pushes_only_what_it_may(board, action):
    before, after = board.copy(), board.copy()
    change = apply_action(after, action)
    (r, c), (dr, dc) = player(before), MOVES[action % 4]
    ahead, beyond = (r + dr, c + dc), (r + 2 * dr, c + 2 * dc)
    assert targets(after) == targets(before) and (after == WALL).sum() == (before == WALL).sum()
    assert len(boxes(after)) == len(boxes(before))
    free = lambda cell: before[cell] in (FLOOR, TARGET)  # noqa: E731
    pushing = ahead in boxes(before)
    if action >= 4:  # a move never pushes: blocked by a box as by a wall
        moves = free(ahead)
        assert boxes(after) == boxes(before)
    else:  # a push moves the one box ahead one cell on, where the cell beyond is free
        moves = free(ahead) or (pushing and beyond[0] in range(len(before)) and free(beyond))
        expected = boxes(before) - {ahead} | {beyond} if pushing and moves else boxes(before)
        assert boxes(after) == expected
    assert player(after) == (ahead if moves else (r, c))
    if not moves:
        assert (after == before).all() and change == 0
    on_targets = lambda b: len(boxes(b) & targets(b))  # noqa: E731
    assert change == on_targets(after) - on_targets(before)
