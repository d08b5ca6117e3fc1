"""AlphaZero MCTS: simulations per second and time per move with the thesis's latent model.

    python benchmarks/bench_mcts.py [--moves 200] [--simulations 50] [--rounds 3] [--seed 0] [--out PATH]

The model is a randomly initialised deterministic memory of the thesis sizes (4.3.1): an
``nn.LSTMCell(16 + 18, 256)`` over [z, one-hot action] with linear next-latent (16) and reward
(1) heads, wrapped as an :class:`~wmthesis.core.MDP` whose state is ``(z, h, c)``; the
evaluator is linear policy (18, softmax) and value heads on [z h]. One expansion = one
LSTMCell step at batch 1 + the heads. torch runs on 1 thread under ``torch.inference_mode()``.

Each row plays ``--moves`` moves of ``--simulations``-simulation searches: plan, take the most
visited action, ``advance`` the tree, step the model (untimed) to get the next "real" state.
Rows:

- ``thesis model``: train mode (root Dirichlet noise) with tree reuse, the self-play setting;
  test mode without reuse; with normalised Q. ``model`` is the share of plan time spent in
  ``transition``/``is_terminal``/the evaluator, ``tree`` the rest (select, backup, noise,
  bookkeeping). Target: >= 1,000 simulations/s.
- ``null model``: a model that costs nothing (constant priors, no tensors): the tree's own
  overhead per simulation.
- ``model alone``: one transition + one evaluation per call, no tree: the ceiling.

``cpu us`` is this process's CPU time per simulation (one torch thread, so about one core):
``1e6 / cpu us`` is the rate on a free core, a figure that other work on a shared machine
changes far less than the wall-clock ``sims/s``. Rows take turns over ``--rounds`` rounds and
each keeps its median round, so a load that changes during the run slows them alike.

Also a micro-benchmark of one PUCT selection over 18 edges: the numpy expression the planner
uses against the same formula as a pure-Python loop. Writes ``benchmarks/results/mcts.json``.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time
import timeit
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from torch import nn

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[1])]  # _results, wmthesis

from wmthesis.alphazero.mcts import MCTS  # noqa: E402
from _results import machine_meta, print_table, write_results  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "mcts.json"
LATENT, HIDDEN, N_ACTIONS = 16, 256, 18


class LatentMDP:
    """Deterministic memory (thesis 4.3.1): h' = LSTMCell([z, a], h); z' = W_z h'; r = w_r h'.

    State: ``(z (1, 16), h (1, 256), c (1, 256))``. Never terminal.
    """

    def __init__(self, latent=LATENT, hidden=HIDDEN, n_actions=N_ACTIONS):
        self.cell = nn.LSTMCell(latent + n_actions, hidden)
        self.next_latent, self.reward = nn.Linear(hidden, latent), nn.Linear(hidden, 1)
        self.one_hot = torch.eye(n_actions).unsqueeze(1)  # (A, 1, A)
        self.action_space = gym.spaces.Discrete(n_actions)

    def transition(self, state, action):
        z, h, c = state
        h, c = self.cell(torch.cat([z, self.one_hot[action]], 1), (h, c))
        return (self.next_latent(h), h, c), float(self.reward(h))

    def is_terminal(self, state):
        return False


class LinearEvaluator:
    """Policy (softmax over 18) and value heads, both linear on [z h] (thesis 4.3.3)."""

    def __init__(self, latent=LATENT, hidden=HIDDEN, n_actions=N_ACTIONS):
        self.policy, self.value = nn.Linear(latent + hidden, n_actions), nn.Linear(latent + hidden, 1)

    def __call__(self, state):
        z, h, _ = state
        features = torch.cat([z, h], 1)
        return torch.softmax(self.policy(features), 1)[0].numpy(), float(self.value(features))


class NullMDP:
    """A model that costs nothing: the state counts steps, no reward, never terminal."""

    action_space = gym.spaces.Discrete(N_ACTIONS)

    def transition(self, state, action):
        return state + 1, 0.0

    def is_terminal(self, state):
        return False


UNIFORM = np.full(N_ACTIONS, 1 / N_ACTIONS)


def null_evaluator(state):
    return UNIFORM, 0.0


class Timed:
    """Wraps an MDP and an evaluator and adds up the seconds spent in them."""

    def __init__(self, mdp, evaluator):
        self.mdp, self.inner_evaluator, self.seconds = mdp, evaluator, 0.0
        self.action_space = mdp.action_space

    def transition(self, state, action):
        start = time.perf_counter()
        result = self.mdp.transition(state, action)
        self.seconds += time.perf_counter() - start
        return result

    def is_terminal(self, state):
        start = time.perf_counter()
        result = self.mdp.is_terminal(state)
        self.seconds += time.perf_counter() - start
        return result

    def evaluator(self, state):
        start = time.perf_counter()
        result = self.inner_evaluator(state)
        self.seconds += time.perf_counter() - start
        return result


def play_row(label: str, mdp, evaluator, start_state, moves: int, simulations: int, seed: int,
             train_mode=True, **options) -> dict:
    """Play ``moves`` moves; simulations/s, ms per move and the model's share of plan time."""
    timed = Timed(mdp, evaluator)
    mcts = MCTS(timed, timed.evaluator, n_simulations=simulations, seed=seed, **options)
    state, plan_seconds, cpu_seconds, total_simulations, depths = start_state, 0.0, 0.0, 0, []
    for move in range(moves + 1):
        if move == 1:  # the first move is a warm-up
            timed.seconds, plan_seconds, cpu_seconds, total_simulations, depths = 0.0, 0.0, 0.0, 0, []
        start, cpu_start = time.perf_counter(), time.process_time()
        counts, info = mcts.plan(state, train_mode=train_mode, debug_mode=True)
        plan_seconds += time.perf_counter() - start
        cpu_seconds += time.process_time() - cpu_start
        total_simulations += info["simulations"]
        depths.append(info["max_depth"])
        action = int(np.argmax(counts))
        mcts.advance(action)
        state, _ = mdp.transition(state, action)
    model_share = timed.seconds / plan_seconds
    return dict(what=label, simulations_per_s=total_simulations / plan_seconds,
                ms_per_move=1e3 * plan_seconds / moves,
                us_per_simulation=1e6 * plan_seconds / total_simulations,
                cpu_us_per_simulation=1e6 * cpu_seconds / total_simulations,
                share_model=model_share, share_tree=1 - model_share, mean_max_depth=float(np.mean(depths)),
                moves=moves, simulations=simulations, load_average_1min=os.getloadavg()[0])


