"""One Boxing action of a planning agent on one CPU thread, at each search budget.

    python benchmarks/bench_boxing_action.py [--steps 300] [--budgets 0 2 4 8 16 64 256] [--agent PATH] [--out PATH]

Plays the shipped World Models + AlphaZero agent (``data/quick/boxing-wm-alphazero/seed0/
agent-own-memory.pt``, the default's, or ``--agent``) greedily in real Boxing for the first ``--steps`` steps of
one bout per budget, torch on one thread, and reports the wall milliseconds per action: the
frame's encoding, the search (budget 0: the policy head alone, no search) and the game's step
together, as a user playing the agent waits for them, with the budget curve's root
(``BudgetCurveConfig.mcts_search``). The same no-op start for every budget. The target: at most
50 ms an action at the budget to recommend, :data:`RECOMMENDED` (the best on the validation bouts,
``docs/findings/planning-budget.md``). Writes ``benchmarks/results/boxing_action.json``.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[1])]  # _results, wmthesis

from _results import machine_meta, print_table, write_results  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = Path(__file__).resolve().parent / "results" / "boxing_action.json"
AGENT = ROOT / "data" / "quick" / "boxing-wm-alphazero" / "seed0" / "agent-own-memory.pt"
RECOMMENDED = 64  # simulations: the budget to recommend (the curve's root's best on validation bouts)
TARGET_MS = 50.0


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--budgets", type=int, nargs="+", default=[0, 2, 4, 8, 16, 64, 256])
    parser.add_argument("--agent", type=Path, default=AGENT)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.steps < 1 or min(args.budgets) < 0:
        parser.error("--steps must be at least 1 and every budget at least 0")

    import torch

    from wmthesis.alphazero.agent import load_agent
    from wmthesis.alphazero.config import search_settings
    from wmthesis.alphazero.evaluation import evaluation_seeds
    from wmthesis.alphazero.imitation import PolicyHeadMind
    from wmthesis.alphazero.replay import game_seeds
    from wmthesis.core import loop
    from wmthesis.envs.atari import boxing_env

    torch.set_num_threads(1)
    agent = load_agent(args.agent)
    env_seed, search_seed = game_seeds(evaluation_seeds(0, 1, agent.config.noop_max)[0])
    env, rows = boxing_env(agent.config.noop_max), []
    try:
        warm = PolicyHeadMind(agent.vision, agent.mdp, agent.heads)  # the first frames pay for lazy setup: untimed
        loop(env, warm, policy="deterministic", callbacks=[warm], max_steps=20, seed=env_seed, train_mode=False)
        for budget in args.budgets:
            if budget == 0:
                mind = PolicyHeadMind(agent.vision, agent.mdp, agent.heads)
            else:
                mind = agent.mind(simulations=budget, **search_settings("quick"))
                mind.new_search(search_seed)
            start = time.perf_counter()
            history = loop(env, mind, policy="deterministic", callbacks=[mind], max_steps=args.steps, seed=env_seed,
                           train_mode=False)
            steps = int(history[0]["steps"])
            ms = 1000 * (time.perf_counter() - start) / steps
            rows.append({"planner": "mcts", "budget": budget, "steps": steps, "ms_per_action": ms,
                         "target_ms": TARGET_MS if budget == RECOMMENDED else None,
                         "met": (ms <= TARGET_MS) if budget == RECOMMENDED else None})
    finally:
        env.close()
    print_table(rows)
    write_results(args.out, machine_meta(steps=args.steps, torch_threads=1, agent=str(args.agent.relative_to(ROOT))
                                         if args.agent.is_relative_to(ROOT) else str(args.agent)), rows)


if __name__ == "__main__":
    main()
