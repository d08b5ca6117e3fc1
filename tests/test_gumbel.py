"""Gumbel MuZero's root: each small function against values computed by hand (and mctx's own
schedule), and the guarantee: on a bandit with known Q, the action returned is at least as good
as the prior's in expectation, at every budget from 2 to 256."""
from __future__ import annotations

import re

import gymnasium as gym
import numpy as np
import pytest

from wmthesis.alphazero.gumbel import (GumbelMCTS, completed_q, considered_scores, considered_visits, gumbel_top_k,
                                       improved_policy, interior_action, mixed_value, sigma)


def test_sequential_halving_visits_as_mctx_schedules_them():
    # mctx's test_considered_min_sims: 24 simulations, 8 actions
    assert considered_visits(8, 24) == (0,) * 8 + (1,) * 4 + (2,) * 4 + (3, 3, 4, 4, 5, 5, 6, 6)
    assert considered_visits(1, 5) == (0, 1, 2, 3, 4)
    assert considered_visits(2, 2) == (0, 0)  # two simulations: each of the two sampled actions once
    assert len(considered_visits(16, 256)) == 256


def test_completed_q_and_sigma_by_hand():
    value, q, visits, priors = 0.5, np.array([1.0, 0.0, 0.2]), np.array([2.0, 0.0, 1.0]), np.array([0.5, 0.3, 0.2])
    weighted = (0.5 * 1.0 + 0.2 * 0.2) / 0.7
    mixed = (0.5 + 3 * weighted) / 4
    assert mixed_value(value, q, visits, priors) == pytest.approx(mixed)
    assert mixed_value(value, q, np.zeros(3), priors) == value  # nothing visited: the node's own value
    completed = completed_q(value, q, visits, priors)
    np.testing.assert_allclose(completed, [1.0, mixed, 0.2])
    np.testing.assert_allclose(sigma(completed, visits), (50 + 2) * 0.1 * (completed - 0.2) / 0.8)
    np.testing.assert_allclose(sigma(np.full(3, 0.4), visits), 0.0)  # a flat node: no preference
    logits = np.log(priors)
    policy = improved_policy(logits, sigma(completed, visits))
    expected = np.exp(logits + sigma(completed, visits))
    np.testing.assert_allclose(policy, expected / expected.sum())


def test_gumbel_top_k_root_scores_and_interior_selection_by_hand():
    logits, gumbel = np.log([0.1, 0.2, 0.3, 0.4]), np.array([1.0, 0.5, -2.0, 0.0])
    assert list(gumbel_top_k(logits, 2, gumbel)) == [3, 1]  # 0 - 0.92 and 0.5 - 1.61 beat 1 - 2.30 and -2 - 1.20
    scores = considered_scores(1, gumbel, logits, np.zeros(4), np.array([1.0, 0.0, 1.0, 2.0]))
    assert np.isinf(scores[[1, 3]]).all() and scores.argmax() == 0  # only actions with 1 visit compete
    # the improved policy is (1/6, 2/6, 3/6) with no Q; visits (1, 1, 0) lag it most at action 2
    assert interior_action(np.log([1 / 6, 2 / 6, 3 / 6]), np.zeros(3), np.array([1.0, 1.0, 0.0])) == 2
    assert interior_action(np.log([1 / 6, 2 / 6, 3 / 6]), np.zeros(3), np.array([0.0, 0.0, 5.0])) == 1


class Bandit:
    """One step: action a pays q[a] and ends the episode."""

    def __init__(self, q):
        self.q = np.asarray(q, float)
        self.action_space = gym.spaces.Discrete(len(q))

    def transition(self, state, action):
        return (action,), float(self.q[action])

    def is_terminal(self, state):
        return len(state) == 1


@pytest.mark.parametrize("budget", [2, 4, 8, 16, 64, 256])
def test_the_gumbel_action_is_no_worse_than_the_priors_in_expectation_at_every_budget(budget):
    rng = np.random.default_rng(0)
    q = rng.uniform(0, 1, 8)
    priors = rng.dirichlet(np.full(8, 0.5))
    priors[np.argmax(q)] = 1e-3  # the prior misses the best arm
    priors /= priors.sum()
    chosen = []
    for seed in range(200):
        search = GumbelMCTS(Bandit(q), lambda state: (priors, 0.0), n_simulations=budget, considered=8, seed=seed,
                            gamma=1.0)
        chosen.append(q[search.plan((), train_mode=True).argmax()])
    assert np.mean(chosen) >= priors @ q  # the guarantee: no worse than acting on the prior
    assert np.mean(chosen) > priors @ q + 0.05  # and here strictly better: search pays from 2 simulations


def test_more_simulations_find_the_best_arm_and_the_target_follows_them():
    q = np.array([0.1, 0.9, 0.3, 0.2])
    search = GumbelMCTS(Bandit(q), lambda state: (np.full(4, 0.25), 0.0), n_simulations=64, considered=4, seed=1,
                        gamma=1.0)
    scores, info = search.plan((), train_mode=True, debug_mode=True)
    assert scores.argmax() == 1 and info["improved_policy"].argmax() == 1
    assert info["visits"].sum() == 64 and info["simulations"] == 64


