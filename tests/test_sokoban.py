"""Sokoban: gymnasium API, seeded generation, level invariants, solvability, rules, rendering."""
import hashlib
import os
import random
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from wmthesis.envs import make_env
from wmthesis.envs.sokoban import (BOX, BOX_ON_TARGET, FLOOR, PLAYER, PLAYER_ON_TARGET, SokobanEnv, TARGET, WALL,
                                   make_tiles, solve)
from wmthesis.envs.sokoban_generator import (box_displacement, count_box_swaps, level_score, place_player_and_targets,
                                             reverse_play, room_topology)

REPO = Path(__file__).resolve().parents[1]
VARIANTS = {"sokoban": ((10, 10), 4), "sokoban-small": ((7, 7), 2)}
IDS = {"sokoban": "wmthesis/Sokoban-v0", "sokoban-small": "wmthesis/SokobanSmall-v0"}


def levels(name, n, seed):
    """Boards and generation infos of `n` successive levels of one env seeded once."""
    env = make_env(name, observation="grid")
    boards, infos = [], []
    for i in range(n):
        env.reset(seed=seed if i == 0 else None)
        boards.append(env.unwrapped.board.copy())
        infos.append(dict(env.unwrapped.generation_info))
    return boards, infos


def board_hash(board):
    return hashlib.sha256(np.ascontiguousarray(board, dtype=np.uint8).tobytes()).hexdigest()


# ---------------------------------------------------------------------------- gymnasium API

@pytest.mark.parametrize("name", VARIANTS)
@pytest.mark.parametrize("observation", ["rgb", "grid"])
def test_check_env_passes_without_warnings(name, observation):
    env = gym.make(IDS[name], observation=observation)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=False)
    assert [str(w.message) for w in caught] == []
    h, w = VARIANTS[name][0]
    expected = (h * 16, w * 16, 3) if observation == "rgb" else ((h - 2) * (w - 2),)
    assert env.observation_space.shape == expected
    assert env.observation_space.dtype == np.uint8
    assert env.action_space.n == 8


def test_unknown_choices_fail_listing_the_valid_ones():
    with pytest.raises(ValueError, match="valid: rgb, grid"):
        SokobanEnv(observation="pixels")
    with pytest.raises(ValueError, match="valid: rgb_array, None"):
        SokobanEnv(render_mode="human")


# ---------------------------------------------------------------------------- seeding

def test_same_seed_same_level_in_two_envs_and_another_process():
    a, _ = levels("sokoban", 3, seed=1234)
    b, _ = levels("sokoban", 3, seed=1234)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    code = ("import hashlib, numpy as np; from wmthesis.envs import make_env; "
            "env = make_env('sokoban'); env.reset(seed=1234); env.reset(); env.reset(); "
            "board = np.ascontiguousarray(env.unwrapped.board, dtype=np.uint8); "
            "print(hashlib.sha256(board.tobytes()).hexdigest())")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, check=True,
                         env={**os.environ, "PYTHONHASHSEED": "987", "PYTHONPATH": str(REPO)})
    assert run.stdout.strip() == board_hash(a[2])


def test_generation_ignores_and_keeps_global_random_state():
    env = SokobanEnv((7, 7), 2)
    random.seed(1)
    np.random.seed(1)
    before = random.getstate(), np.random.get_state()[1].copy()
    env.reset(seed=5)
    first = env.board.copy()
    assert random.getstate() == before[0] and np.array_equal(np.random.get_state()[1], before[1])
    random.seed(2)
    np.random.seed(2)
    env.reset(seed=5)
    assert np.array_equal(env.board, first)


def test_different_seeds_and_successive_resets_give_different_levels():
    by_seed = {board_hash(levels("sokoban", 1, seed=s)[0][0]) for s in range(10)}
    assert len(by_seed) == 10
    successive, _ = levels("sokoban", 10, seed=0)
    assert len({board_hash(b) for b in successive}) == 10
    small, _ = levels("sokoban-small", 30, seed=0)
    assert len({board_hash(b) for b in small}) >= 28


