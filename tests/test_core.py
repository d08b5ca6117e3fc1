"""HumbleRL core: loop semantics, callbacks, interpreters, policies, pool.

Each fault of the original HumbleRL (DESIGN.md) has a test here that would have caught it.
No mocks: a real gymnasium environment and a recording callback subclass, so a misspelt
event name cannot make a test pass by accident.
"""
import gymnasium as gym
import numpy as np
import pytest

from wmthesis.core import (MDP, Callback, CallbackList, ChainInterpreter, EpsilonGreedy, Interpreter,
                           Mind, Proportional, RandomMind, Stochastic, Transition, loop, make_policy, pool)


class Chain(gym.Env):
    """Positions 0..n-1, start at 0; action 1 moves right, 0 left; reaching n-1 pays 1 and terminates."""

    def __init__(self, n=4):
        self.n = n
        self.observation_space = gym.spaces.Discrete(n)
        self.action_space = gym.spaces.Discrete(2)
        self.steps_taken = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.position = 0
        return self.position, {}

    def step(self, action):
        self.steps_taken += 1
        self.position = max(0, min(self.n - 1, self.position + (1 if action == 1 else -1)))
        done = self.position == self.n - 1
        return self.position, float(done), done, False, {"position": self.position}


class Constant(Mind):
    def __init__(self, action, n_actions=2):
        self.scores = np.eye(n_actions)[action]

    def plan(self, state, train_mode=True, debug_mode=False):
        return self.scores, {"state": state}


class Recorder(Callback):
    def __init__(self):
        self.events = []

    def on_loop_start(self):
        self.events.append(("loop_start",))

    def on_loop_end(self, is_aborted):
        self.events.append(("loop_end", is_aborted))

    def on_episode_start(self, episode, train_mode):
        self.events.append(("episode_start", episode, train_mode))

    def on_episode_end(self, episode, train_mode):
        self.events.append(("episode_end", episode, train_mode))

    def on_action_planned(self, step, scores, info):
        self.events.append(("planned", step))

    def on_step_taken(self, step, transition, info):
        self.events.append(("step", step, transition, info["truncated"]))

    @property
    def metrics(self):
        return {"n_events": len(self.events)}


def test_events_in_order_for_a_terminating_episode():
    recorder = Recorder()
    history = loop(Chain(3), Constant(1), callbacks=[recorder], train_mode=False)
    names = [e[0] for e in recorder.events]
    assert names == ["loop_start", "episode_start", "planned", "step", "planned", "step", "episode_end", "loop_end"]
    assert recorder.events[1] == ("episode_start", 0, False)
    last_step = recorder.events[5]
    assert last_step[2] == Transition(1, 1, 1.0, 2, True) and last_step[3] is False
    assert recorder.events[-1] == ("loop_end", False)
    assert history == [{"episode": 0, "return": 1.0, "steps": 2, "terminated": True, "truncated": False,
                        "n_events": 7}]


def test_max_steps_runs_exactly_that_many_steps_and_ends_the_episode():
    """Original faults: one ply too many, and no on_episode_end for a cut episode."""
    env, recorder = Chain(10), Recorder()
    history = loop(env, Constant(0), n_episodes=2, max_steps=5, callbacks=[recorder])
    assert env.steps_taken == 10
    steps = [e for e in recorder.events if e[0] == "step"]
    assert [e[1] for e in steps] == [0, 1, 2, 3, 4] * 2
    assert [e[3] for e in steps] == [False, False, False, False, True] * 2
    assert all(not e[2].is_terminal for e in steps)
    assert [e for e in recorder.events if e[0] == "episode_end"] == [("episode_end", 0, True), ("episode_end", 1, True)]
    assert [(h["steps"], h["terminated"], h["truncated"]) for h in history] == [(5, False, True)] * 2


def test_truncation_by_the_environment_is_not_terminal():
    env = gym.wrappers.TimeLimit(Chain(10), max_episode_steps=3)
    recorder = Recorder()
    history = loop(env, Constant(1), callbacks=[recorder])
    steps = [e for e in recorder.events if e[0] == "step"]
    assert len(steps) == 3 and steps[-1][3] is True and not steps[-1][2].is_terminal
    assert history[0]["truncated"] and not history[0]["terminated"]


def test_reaching_max_steps_on_the_terminal_step_counts_as_terminated():
    history = loop(Chain(3), Constant(1), max_steps=2)
    assert history[0]["terminated"] and not history[0]["truncated"]


def test_unknown_keyword_arguments_fail_loudly():
    """Original fault: a misspelt `trian_mode` was silently swallowed."""
    with pytest.raises(TypeError, match="trian_mode"):
        loop(Chain(), Constant(1), trian_mode=False)
    with pytest.raises(TypeError, match="trian_mode"):
        pool(Chain, lambda: Constant(1), 1, trian_mode=False)
    with pytest.raises(ValueError, match="deterministic, stochastic, proportional, epsilon-greedy"):
        loop(Chain(), Constant(1), policy="greedy")


def test_aborted_loop_reports_it_and_reraises():
    class Exploding(Mind):
        calls = 0

        def plan(self, state, train_mode=True, debug_mode=False):
            self.calls += 1
            if self.calls == 3:
                raise KeyboardInterrupt
            return np.array([1.0, 0.0])

    recorder = Recorder()
    with pytest.raises(KeyboardInterrupt):
        loop(Chain(), Exploding(), callbacks=[recorder], n_episodes=3)
    assert recorder.events[-1] == ("loop_end", True)
    assert not any(e[0] == "episode_end" for e in recorder.events)