def model_alone_row(mdp, evaluator, start_state, calls: int) -> dict:
    """One transition + one evaluation per call, no tree: the ceiling on simulations/s."""
    state, start, cpu_start = start_state, time.perf_counter(), time.process_time()
    for call in range(calls):
        state, _ = mdp.transition(state, call % N_ACTIONS)
        evaluator(state)
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
    return dict(what="model alone: transition + evaluator", simulations_per_s=calls / seconds,
                us_per_simulation=1e6 * seconds / calls, cpu_us_per_simulation=1e6 * cpu_seconds / calls,
                share_model=1.0, share_tree=0.0)


def median_row(results: list[dict]) -> dict:
    """The round with the median simulations/s, and how many rounds there were."""
    ranked = sorted(results, key=lambda row: row["simulations_per_s"])
    return {**ranked[len(ranked) // 2], "rounds": len(results)}


def select_rows(repeats: int = 20_000) -> list[dict]:
    """One PUCT selection over 18 edges: the planner's numpy expression vs pure Python."""
    rng = np.random.default_rng(0)
    P, Q = rng.dirichlet(np.ones(N_ACTIONS)), rng.random(N_ACTIONS)
    N = rng.integers(0, 5, N_ACTIONS).astype(float)
    c, visits = 1.0, int(N.sum())
    lists = (P.tolist(), N.tolist(), Q.tolist())

    def numpy_select():
        return int((Q + (c * math.sqrt(max(visits, 1))) * P / (1.0 + N)).argmax())

    def python_select():
        s = c * math.sqrt(max(visits, 1))
        scores = [q + s * p / (1.0 + n) for p, n, q in zip(*lists)]
        return scores.index(max(scores))

    assert numpy_select() == python_select()
    rows = []
    for name, fn in (("select one node (numpy, as planned)", numpy_select),
                     ("select one node (pure Python)", python_select)):
        seconds = min(timeit.repeat(fn, number=repeats, repeat=5)) / repeats
        rows.append(dict(what=name, us_per_select=1e6 * seconds))
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--moves", type=int, default=200, help="timed moves per row (after one warm-up)")
    parser.add_argument("--simulations", type=int, default=50)
    parser.add_argument("--rounds", type=int, default=3, help="rows take turns; the median round is kept")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    torch.manual_seed(args.seed)
    load_before = os.getloadavg()
    mdp, evaluator = LatentMDP(), LinearEvaluator()
    start = (torch.randn(1, LATENT), torch.zeros(1, HIDDEN), torch.zeros(1, HIDDEN))
    M, S, seed = args.moves, args.simulations, args.seed
    benchmarks = [
        lambda: play_row("thesis model: train, noise, reuse", mdp, evaluator, start, M, S, seed),
        lambda: play_row("thesis model: test, no reuse", mdp, evaluator, start, M, S, seed,
                         train_mode=False, reuse_tree=False),
        lambda: play_row("thesis model: train, reuse, normalize_q", mdp, evaluator, start, M, S, seed,
                         normalize_q=True),
        lambda: play_row("null model: tree only", NullMDP(), null_evaluator, 0, M, S, seed),
        lambda: model_alone_row(mdp, evaluator, start, M * S)]
    rounds: list[list[dict]] = [[] for _ in benchmarks]
    with torch.inference_mode():
        for _ in range(args.rounds):  # rows take turns, so a changing load slows them alike
            for results, benchmark in zip(rounds, benchmarks):
                results.append(benchmark())
    rows = [median_row(results) for results in rounds] + select_rows()

    print(f"AlphaZero MCTS, {S} simulations a move, {M} moves x {args.rounds} rounds, "
          f"LSTMCell({LATENT}+{N_ACTIONS}, {HIDDEN}), 1 torch thread (load before: {load_before[0]:.2f})")
    print_table(rows, ["what", "simulations_per_s", "us_per_simulation", "cpu_us_per_simulation", "ms_per_move",
                       "share_model", "share_tree", "mean_max_depth", "us_per_select"])
    meta = machine_meta(moves=M, simulations=S, rounds=args.rounds, latent=LATENT, lstm=HIDDEN,
                        n_actions=N_ACTIONS, seed=seed, threads=torch.get_num_threads(), cpus=os.cpu_count(),
                        load_average_before=load_before, load_average_after=os.getloadavg())
    write_results(args.out, meta, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