# ---------------------------------------------------------------------------- level invariants

@pytest.mark.parametrize("name,n", [("sokoban", 30), ("sokoban-small", 60)])
def test_levels_have_wall_border_one_player_and_num_boxes_boxes_and_targets(name, n):
    (h, w), num_boxes = VARIANTS[name]
    boards, infos = levels(name, n, seed=3)
    for board, info in zip(boards, infos):
        assert board.shape == (h, w)
        border = np.concatenate([board[0], board[-1], board[:, 0], board[:, -1]])
        assert np.all(border == WALL)
        assert np.count_nonzero(np.isin(board, [BOX, BOX_ON_TARGET])) == num_boxes
        assert np.count_nonzero(np.isin(board, [TARGET, BOX_ON_TARGET, PLAYER_ON_TARGET])) == num_boxes
        assert np.count_nonzero(np.isin(board, [PLAYER, PLAYER_ON_TARGET])) == 1
        assert np.count_nonzero(board == BOX_ON_TARGET) == 0  # gym-sokoban's rule: all boxes off
        assert set(info) >= {"score", "box_swaps", "displacement", "pulls", "seconds"}
        assert info["score"] == info["box_swaps"] * info["displacement"] > 0
        assert 1 <= info["box_swaps"] <= info["pulls"]
        assert info["displacement"] <= info["pulls"]


def test_generated_levels_count_swaps_not_pulls():
    _, infos = levels("sokoban", 20, seed=11)
    assert all(i["box_swaps"] <= i["pulls"] for i in infos)
    assert any(i["box_swaps"] < i["pulls"] for i in infos)  # gym-sokoban's count: always equal


def test_mean_difficulty_of_10x10_levels():
    _, infos = levels("sokoban", 30, seed=21)
    # gym-sokoban's exhaustive search: a mean displacement of about 16 (benchmarks/bench_sokoban.py)
    assert np.mean([i["displacement"] for i in infos]) >= 12


# ---------------------------------------------------------------------------- solvability

def play(env, actions):
    rewards, ends = [], []
    for action in actions:
        _, reward, terminated, truncated, info = env.step(action)
        rewards.append(reward)
        ends.append((terminated, truncated))
    return rewards, ends, info


@pytest.mark.parametrize("name,n,max_nodes", [("sokoban-small", 30, 20_000), ("sokoban", 4, 200_000)])
def test_solver_solves_generated_levels_and_the_env_agrees(name, n, max_nodes):
    num_boxes = VARIANTS[name][1]
    env = make_env(name, observation="grid", max_steps=10_000)
    env.reset(seed=42)
    for i in range(n):
        if i:
            env.reset()
        actions = solve(env.unwrapped.board, max_nodes)
        assert actions, f"level {i} not solved"
        rewards, ends, info = play(env, actions)
        assert ends[-1] == (True, False) and not any(t or u for t, u in ends[:-1])
        assert info["boxes_on_target"] == num_boxes
        assert rewards[-1] == pytest.approx(-0.1 + 1 + 10)
        # every box starts off target: total = step penalties + num_boxes net arrivals + 10
        assert sum(rewards) == pytest.approx(-0.1 * len(actions) + num_boxes + 10)


def test_solver_returns_none_on_an_unsolvable_board():
    board = np.array([[0, 0, 0, 0, 0],
                      [0, 4, 1, 2, 0],
                      [0, 1, 5, 1, 0],
                      [0, 0, 0, 0, 0]])  # the box sits in a corner
    assert solve(board) is None
    assert solve(np.array([[0, 0, 0, 0], [0, 5, 3, 0], [0, 0, 0, 0]])) == []


# ---------------------------------------------------------------------------- rules

BOARD = np.array([[0, 0, 0, 0, 0, 0, 0],
                  [0, 5, 4, 2, 1, 1, 0],
                  [0, 1, 1, 1, 4, 0, 0],
                  [0, 1, 1, 1, 2, 1, 0],
                  [0, 0, 0, 0, 0, 0, 0]])


