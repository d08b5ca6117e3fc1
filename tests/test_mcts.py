"""AlphaZero MCTS (thesis 4.3.2) on tiny deterministic MDPs with known optimal values.

No mocks of the search: real MDP classes written here, evaluators as plain functions, and a
gymnasium chain whose dynamics the chain MDP mirrors for the :func:`loop` test.
"""
import time

import gymnasium as gym
import numpy as np
import pytest

from wmthesis.alphazero.mcts import MCTS, most_probable
from wmthesis.core import Callback, loop

LEFT, RIGHT = 0, 1


class ChainMDP:
    """Positions 0..n-1; RIGHT moves right, LEFT left (clamped at 0); reaching n-1 pays
    ``scale`` and is terminal. Optimal value from position 0: ``scale * gamma**(n-2)``."""

    def __init__(self, n=5, scale=1.0):
        self.n, self.scale = n, scale
        self.action_space = gym.spaces.Discrete(2)

    def transition(self, state, action):
        next_state = max(0, min(self.n - 1, state + (1 if action == RIGHT else -1)))
        return next_state, self.scale * float(next_state == self.n - 1)

    def is_terminal(self, state):
        return state == self.n - 1


class TreeMDP:
    """A depth-3 tree over 3 actions; a state is the tuple of actions taken.

    Action 0 at the root pays ``small`` at once; the only other reward, ``big``, is on the
    leaf behind actions (2, 0, 1), reached with zero reward on the way. Depth 3 is terminal.
    """

    GOAL = (2, 0, 1)

    def __init__(self, small=0.1, big=1.0):
        self.small, self.big = small, big
        self.action_space = gym.spaces.Discrete(3)

    def transition(self, state, action):
        next_state = state + (action,)
        reward = self.small if next_state == (0,) else self.big if next_state == self.GOAL else 0.0
        return next_state, reward

    def is_terminal(self, state):
        return len(state) == 3


class LineMDP:
    """An endless line: every state is new, nothing terminates, no reward."""

    action_space = gym.spaces.Discrete(2)

    def transition(self, state, action):
        return state + 1, 0.0

    def is_terminal(self, state):
        return False


class ChainEnv(gym.Env):
    """The gymnasium twin of :class:`ChainMDP` (reward 1 on reaching the end)."""

    def __init__(self, n=5):
        self.n = n
        self.observation_space = gym.spaces.Discrete(n)
        self.action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.position = 0
        return self.position, {}

    def step(self, action):
        self.position = max(0, min(self.n - 1, self.position + (1 if action == RIGHT else -1)))
        done = self.position == self.n - 1
        return self.position, float(done), done, False, {}


def uniform(n_actions):
    return lambda state: (np.ones(n_actions), 0.0)


def search(mdp, evaluator, state, n, **options):
    """Counts and info of one fresh search without noise."""
    mcts = MCTS(mdp, evaluator, n_simulations=n, **options)
    return mcts.plan(state, train_mode=False, debug_mode=True)


def simulations_until_right(mdp, evaluator, state, best, max_n=120):
    """The smallest budget n from which every budget up to ``max_n`` picks ``best``."""
    right = [np.argmax(search(mdp, evaluator, state, n)[0]) == best for n in range(1, max_n + 1)]
    assert right[-1], "never found the best action"
    wrong = [n for n, ok in enumerate(right, start=1) if not ok]
    return wrong[-1] + 1 if wrong else 1


# ----------------------------------------------------------------------------- search quality
def test_chain_picks_right_and_root_value_approaches_the_optimal_value():
    gamma, mdp = 0.9, ChainMDP(5)
    optimal = gamma ** 3  # four steps right, reward 1 on the last one
    errors = {}
    for n in (200, 2000):
        counts, info = search(mdp, uniform(2), 0, n, gamma=gamma)
        assert counts.dtype == np.float64 and counts.shape == (2,) and counts.sum() == n
        assert np.argmax(counts) == RIGHT
        errors[n] = abs(info["root_value"] - optimal)
        assert info["root_value"] <= optimal + 1e-12  # a mean of returns no better than optimal
    assert errors[2000] < 0.05
    assert errors[2000] < errors[200] / 2


def test_delayed_larger_reward_beats_a_small_immediate_one():
    counts, info = search(TreeMDP(small=0.1, big=1.0), uniform(3), (), 300, gamma=0.99)
    assert np.argmax(counts) == 2
    assert info["q"][2] > info["q"][0]
    assert info["max_depth"] == 3
    # a one-step lookahead would take the immediate reward
    counts, _ = search(TreeMDP(small=0.1, big=1.0), uniform(3), (), 300, gamma=0.99, c=0.0)
    assert np.argmax(counts) == 0


