"""DeepMind's Boxoban levels in the package: every vendored file, the sources that name them,
the held-out sets refused, and the environment playing them by the rules."""
import gzip

import numpy as np
import pytest

from wmthesis.envs import make_env
from wmthesis.envs.boxoban import SETS, boxoban_file, boxoban_levels, parse_source
from wmthesis.envs.levels import BOX, BOX_ON_TARGET, PLAYER, PLAYER_ON_TARGET, TARGET, board_to_text, read_levels
from wmthesis.envs.sokoban import solve
from wmthesis.sokoban_search.evaluation import check_board_solutions

# Level 0 of unfiltered/valid/000.txt, as DeepMind's file writes it.
UNFILTERED_VALID_0 = """##########
#####  ..#
##### $  #
####    .#
###  $   #
###     .#
#     ####
# $ $ @###
##       #
##########"""


def test_every_vendored_file_holds_1000_boxoban_levels():
    for name, files in SETS.items():
        boards = np.stack(boxoban_levels(f"boxoban-{name}"))
        assert boards.shape == (1000 * files, 10, 10), name
        count = lambda *codes: np.isin(boards, codes).sum(axis=(1, 2))  # noqa: E731
        assert np.all(count(BOX, BOX_ON_TARGET) == 4) and np.all(count(TARGET, BOX_ON_TARGET, PLAYER_ON_TARGET) == 4)
        assert np.all(count(PLAYER, PLAYER_ON_TARGET) == 1)
        assert len({b.tobytes() for b in boards}) > 0.99 * len(boards), name  # the files are not repeats


def test_a_source_names_a_set_and_its_files_in_one_order():
    assert parse_source("boxoban-medium-valid:005-009") == ("medium-valid", [5, 6, 7, 8, 9])
    assert parse_source("boxoban-unfiltered-train:3,0-1") == ("unfiltered-train", [3, 0, 1])
    assert parse_source("boxoban-unfiltered-valid") == ("unfiltered-valid", list(range(10)))
    first = boxoban_levels("boxoban-unfiltered-valid:000")
    assert board_to_text(first[0]) == UNFILTERED_VALID_0
    two = boxoban_levels("boxoban-unfiltered-valid:001,000")
    assert len(two) == 2000 and np.array_equal(two[1000], first[0]) and not np.array_equal(two[0], first[0])
    # any Boxoban file reads on its own, gzipped or not
    path = boxoban_file("unfiltered-valid", 0)
    assert np.array_equal(read_levels(path)[999], first[999])


@pytest.mark.parametrize("source, message", [
    ("boxoban-hard", "kept for an external check"),
    ("boxoban-unfiltered-test", "kept for an external check"),
    ("boxoban-unfiltered-valid:010", "holds files 000-009 here, not 010"),
    ("boxoban-medium-train:3-1", "is not a file number or a range"),
    ("boxoban-easy-valid", "unknown set 'easy-valid'"),
    ("boxoban", "expected boxoban-SET"),
])
def test_held_out_sets_and_bad_sources_are_refused(source, message):
    with pytest.raises(ValueError, match=message):
        boxoban_levels(source)


def test_the_environment_plays_boxoban_levels_by_the_rules(tmp_path):
    env = make_env("sokoban", levels="boxoban-unfiltered-valid:000", observation="grid")
    _, info = env.reset(seed=0, options={"level": 0})
    assert info["level"] == 0 and board_to_text(env.board) == UNFILTERED_VALID_0
    actions = solve(env.board)  # the A* reference, true rules
    assert actions is not None
    rewards = [env.step(a)[1] for a in actions]
    assert env.boxes_on_target() == 4 and rewards[-1] > 10 - 1e-6 and env._episode == "ended"
    # the referee that checks claimed solutions: the whole solution within the steps, nothing less
    board = env.levels[0]
    claims = [{"level": 0, "actions": actions}, {"level": 0, "actions": actions[:-1]}]
    assert check_board_solutions([board], claims) == [True, False]
    assert check_board_solutions([board], claims[:1], max_steps=len(actions) - 1) == [False]
    drawn = [env.reset(seed=7)[1]["level"] for _ in range(3)]
    assert drawn[0] == drawn[1] == drawn[2]  # the same seed, the same level
    assert len({env.reset()[1]["level"] for _ in range(20)}) > 10  # else drawn from the whole source
    with pytest.raises(ValueError, match="level 1000 is outside the level source"):
        env.reset(options={"level": 1000})
    for index in (1.5, "1", True):  # not silently another level
        with pytest.raises(TypeError, match="options\\['level'\\] is a level's index, an integer"):
            env.reset(options={"level": index})
    # a text file of one's own is a source too
    mine = tmp_path / "mine.txt.gz"
    with gzip.open(mine, "wt") as f:
        f.write("; 0\n#####\n#@$.#\n#####\n")
    small = make_env("sokoban-small", levels=str(mine))
    small.reset(seed=0)
    assert small.step(3)[2] and small.board.shape == (7, 7)