def built(board=BOARD, max_steps=120):
    """An env whose generated level is replaced by `board`."""
    env = SokobanEnv((7, 7), 2, observation="grid", max_steps=max_steps)
    env.reset(seed=0)
    env.unwrapped.board = np.array(board)
    return env


def test_push_onto_and_off_a_target():
    env = built()
    _, reward, terminated, truncated, info = env.step(3)  # push right: the box onto the target
    assert reward == pytest.approx(-0.1 + 1) and info["boxes_on_target"] == 1
    assert not (terminated or truncated)  # the other box is still off its target
    assert env.board[1, 2] == PLAYER and env.board[1, 3] == BOX_ON_TARGET
    _, reward, _, _, info = env.step(3)  # push right again: off the target, the player onto it
    assert reward == pytest.approx(-0.1 - 1) and info["boxes_on_target"] == 0
    assert env.board[1, 3] == PLAYER_ON_TARGET and env.board[1, 4] == BOX and env.board[1, 2] == FLOOR
    _, reward, _, _, _ = env.step(5)  # move down, off the target
    assert reward == pytest.approx(-0.1)
    assert env.board[1, 3] == TARGET and env.board[2, 3] == PLAYER


def test_solving_gives_ten_and_terminates():
    env = built(np.array([[0, 0, 0, 0, 0, 0],
                          [0, 5, 4, 2, 1, 0],
                          [0, 1, 1, 3, 1, 0],
                          [0, 0, 0, 0, 0, 0]]))
    _, reward, terminated, truncated, info = env.step(3)  # the last box onto its target
    assert reward == pytest.approx(-0.1 + 1 + 10) and terminated and not truncated
    assert info["boxes_on_target"] == 2


def test_move_never_pushes_and_blocked_pushes_cost_a_step():
    env = built()
    before = env.board.copy()
    _, reward, *_ = env.step(7)  # move right into the box
    assert reward == pytest.approx(-0.1) and np.array_equal(env.board, before)
    _, reward, *_ = env.step(0)  # push up into the wall
    assert reward == pytest.approx(-0.1) and np.array_equal(env.board, before)
    boxes_in_a_row = np.array([[0, 0, 0, 0, 0, 0],
                               [0, 5, 4, 4, 2, 0],
                               [0, 1, 1, 1, 2, 0],
                               [0, 0, 0, 0, 0, 0]])
    env = built(boxes_in_a_row)
    _, reward, *_ = env.step(3)  # push right into two boxes
    assert reward == pytest.approx(-0.1) and np.array_equal(env.board, boxes_in_a_row)
    box_at_wall = np.array([[0, 0, 0, 0, 0],
                            [0, 2, 5, 4, 0],
                            [0, 1, 1, 2, 0],
                            [0, 0, 0, 0, 0]])
    env = built(box_at_wall)
    _, reward, *_ = env.step(3)  # push right into the wall behind the box
    assert reward == pytest.approx(-0.1) and np.array_equal(env.board, box_at_wall)
    _, reward, *_ = env.step(6)  # a move onto floor does move
    assert env.board[1, 1] == PLAYER_ON_TARGET


def test_truncation_after_max_steps():
    env = built(max_steps=5)
    for t in range(1, 6):
        _, reward, terminated, truncated, _ = env.step(4)  # move up into the wall
        assert reward == pytest.approx(-0.1) and not terminated
        assert truncated == (t == 5)
    env.reset()
    assert env.steps == 0


def test_reset_from_a_given_board_padded_with_wall_to_the_room():
    env = SokobanEnv((7, 7), 2, observation="grid")
    obs, info = env.reset(seed=0, options={"board": BOARD})
    assert np.array_equal(env.board[:5], BOARD) and (env.board[5:] == 0).all() and info["boxes_on_target"] == 0
    assert np.array_equal(obs, env.board[1:-1, 1:-1].ravel())


# ---------------------------------------------------------------------------- generation parts