def test_informative_priors_need_fewer_simulations():
    mdp = TreeMDP(small=0.1, big=1.0)

    def informed(state):  # mass on the path to the goal
        depth = len(state)
        priors = np.full(3, 0.05)
        priors[TreeMDP.GOAL[depth]] = 0.9
        return priors, 0.0

    with_priors = simulations_until_right(mdp, informed, (), best=2)
    without = simulations_until_right(mdp, uniform(3), (), best=2)
    assert with_priors < without
    assert with_priors <= 5 and without >= 10
    # U uses sqrt(max(N(s), 1)): the very first simulation already follows the priors
    assert search(mdp, informed, (), 1)[0].tolist() == [0, 0, 1]


def test_discounted_backup_matches_a_hand_computation():
    """One action: 0 -r=1-> 1 -r=2-> 2 (terminal); V = 10 for non-terminal states, gamma 0.9.

    sim 1: G = 1 + 0.9 * V(1) = 10.  sim 2: expands state 2 (terminal, V = 0): G = 2 on the
    second edge, 1 + 0.9 * 2 = 2.8 on the first. sim 3: reaches the terminal node again: 2.8.
    """

    class TwoSteps:
        action_space = gym.spaces.Discrete(1)

        def transition(self, state, action):
            return state + 1, float(state + 1)

        def is_terminal(self, state):
            return state == 2

    evaluator = lambda state: ([1.0], 10.0)  # noqa: E731
    expected = {1: 10.0, 2: (10 + 2.8) / 2, 3: (10 + 2.8 + 2.8) / 3}
    for n, root_value in expected.items():
        counts, info = search(TwoSteps(), evaluator, 0, n, gamma=0.9)
        assert counts.tolist() == [n]
        assert info["root_value"] == pytest.approx(root_value, abs=1e-12)
        assert info["q"][0] == pytest.approx(root_value, abs=1e-12)
        assert info["max_depth"] == min(n, 2)


def test_normalized_q_is_invariant_to_the_reward_scale():
    """Rewards x1000 with normalised Q: the same counts as unscaled, the same action as the
    plain search on unscaled rewards. (Normalised Q stretches the small immediate reward to
    the full [0, 1] range, so this deceptive tree needs c = 2 and 1,000 simulations.)"""
    small, big, options = 0.1, 1.0, dict(c=2.0)
    plain, _ = search(TreeMDP(small, big), uniform(3), (), 1000, **options)
    normed, _ = search(TreeMDP(small, big), uniform(3), (), 1000, normalize_q=True, **options)
    scaled = TreeMDP(1000 * small, 1000 * big)
    scaled_normed, _ = search(scaled, uniform(3), (), 1000, normalize_q=True, **options)
    scaled_plain, _ = search(scaled, uniform(3), (), 1000, **options)
    assert np.argmax(plain) == np.argmax(normed) == np.argmax(scaled_normed) == 2
    np.testing.assert_array_equal(scaled_normed, normed)
    # without normalisation, rewards of 100 drown the prior bonus: greedy on the first reward
    assert np.argmax(scaled_plain) == 0 and scaled_plain[0] > 900


class WideMDP:
    """18 actions, each edge a fixed pseudo-random reward N(0, 1), terminal at depth 30."""

    action_space = gym.spaces.Discrete(18)

    def transition(self, state, action):
        next_state = state + (action,)
        return next_state, float(np.random.default_rng(list(next_state)).normal())

    def is_terminal(self, state):
        return len(state) >= 30


def test_normalized_q_scores_untried_actions_at_the_node_value():
    """With 0 for unvisited edges, normalised Q makes untried actions look worst: a 50-simulation
    search tried ~2 of 18 root actions and dived to depth ~29. Scored at the node's mean Q
    (as mctx does), it tries nearly every root action and stays shallow."""
    tried, depths = [], []
    for seed in range(10):
        counts, info = search(WideMDP(), uniform(18), (seed,), 50, normalize_q=True)
        tried.append((counts > 0).sum())
        depths.append(info["max_depth"])
    assert np.mean(tried) > 15 and np.median(depths) <= 10


# ----------------------------------------------------------------------------- priors and noise
def test_all_zero_or_nan_priors_behave_as_uniform():
    reference, ref_info = search(TreeMDP(), uniform(3), (), 100)
    for bad in (np.zeros(3), np.full(3, np.nan), [np.inf, 1.0, 1.0]):
        counts, info = search(TreeMDP(), lambda state, bad=bad: (bad, 0.0), (), 100)
        np.testing.assert_array_equal(counts, reference)
        np.testing.assert_allclose(info["priors"], np.full(3, 1 / 3))


