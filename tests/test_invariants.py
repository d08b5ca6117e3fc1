"""Invariants that must hold for any input (property-based, with hypothesis).

Sokoban's rules over random levels and random play; seeds that give the same level in any
process; an episode store that never loses a completed episode and never samples across an
episode boundary; planners that always return a legal action, and the best one where a small
problem's answer is known.
"""
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from wmthesis.alphazero.mcts import MCTS
from wmthesis.data import EpisodeStore
from wmthesis.envs import make_env
from wmthesis.envs.sokoban import (BOX, BOX_ON_TARGET, PLAYER, PLAYER_ON_TARGET, SOLVED_REWARD, STEP_PENALTY, TARGET,
                                   WALL)
from wmthesis.planet.cem import cem_plan

SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _counts(board: np.ndarray) -> dict:
    return {"player": int(np.isin(board, (PLAYER, PLAYER_ON_TARGET)).sum()),
            "boxes": int(np.isin(board, (BOX, BOX_ON_TARGET)).sum()),
            "targets": int(np.isin(board, (TARGET, BOX_ON_TARGET, PLAYER_ON_TARGET)).sum()),
            "on_target": int((board == BOX_ON_TARGET).sum())}


# ----------------------------------------------------------------------------- Sokoban
@SETTINGS
@given(seed=st.integers(0, 2**31 - 1), actions=st.lists(st.integers(0, 7), min_size=1, max_size=60),
       name=st.sampled_from(["sokoban-small", "sokoban"]))
def test_sokoban_rules_hold_over_random_levels_and_play(seed, actions, name):
    env = make_env(name, observation="grid")
    env.reset(seed=seed)
    board = env.unwrapped.board
    walls, start = board == WALL, _counts(board)
    assert start["player"] == 1 and start["boxes"] == start["targets"] == env.unwrapped.num_boxes
    for action in actions:
        before = _counts(board)
        _, reward, terminated, truncated, _ = env.step(action)
        after = _counts(board)
        assert after["player"] == 1
        assert (after["boxes"], after["targets"]) == (start["boxes"], start["targets"])
        assert np.array_equal(board == WALL, walls)
        expected = STEP_PENALTY + (after["on_target"] - before["on_target"]) + (SOLVED_REWARD if terminated else 0.0)
        assert reward == pytest.approx(expected)
        assert terminated == (after["on_target"] == after["boxes"])
        if terminated or truncated:
            break


LEVEL_SCRIPT = """
import sys
import numpy as np
from wmthesis.envs import make_env
env = make_env(sys.argv[1], observation="grid")
for seed in sys.argv[2:]:
    env.reset(seed=int(seed))
    print(",".join(map(str, env.unwrapped.board.ravel())))
"""


@settings(max_examples=2, deadline=None)
@given(seeds=st.lists(st.integers(0, 2**31 - 1), min_size=1, max_size=6))
def test_the_same_seed_gives_the_same_level_in_any_process(seeds):
    env = make_env("sokoban-small", observation="grid")
    here = []
    for seed in seeds:
        env.reset(seed=seed)
        here.append(",".join(map(str, env.unwrapped.board.ravel())))
    other = subprocess.run([sys.executable, "-c", LEVEL_SCRIPT, "sokoban-small", *map(str, seeds)],
                           capture_output=True, text=True, check=True).stdout.split()
    assert other == here


# ----------------------------------------------------------------------------- episode store
def _episode(index: int, length: int) -> dict:
    """An episode whose every row says which episode and step it is (to check chunks)."""
    observations = np.zeros((length, 2, 2, 1), np.uint8)
    observations[:, 0, 0, 0] = index
    observations[:, 0, 1, 0] = np.arange(length) % 256
    terminals = np.zeros(length, bool)
    terminals[-1] = True
    return dict(observations=observations, actions=np.full(length, index), rewards=np.arange(length, dtype=float),
                terminals=terminals)


class Crash(Exception):
    pass


@SETTINGS
@given(lengths=st.lists(st.integers(1, 40), min_size=1, max_size=8), crash_at=st.integers(0, 8),
       crash_in=st.sampled_from(["rows", "commit"]), data=st.data())
def test_the_store_never_loses_a_completed_episode_nor_samples_across_episodes(tmp_path_factory, lengths, crash_at,
                                                                                crash_in, data):
    path = tmp_path_factory.mktemp("store") / "episodes.h5"
    completed = []
    with EpisodeStore(path, "a", env="test", obs_shape=(2, 2, 1), chunk_steps=4) as store:
        original = store._append_index
        for k, length in enumerate(lengths):
            if k == crash_at:  # the process dies while writing this episode (SIGKILL: nothing after runs)
                def die(name, value):
                    if crash_in == "rows" or name == "episode_ends":
                        raise Crash
                    original(name, value)
                store._append_index = die
                with pytest.raises(Crash):
                    store.append_episode(**_episode(k, length))
                break
            store.append_episode(**_episode(k, length))
            completed.append(length)
    with EpisodeStore(path, "a") as store:  # reopened after the crash: trimmed to the committed episodes
        assert len(store) == len(completed)
        for k, length in enumerate(completed):
            episode = store.episode(k)
            assert np.array_equal(episode["actions"], np.full(length, k))
            assert np.array_equal(episode["observations"][:, 0, 1, 0], np.arange(length) % 256)
        store.append_episode(**_episode(len(completed), 5))  # and writing goes on
        completed.append(5)
    with EpisodeStore(path) as store:
        chunk = data.draw(st.integers(1, max(completed)))
        if max(completed) >= chunk:
            batch = store.sample_chunks(data.draw(st.integers(1, 6)), chunk, np.random.default_rng(0))
            ids = batch["observations"][..., 0, 0, 0].numpy()
            steps = batch["observations"][..., 0, 1, 0].numpy().astype(int)
            assert (ids == ids[:, :1]).all()  # one episode per chunk
            assert (np.diff(steps, axis=1) % 256 == 1).all()  # consecutive steps
            assert (batch["actions"].numpy() == ids).all()


