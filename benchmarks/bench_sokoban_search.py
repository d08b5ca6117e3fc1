"""Search in a learned Sokoban model: model transitions per second (batched) and search nodes per second.

    python benchmarks/bench_sokoban_search.py [--levels 20] [--budget 2000] [--seed 0] [--out PATH]

Rows:

- ``model expand``: :meth:`SokobanModel.expand` (every action's outcome at once) on batches of
  1, 16, 64 and 256 random boards of the ``sokoban`` (8x8 inner cells) and ``sokoban-small``
  (5x5) sizes, at the default model size (64 channels, 2 blocks, randomly initialised: speed
  does not depend on the weights). ``transitions/s`` counts board x action pairs.
- ``model expand, seen changes``: the same with the count changes of random play on 20
  ``sokoban-small`` levels seen (:meth:`SokobanModel.see_changes`), so that every prediction
  is also checked against them, as in a trained model.
- ``search``: breadth-first :func:`best_first` from ``--levels`` generated levels of each
  variant with the learned-model interface (the random model above, its end logits pinned
  negative and its skip connection off: the search never finds an end and its children are new
  states, so every search expands its whole ``--budget``), the same with a policy prior
  (:class:`Policy`, 32 channels x 2 blocks, weight 1: one more network call per batch), the
  same keeping its graph and backing up its values as the training rounds do (:func:`backed_up`,
  timed with the search), and with the true rules (:class:`Simulator`, which stops when it solves the level): nodes expanded per
  second, batch 64.

- ``pixel coding``: random play's boards of 150 ``sokoban`` levels turned into the pixel agent's
  codes (:meth:`PixelInputs.from_grid`: rendered, then coded), as the pixel run's random stage
  does with all of its boards: boards per second and the peak of memory numpy allocates
  (``tracemalloc``). Coding all boards at once took 110 kB a board, 12 GB for a quick run's
  random play; now a constant of about 0.45 GB.

With ``--agent FOLDER`` (a trained pixel run, e.g. ``data/quick/sokoban-search/seed0/pixels``, with
its ``--profile``'s evaluation search, ``eval_budget`` included), also ``trained agent``: that agent on the first
``--agent-levels`` levels of each Boxoban validation set (unfiltered and medium valid 000-001,
never the report files), on one thread, as the issue measures it ("seconds per level on one
core"): levels solved, search nodes and seconds per level. Run it on a quiet machine.

The model runs in bfloat16 where the CPU computes it natively (:func:`wmthesis.utils.half_precision`),
as in the experiment; the JSON records which. Runs on torch's default threads (the machine's cores). Writes ``benchmarks/results/sokoban_search.json`` (a machine with bfloat16);
``sokoban_search_float32.json`` is a run on a 2-core AMD EPYC without it (AVX2), with ``--agent``
on seed 0's quick pixel run (the curriculum, since 2026-11-25), everything else paused.
"""
from __future__ import annotations

import argparse
import copy
import sys
import time
from contextlib import nullcontext
from pathlib import Path

import numpy as np
import torch

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[1])]  # _results, wmthesis

from wmthesis.sokoban_search.agent import grid_env, grid_state, level_seeds, random_play  # noqa: E402
from wmthesis.sokoban_search.heuristic import backed_up  # noqa: E402
from wmthesis.sokoban_search.model import SokobanModel  # noqa: E402
from wmthesis.sokoban_search.policy import Policy  # noqa: E402
from wmthesis.sokoban_search.search import Simulator, best_first  # noqa: E402
from wmthesis.utils import device, half_precision  # noqa: E402
from _results import machine_meta, print_table, write_results  # noqa: E402

SIZES = {"sokoban": (8, 8), "sokoban-small": (5, 5)}
REWARDS = (-1.1, -0.1, 0.9, 10.9)


def expand_rows(model: SokobanModel, rng: np.random.Generator, name: str = "model expand") -> list[dict]:
    rows = []
    for variant, shape in SIZES.items():
        for batch in (1, 16, 64, 256):
            states = rng.integers(0, 7, size=(batch, *shape)).astype(np.uint8)
            model.expand(states)
            calls, start = 0, time.perf_counter()
            while time.perf_counter() - start < 1.0:
                model.expand(states)
                calls += 1
            seconds = (time.perf_counter() - start) / calls
            rows.append(dict(row=name, variant=variant, batch=batch, ms_per_call=1e3 * seconds,
                             transitions_per_s=batch * model.n_actions / seconds))
    return rows