def test_box_swaps_count_changes_of_pulled_box_not_pulls():
    assert count_box_swaps([]) == 0
    assert count_box_swaps([2, 2, 2, 2]) == 1  # one box pulled four times: no swap beyond the first
    assert count_box_swaps([0, 1, 0, 1]) == 4  # alternating: every pull a swap
    assert count_box_swaps([0, 0, 1, 1, 0]) == 3
    targets = [(1, 1), (1, 4)]
    boxes = [(3, 1), (1, 2)]  # displacement 2 + 2
    assert box_displacement(boxes, targets) == 4
    assert level_score([0, 0, 1, 1], boxes, targets) == 2 * 4  # gym-sokoban: 4 * 4
    assert level_score([0, 1], [(3, 1), (1, 1)], targets) == 0  # a box on a target


def test_reverse_play_pulls_boxes_off_targets_in_a_corridor():
    room = np.zeros((3, 8), np.uint8)
    room[1, 1:7] = 1  # a corridor; the player left of the box, which it can only pull leftwards
    boxes, player, pulled, score = reverse_play(room, [(1, 5)], (1, 4), np.random.default_rng(0))
    assert boxes == [(1, 2)] and player == (1, 1) and pulled == [0, 0, 0]
    assert score == level_score(pulled, boxes, [(1, 5)]) == 1 * 3
    stuck = np.zeros((4, 4), np.uint8)
    stuck[1, 1:3] = stuck[2, 2] = 1  # no cell to step back to in line with the box
    assert reverse_play(stuck, [(1, 1)], (1, 2), np.random.default_rng(0)) == ([(1, 1)], (1, 2), [], 0)


@pytest.mark.parametrize("dim_room,num_boxes", VARIANTS.values())
def test_reverse_play_scores_with_level_score(dim_room, num_boxes):
    rng = np.random.default_rng(4)
    swaps_below_pulls = 0
    for _ in range(15):
        room = room_topology(dim_room, rng)
        if np.count_nonzero(room) <= num_boxes + 1:
            continue
        player, targets = place_player_and_targets(room, num_boxes, rng)
        boxes, player, pulled, score = reverse_play(room, targets, player, rng)
        assert score == level_score(pulled, boxes, targets)
        assert (score > 0) == bool(pulled)
        swaps_below_pulls += count_box_swaps(pulled) < len(pulled)
    assert swaps_below_pulls > 0  # scored with gym-sokoban's count, swaps would equal pulls


# ---------------------------------------------------------------------------- observations

def test_grid_observation_is_the_inner_board():
    env = make_env("sokoban", observation="grid")
    obs, _ = env.reset(seed=8)
    assert obs.shape == (64,) and obs.dtype == np.uint8
    assert np.array_equal(obs, env.unwrapped.board[1:-1, 1:-1].ravel())
    for action in np.random.default_rng(0).integers(0, 8, 30):
        obs, *_ = env.step(int(action))
        assert np.array_equal(obs, env.unwrapped.board[1:-1, 1:-1].ravel())


@pytest.mark.parametrize("tile_size", [1, 4, 16])
def test_rgb_observation_draws_each_cell_with_its_tile(tile_size):
    env = SokobanEnv((7, 7), 2, tile_size=tile_size)
    obs, _ = env.reset(seed=9)
    assert obs.shape == (7 * tile_size, 7 * tile_size, 3) and obs.dtype == np.uint8
    assert np.array_equal(obs, env.render())
    tiles = make_tiles(tile_size)
    assert tiles.shape == (7, tile_size, tile_size, 3)
    assert len({t.tobytes() for t in tiles}) == 7  # seven distinct sprites
    for r, c in np.ndindex(*env.board.shape):
        cell = obs[r * tile_size:(r + 1) * tile_size, c * tile_size:(c + 1) * tile_size]
        assert np.array_equal(cell, tiles[env.board[r, c]])


def test_render_without_render_mode_returns_none():
    env = SokobanEnv((7, 7), 2, observation="grid", render_mode=None)
    env.reset(seed=0)
    assert env.render() is None