# ----------------------------------------------------------------------------- planners
@SETTINGS
@given(n_actions=st.integers(1, 6), horizon=st.integers(1, 5), candidates=st.integers(1, 30),
       iterations=st.integers(1, 3), seed=st.integers(0, 1000), data=st.data())
def test_cem_returns_a_legal_action_for_any_legal_input(n_actions, horizon, candidates, iterations, seed, data):
    top_k = data.draw(st.integers(1, candidates))
    weights = torch.randn(horizon, n_actions, generator=torch.Generator().manual_seed(seed))

    def rollout(actions):  # any finite returns, ties included
        return (actions * weights).sum((1, 2)).round()

    action = cem_plan(rollout, n_actions, horizon, candidates, top_k, iterations,
                      torch.Generator().manual_seed(seed))
    assert isinstance(action, int) and 0 <= action < n_actions


class RandomMDP:
    """A random deterministic MDP over integer states with random rewards and terminals."""

    def __init__(self, n_actions: int, seed: int):
        self.action_space = gym.spaces.Discrete(n_actions)
        self.seed = seed

    def _draw(self, state, action):
        return np.random.default_rng([self.seed, state % 2**32, action])

    def transition(self, state, action):
        rng = self._draw(state, action)
        return int(rng.integers(10_000)), float(rng.normal())

    def is_terminal(self, state) -> bool:
        return state % 7 == 0 and state > 0


@SETTINGS
@given(n_actions=st.integers(1, 6), simulations=st.integers(1, 40), seed=st.integers(0, 1000),
       train_mode=st.booleans(), normalize_q=st.booleans(), c=st.floats(0.0, 5.0))
def test_mcts_returns_a_legal_action_for_any_legal_input(n_actions, simulations, seed, train_mode, normalize_q, c):
    rng = np.random.default_rng(seed)

    def evaluator(state):
        priors = rng.dirichlet(np.ones(n_actions))
        return priors, float(rng.normal())

    mcts = MCTS(RandomMDP(n_actions, seed), evaluator, c=c, n_simulations=simulations, normalize_q=normalize_q,
                seed=seed)
    counts = mcts.plan(int(rng.integers(1, 10_000)), train_mode=train_mode)
    assert counts.shape == (n_actions,) and np.isfinite(counts).all() and (counts >= 0).all()
    action = int(np.argmax(counts))
    assert 0 <= action < n_actions


@SETTINGS
@given(n_actions=st.integers(2, 5), horizon=st.integers(1, 4), seed=st.integers(0, 10_000))
def test_cem_finds_the_best_first_action_of_a_random_separable_landscape(n_actions, horizon, seed):
    """Return = sum over steps of a weight per (step, action): the best plan takes each step's
    largest weight, so CEM's first action is the first row's argmax wherever that row has a margin."""
    weights = torch.randn(horizon, n_actions, generator=torch.Generator().manual_seed(seed))
    top = weights[0].sort(descending=True).values
    assume(float(top[0] - top[1]) > 0.3)
    action = cem_plan(lambda actions: (actions * weights).sum((1, 2)), n_actions, horizon, 300, 30, 5,
                      torch.Generator().manual_seed(seed))
    assert action == int(weights[0].argmax())


class TwoStepTree:
    """A deterministic two-step game: from the root (0), action a pays ``first[a]`` and leads to
    state 1 + a; from there action b pays ``second[a, b]`` and ends the game (state 100 + 10 a + b)."""

    def __init__(self, first: np.ndarray, second: np.ndarray):
        self.first, self.second = first, second
        self.action_space = gym.spaces.Discrete(len(first))

    def transition(self, state, action):
        if state == 0:
            return 1 + action, float(self.first[action])
        return 100 + 10 * (state - 1) + action, float(self.second[state - 1, action])

    def is_terminal(self, state) -> bool:
        return state >= 100


@SETTINGS
@given(n_actions=st.integers(2, 4), seed=st.integers(0, 10_000))
def test_mcts_visits_the_best_path_of_a_random_two_step_game_most(n_actions, seed):
    """With uniform priors and a value of 0 at every leaf, enough simulations find the first
    action whose best continuation pays the most (undiscounted), wherever it wins by a margin."""
    rng = np.random.default_rng(seed)
    first, second = rng.normal(size=n_actions), rng.normal(size=(n_actions, n_actions))
    totals = np.sort(first + second.max(1))[::-1]
    assume(totals[0] - totals[1] > 0.3)
    mcts = MCTS(TwoStepTree(first, second), lambda state: (np.full(n_actions, 1 / n_actions), 0.0), c=1.25,
                n_simulations=60 * n_actions ** 2, gamma=1.0, normalize_q=True, seed=seed)
    counts = mcts.plan(0, train_mode=False)
    assert int(np.argmax(counts)) == int(np.argmax(first + second.max(1)))