def test_priors_are_normalised_and_checked():
    counts, info = search(TreeMDP(), lambda state: ([2.0, 6.0, 0.0], 0.0), (), 10)
    np.testing.assert_allclose(info["priors"], [0.25, 0.75, 0.0])
    with pytest.raises(ValueError, match="non-negative"):
        search(TreeMDP(), lambda state: ([-1.0, 0.5, 0.5], 0.0), (), 10)
    with pytest.raises(ValueError, match="3 actions"):
        search(TreeMDP(), lambda state: ([0.5, 0.5], 0.0), (), 10)


def test_dirichlet_noise_only_in_train_mode_and_seeded():
    def plan(seed, train_mode):
        mcts = MCTS(TreeMDP(), uniform(3), n_simulations=60, seed=seed)
        return mcts.plan((), train_mode=train_mode, debug_mode=True)

    test_a, info_a = plan(0, False)
    test_b, info_b = plan(1, False)
    np.testing.assert_array_equal(test_a, test_b)
    np.testing.assert_array_equal(info_a["priors"], np.full(3, 1 / 3))

    train_0, info_0 = plan(0, True)
    train_0_again, info_0_again = plan(0, True)
    _, info_1 = plan(1, True)
    np.testing.assert_array_equal(train_0, train_0_again)
    np.testing.assert_array_equal(info_0["priors"], info_0_again["priors"])
    assert not np.allclose(info_0["priors"], info_1["priors"])
    assert not np.allclose(info_0["priors"], 1 / 3)
    assert info_0["priors"].sum() == pytest.approx(1.0)
    assert info_0["priors"].min() >= 0.75 / 3 - 1e-12  # at least (1 - ratio) of the prior is kept


# ----------------------------------------------------------------------------- budget
def test_timeout_stops_the_search():
    def slow(state):
        time.sleep(0.005)
        return np.ones(2), 0.0

    mcts = MCTS(LineMDP(), slow, n_simulations=10_000, timeout=0.05)
    start = time.perf_counter()
    counts, info = mcts.plan(0, train_mode=False, debug_mode=True)
    elapsed = time.perf_counter() - start
    assert elapsed < 0.05 + 0.1
    assert 1 <= info["simulations"] <= 10  # each simulation sleeps 5 ms
    assert counts.sum() == info["simulations"]


def test_at_least_one_simulation_and_exact_budget():
    mcts = MCTS(LineMDP(), uniform(2), n_simulations=7, timeout=1e-9)
    assert mcts.plan(0, debug_mode=True)[1]["simulations"] == 1
    mcts = MCTS(LineMDP(), uniform(2), n_simulations=7)
    assert mcts.plan(0, debug_mode=True)[1]["simulations"] == 7


def test_a_depth_cap_keeps_the_tree_shallow_and_backs_up_the_capped_leaf_value():
    """With ``max_depth=1`` the search is a one-step lookahead: Q(a) = R(a) + gamma V(s_a) on
    every visit, however many simulations; the big reward three steps down is out of reach."""
    value = {(0,): 0.0, (1,): 0.5, (2,): 0.2}
    evaluator = lambda state: (np.ones(3), value.get(state, 0.0))  # noqa: E731
    counts, info = search(TreeMDP(small=0.1, big=1.0), evaluator, (), 300, gamma=0.9, max_depth=1)
    assert info["max_depth"] == 1 and counts.sum() == 300
    np.testing.assert_allclose(info["q"], [0.1, 0.9 * 0.5, 0.9 * 0.2])
    assert np.argmax(counts) == 1
    _, deep = search(TreeMDP(small=0.1, big=1.0), evaluator, (), 300, gamma=0.9, max_depth=2)
    assert deep["max_depth"] == 2
    _, free = search(LineMDP(), uniform(2), 0, 50)
    assert free["max_depth"] > 2  # no cap: an endless line is followed deeper