def test_chain_interpreter_applies_in_order():
    add_one = Interpreter(state_fn=lambda s: s + 1, reward_fn=lambda r: r * 10)
    double = Interpreter(state_fn=lambda s: s * 2)
    assert ChainInterpreter(add_one, double)(3, 0.5) == (8, 5.0)
    assert ChainInterpreter(double, add_one)(3, 0.5) == (7, 5.0)
    seen = []

    class Spy(Mind):
        def plan(self, state, train_mode=True, debug_mode=False):
            seen.append(state)
            return np.array([0.0, 1.0])

    loop(Chain(3), Spy(), interpreter=ChainInterpreter(add_one, double))
    assert seen == [2, 4]  # (0 + 1) * 2, (1 + 1) * 2


def test_callback_list_merges_metrics():
    class A(Callback):
        metrics = {"a": 1, "shared": "a"}

    class B(Callback):
        metrics = {"b": 2, "shared": "b"}

    assert CallbackList([A(), B()]).metrics == {"a": 1, "b": 2, "shared": "b"}


def frequencies(policy, scores, n=20_000, step=0, seed=0):
    rng = np.random.default_rng(seed)
    actions = [policy(np.asarray(scores), step, rng) for _ in range(n)]
    return np.bincount(actions, minlength=len(scores)) / n


def test_stochastic_policy_matches_softmax_with_temperature():
    scores = np.array([1.0, 2.0, 0.0])
    for temperature in (0.5, 2.0):
        expected = np.exp(scores / temperature) / np.exp(scores / temperature).sum()
        assert np.allclose(frequencies(Stochastic(temperature), scores), expected, atol=0.015)
    with pytest.raises(ValueError):
        Stochastic(0.0)


def test_proportional_policy_samples_visit_counts_then_turns_greedy():
    scores = [10, 30, 60]
    assert np.allclose(frequencies(Proportional(warmup=12), scores, step=11), [0.1, 0.3, 0.6], atol=0.015)
    assert np.array_equal(frequencies(Proportional(warmup=12), scores, n=200, step=12), [0, 0, 1])
    assert np.allclose(frequencies(Proportional(), scores, step=1000), [0.1, 0.3, 0.6], atol=0.015)
    assert np.allclose(frequencies(Proportional(), [0, 0], n=4000), [0.5, 0.5], atol=0.04)


def test_proportional_warmup_zero_is_an_error_not_a_silent_greedy_policy():
    """Original fault: warmup=0 silently became deterministic."""
    with pytest.raises(ValueError, match="warmup"):
        make_policy("proportional", warmup=0)


def test_epsilon_greedy_explores_and_decays():
    policy = EpsilonGreedy(epsilon=0.5)
    # greedy action 2 with prob 1 - eps + eps / 3
    assert np.allclose(frequencies(policy, [0, 0, 1]), [0.5 / 3, 0.5 / 3, 0.5 + 0.5 / 3], atol=0.015)
    decaying = EpsilonGreedy(epsilon=1.0, decay=0.5, min_epsilon=0.1)
    rng = np.random.default_rng(0)
    for _ in range(3):
        decaying(np.zeros(2), 0, rng)
    assert decaying.epsilon == pytest.approx(0.125)
    for _ in range(3):
        decaying(np.zeros(2), 0, rng)
    assert decaying.epsilon == pytest.approx(0.1)


def test_seeded_loops_repeat_and_different_seeds_differ():
    def run(seed):
        recorder = Recorder()
        loop(Chain(6), RandomMind(2, seed=seed), max_steps=30, policy="stochastic", seed=seed, callbacks=[recorder])
        return [e[2].action for e in recorder.events if e[0] == "step"]

    assert run(1) == run(1)
    assert run(1) != run(2)


def random_chain():
    import torch

    return RandomMind(2, seed=int(torch.randint(0, 2**31, ()).item()))  # seeded by pool through torch


def test_pool_returns_histories_in_job_order_independent_of_workers():
    serial = pool(lambda: Chain(8), random_chain, 4, workers=1, seed=3, max_steps=40)
    parallel = pool(lambda: Chain(8), random_chain, 4, workers=2, seed=3, max_steps=40)
    assert serial == parallel
    assert len(serial) == 4 and all(len(h) == 1 for h in serial)
    assert len({h[0]["steps"] for h in serial}) > 1  # jobs are seeded differently
    assert pool(lambda: Chain(8), random_chain, 4, workers=2, seed=4, max_steps=40) != serial


def test_mdp_protocol_is_checkable():
    class Line:
        action_space = gym.spaces.Discrete(2)

        def transition(self, state, action):
            return state + 1, 0.0

        def is_terminal(self, state):
            return state > 3

    assert isinstance(Line(), MDP)
    assert not isinstance(object(), MDP)


def test_constant_mind_picks_its_action_every_step_and_refuses_one_outside_the_set():
    from wmthesis.core import ConstantMind, Deterministic

    mind = ConstantMind(3, 1)
    assert [Deterministic()(mind.plan(state), step, None) for step, state in enumerate(range(5))] == [1] * 5
    with pytest.raises(ValueError, match=r"action must be in \[0, 3\), got 3"):
        ConstantMind(3, 3)


def test_a_process_pool_of_one_worker_runs_one_process_and_none_is_refused():
    import os

    from wmthesis.utils import parallel_calls, process_pool

    with process_pool(1) as executor:  # `validate --workers 1`: one process, not the default two
        pids = parallel_calls([(os.getpid,) for _ in range(3)], progress=False, executor=executor)
    assert len(set(pids)) == 1 and pids[0] != os.getpid()
    with pytest.raises(ValueError, match="workers must be >= 1"):
        process_pool(0)