def test_bad_options_are_refused():
    bandit = Bandit([0.0, 1.0])
    with pytest.raises(ValueError, match=r"considered must be an integer in \[1, 2\]"):
        GumbelMCTS(bandit, lambda s: (np.ones(2), 0.0), considered=3)
    with pytest.raises(ValueError, match="at least 2 simulations"):
        GumbelMCTS(bandit, lambda s: (np.ones(2), 0.0), considered=2, n_simulations=1)


def test_the_configs_root_chooses_the_search():
    """``AlphaZeroConfig.root``: None is the thesis's PUCT search, "gumbel" Gumbel MuZero's root
    with k = min(16, A) (no tree reuse), anything else refused naming the roots."""
    import dataclasses

    from wmthesis.alphazero.config import AlphaZeroConfig
    from wmthesis.alphazero.gumbel import GumbelMCTS, root_search
    from wmthesis.alphazero.mcts import MCTS

    bandit = Bandit([0.1, 0.9, 0.3, 0.2])
    config = AlphaZeroConfig(simulations=8)
    assert type(root_search(config, bandit, lambda s: (np.ones(4), 0.0), 0)) is MCTS
    gumbel = root_search(dataclasses.replace(config, root="gumbel"), bandit, lambda s: (np.ones(4), 0.0), 0)
    assert isinstance(gumbel, GumbelMCTS) and gumbel.considered == 4 and not gumbel.reuse_tree
    assert (gumbel.gumbel_scale, gumbel.c_scale) == (1.0, 0.1)
    tuned = root_search(dataclasses.replace(config, root="gumbel", gumbel_scale=0.0, c_scale=0.03, c_visit=0.0), bandit,
                        lambda s: (np.ones(4), 0.0), 0)
    assert (tuned.gumbel_scale, tuned.c_scale, tuned.c_visit) == (0.0, 0.03, 0.0)
    with pytest.raises(ValueError, match="unknown root 'x'; valid: puct, gumbel"):
        root_search(dataclasses.replace(config, root="x"), bandit, lambda s: (np.ones(4), 0.0), 0)


@pytest.mark.parametrize("changes, says", [
    (dict(root="gumble"), "unknown root 'gumble'; valid: puct, gumbel"),
    (dict(tie_break="random"), "unknown tie_break 'random'; valid: first, q, prior"),
    (dict(root="gumbel", simulations=1), "at least 2 simulations, got 1"),
    (dict(root="gumbel", simulations=2.5), "an integer budget of at least 2 simulations, got 2.5"),
    (dict(root="gumbel", considered=1), "considers an integer number of actions, at least 2, got 1"),
    (dict(root="gumbel", c_scale=0.0), "c_scale > 0 and c_visit >= 0, got 1.0, 0.0, 50.0"),
    (dict(root="gumbel", gumbel_scale=-1.0), "gumbel_scale >= 0"),
    (dict(root="gumbel", c_visit=-1.0), "c_visit >= 0"),
])
def test_a_search_that_cannot_run_is_refused_when_it_is_configured(changes, says):
    from wmthesis.alphazero.config import AlphaZeroConfig

    with pytest.raises(ValueError, match=re.escape(says)):
        AlphaZeroConfig(**changes)


def test_a_gumbel_root_that_would_consider_more_actions_than_the_game_has_is_refused():
    from wmthesis.alphazero.config import AlphaZeroConfig
    from wmthesis.alphazero.gumbel import root_search

    class Game:
        action_space = type("Space", (), {"n": 18})()

    with pytest.raises(ValueError, match="at most the game's 18 actions, got 20"):
        root_search(AlphaZeroConfig(root="gumbel", considered=20), Game(), None, seed=0)


def test_where_the_search_moved_the_heads_action_and_what_those_steps_earned():
    """``search_changes`` on a game whose head prefers action 0 everywhere: the steps where the
    search played another action, and each step's real return over the next steps, by hand."""
    import torch

    from wmthesis.alphazero.budget import search_changes, steps_ahead_returns
    from wmthesis.alphazero.heads import AlphaZeroHeads
    from wmthesis.alphazero.replay import Game

    assert steps_ahead_returns(np.array([1.0, 0.0, -1.0, 2.0]), 2).tolist() == [1.0, -1.0, 1.0, 2.0]
    heads = AlphaZeroHeads(1, 1, 3)
    with torch.no_grad():
        heads.policy.weight.zero_()
        heads.policy.bias.copy_(torch.tensor([1.0, 0.0, 0.0]))
    T = 4
    game = Game(index=0, features=np.zeros((T, 2), np.float32), policies=np.zeros((T, 3), np.float32),
                actions=np.array([0, 2, 0, 1]), rewards=np.array([1.0, 0.0, -1.0, 2.0], np.float32),
                predicted_rewards=np.zeros(T, np.float32), root_values=np.zeros(T, np.float32),
                depths=np.zeros(T, np.int16), q=np.zeros((T, 3), np.float32), terminated=True,
                last_features=np.zeros(2, np.float32), seconds=1.0)
    changes = search_changes(heads, [game, game], steps=2)
    assert changes["changed"] == 0.5
    assert changes["return_changed"] == np.mean([-1.0, 2.0]) and changes["return_kept"] == np.mean([1.0, 1.0])