def search_rows(model: SokobanModel, levels: int, budget: int, seed: int) -> list[dict]:
    rows = []
    prior = Policy(7, 8).log_probs  # the policy prior's size in the experiment (the value's: 32 x 2)
    searches = {"learned model": (model.expand, {}), "learned model, policy prior": (model.expand, dict(prior=prior, prior_weight=1.0)),
                "learned model, graph backed up": (model.expand, dict(graph=True)),
                "true rules": (Simulator().expand, {})}
    for variant in SIZES:
        env = grid_env(variant)
        roots = [grid_state(env, env.reset(seed=s)[0]) for s in level_seeds(seed, 5_000, levels)]
        for name, (expand, options) in searches.items():
            expanded, seconds = 0, 0.0
            for root in roots:
                result = best_first(expand, root, budget=budget, batch=64, **options)
                start = time.perf_counter()
                if "graph" in result.info:  # the rounds' labels from the search's graph
                    backed_up(result.info["graph"], cap=120.0)
                expanded = expanded + result.expanded
                seconds = seconds + result.seconds + time.perf_counter() - start
            rows.append(dict(row=f"search, {name}", variant=variant, levels=levels,
                             nodes_per_level=expanded / levels, nodes_per_s=expanded / seconds))
    return rows


def coding_rows(seed: int) -> list[dict]:
    import tracemalloc

    from wmthesis.sokoban_search.cells import PixelInputs, fit_coder, render_cells

    states = random_play("sokoban", seed, 150)["states"]
    inputs = PixelInputs(fit_coder(render_cells(states[::20]), seed=seed))
    tracemalloc.start()
    start = time.perf_counter()
    inputs.from_grid(states)
    seconds, (_, peak) = time.perf_counter() - start, tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return [dict(row="pixel coding", variant="sokoban", boards=len(states), boards_per_s=len(states) / seconds,
                 peak_mb=peak / 2 ** 20)]


def agent_rows(folder: str, profile: str, levels: int) -> list[dict]:
    from wmthesis.sokoban_search.config import SokobanSearchConfig
    from wmthesis.config import for_profile
    from wmthesis.envs.boxoban import load_levels
    from wmthesis.envs.boxoban import BOXOBAN_SPLITS
    from wmthesis.sokoban_search.evaluation import solve_boards
    from wmthesis.sokoban_search.iteration import evaluation_search, load_run

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    run = load_run(folder)
    agent = run.agent(evaluation_search(for_profile(SokobanSearchConfig, profile)))  # the evaluation's search settings
    rows = []
    for kind, source in BOXOBAN_SPLITS["validation"].items():
        plays = solve_boards(agent, load_levels(source)[:levels], progress=False)
        rows.append(dict(row="trained agent, one thread", variant=f"boxoban {kind} valid", levels=levels,
                         solved=sum(p["solved"] for p in plays),
                         nodes_per_level=float(np.mean([p["expanded"] for p in plays])),
                         seconds_per_level=float(np.mean([p["seconds"] for p in plays]))))
    torch.set_num_threads(threads)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", type=int, default=20)
    parser.add_argument("--budget", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--agent", help="a trained run's folder: also time that agent on Boxoban validation levels")
    parser.add_argument("--agent-levels", type=int, default=10)
    parser.add_argument("--profile", default="quick", help="the search settings of --agent's run")
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent / "results" / "sokoban_search.json"))
    args = parser.parse_args(argv)
    torch.manual_seed(args.seed)
    model = SokobanModel(7, 8, REWARDS)
    with torch.no_grad():  # a random model that never predicts an end and whose children differ,
        model.event_head[-1].bias.view(model.n_actions, -1)[:, -1] = -1e4  # so that a search
        model.copy.zero_()                                                 # runs its whole budget
    checking = copy.deepcopy(model)
    played = random_play("sokoban-small", args.seed, 20)
    checking.see_changes(played["states"], played["next_states"])
    rows = (expand_rows(model, np.random.default_rng(args.seed))
            + expand_rows(checking, np.random.default_rng(args.seed), "model expand, seen changes")
            + search_rows(model, args.levels, args.budget, args.seed)
            + coding_rows(args.seed)
            + (agent_rows(args.agent, args.profile, args.agent_levels) if args.agent else []))
    print_table(rows)
    precision = "float32" if isinstance(half_precision(device()), nullcontext) else "bfloat16"
    print(f"model precision: {precision} (wmthesis.utils.half_precision)")
    write_results(args.out, machine_meta(threads=torch.get_num_threads(), levels=args.levels, budget=args.budget,
                                         precision=precision), rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