def test_root_actions_keep_the_root_to_its_most_probable_actions_however_many_simulations():
    """With ``root_actions=2`` the root never visits its least probable action, even where that
    action leads to the big reward, and even with the normalised Q that gives an unvisited edge
    the node's mean; without it, the search tries that action."""
    priors = lambda state: (np.array([0.5, 0.3, 0.2]) if state == () else np.ones(3), 0.0)  # noqa: E731
    for normalize_q in (False, True):
        counts, info = search(TreeMDP(small=0.1, big=1.0), priors, (), 400, gamma=0.9, root_actions=2,
                              normalize_q=normalize_q)
        assert counts[2] == 0 and counts.sum() == 400 and np.isnan(info["q"][2])
        assert np.argmax(counts) == 0  # the small reward is the best of the two allowed
        free, _ = search(TreeMDP(small=0.1, big=1.0), priors, (), 400, gamma=0.9, normalize_q=normalize_q)
        assert free[2] > 0
    # the k most probable after the root's noise; ties to the lower index
    np.testing.assert_array_equal(most_probable(np.array([0.2, 0.5, 0.2, 0.1]), 2), [True, True, False, False])


@pytest.mark.parametrize("option", [dict(n_simulations=0), dict(timeout=0.0), dict(c=-1.0), dict(max_depth=0),
                                    dict(root_actions=0),
                                    dict(gamma=1.5), dict(dirichlet_alpha=0.0), dict(noise_ratio=2.0)])
def test_invalid_options_raise(option):
    with pytest.raises(ValueError):
        MCTS(LineMDP(), uniform(2), **option)


# ----------------------------------------------------------------------------- tree reuse
def test_advance_keeps_the_subtree_and_the_next_plan_adds_to_it():
    mdp = ChainMDP(6)
    mcts = MCTS(mdp, uniform(2), n_simulations=100, gamma=0.9)
    mcts.plan(0, train_mode=False)
    child = mcts.root.children[RIGHT]
    n_before, q_before, visits_before = child.N.copy(), child.Q.copy(), child.visits
    assert visits_before > 10

    mcts.advance(RIGHT)
    assert mcts.root is child
    np.testing.assert_array_equal(mcts.root.N, n_before)
    np.testing.assert_array_equal(mcts.root.Q, q_before)

    real_state = np.int64(1)  # the real observation: equal, but another object than the model's
    counts, info = mcts.plan(real_state, train_mode=False, debug_mode=True)
    assert info["reused"] and mcts.root is child and mcts.root.state is real_state
    assert counts.sum() == n_before.sum() + 100
    assert np.all(counts >= n_before)
    assert mcts.root.visits == visits_before + 100


def test_no_reuse_without_advance_or_when_disabled():
    mcts = MCTS(ChainMDP(6), uniform(2), n_simulations=50)
    assert mcts.plan(0, train_mode=False).sum() == 50
    assert mcts.plan(0, train_mode=False).sum() == 50  # no advance: a fresh tree

    mcts = MCTS(ChainMDP(6), uniform(2), n_simulations=50, reuse_tree=False)
    mcts.plan(0, train_mode=False)
    mcts.advance(RIGHT)
    counts, info = mcts.plan(1, train_mode=False, debug_mode=True)
    assert counts.sum() == 50 and not info["reused"]


def test_an_unexpanded_child_starts_a_fresh_tree():
    mcts = MCTS(TreeMDP(), uniform(3), n_simulations=1)
    mcts.plan((), train_mode=False)  # one simulation expands action 0 only
    mcts.advance(1)
    assert mcts.root is None
    counts, info = mcts.plan((1,), train_mode=False, debug_mode=True)
    assert counts.sum() == 1 and not info["reused"]


def test_episode_start_forgets_the_tree():
    mcts = MCTS(ChainMDP(6), uniform(2), n_simulations=50)
    mcts.plan(0, train_mode=False)
    mcts.advance(RIGHT)
    mcts.on_episode_start(1, True)
    assert mcts.root is None
    assert mcts.plan(0, train_mode=False).sum() == 50


# ----------------------------------------------------------------------------- as a Mind
class PlanInfo(Callback):
    def __init__(self):
        self.reused = []

    def on_action_planned(self, step, scores, info):
        self.reused.append(info["reused"])


def test_mcts_reaches_the_goal_in_loop():
    n = 5
    mcts = MCTS(ChainMDP(n), uniform(2), n_simulations=50, seed=0)
    plans = PlanInfo()
    history = loop(ChainEnv(n), mcts, callbacks=[mcts, plans], train_mode=False, debug_mode=True,
                   max_steps=30)
    assert history[0]["terminated"] and history[0]["return"] == 1.0
    assert history[0]["steps"] == n - 1  # greedy on visit counts walks straight right
    assert plans.reused == [False] + [True] * (n - 2)

    history = loop(ChainEnv(n), mcts, callbacks=[mcts], policy="proportional",
                   policy_options={"warmup": 3}, n_episodes=2, max_steps=30, seed=0)
    assert all(episode["terminated"] and episode["return"] == 1.0 for episode in history)
