"""What the behaviour gate (``tests/test_same_numbers.py``) measures, and the script that records it.

Two parts, both on seed 0 with one torch thread:

- ``runs``: every default and every kept variant in the ``smoke`` profile, through ``reproduce``:
  the metrics that a wrong recipe changes (scores, curves, tables), wall times left out;
- ``signals``: numbers that a wrong implementation changes where smoke's tiny runs carry no
  signal (their AlphaZero heads score 0 everywhere, their Sokoban search solves nothing): the
  shipped AlphaZero agent's root visits and Q on a fixed real Boxing state, a toy tree's, the
  shipped Sokoban agent's and the true rules' solutions of small levels (a push rule off by one
  changes them), the shipped World Models agent's controller scores and memory step on real frames.

    python tests/same_numbers.py        # records tests/golden/smoke-seed0.json on this checkout
"""
from __future__ import annotations

import importlib.metadata
import json
import os
import subprocess
from pathlib import Path

import numpy as np

GOLDEN = Path(__file__).parent / "golden" / "smoke-seed0.json"
VERSIONS = ("ale-py", "cma", "gymnasium", "h5py", "numpy", "scipy", "torch")
RUNS = ("boxing-wm:None", "boxing-wm:population-16", "boxing-wm-alphazero:None", "boxing-wm-alphazero:imitation",
        "planet-boxing:None", "planet-boxing:unchanged", "planet-boxing-agent:None", "planet-boxing-study:None",
        "planet-boxing-search:None", "planet-boxing-value:None", "planet-boxing-value:lean",
        "planet-boxing-value:scored-rounds", "planet-freeway:None", "planet-freeway-value:None", "planet-sokoban:None",
        "sokoban-search:None", "sokoban-wm:None", "planning-budget:None", "boxing-wm-dream:None")
KEPT = ("score", "value", "value_planner", "agent", "random", "summary", "open_loop", "scores", "controller_curve",
        "curve", "tables", "boxoban", "budgets", "rows")
SHIPPED = Path(__file__).resolve().parents[1] / "data"
LEVELS = ("#######\n#@ $ .#\n#######",
          "######\n#    #\n# $$ #\n#.@ .#\n######",
          "##########\n#   #    #\n# $   .  #\n#  ## $  #\n# @   .  #\n##########")


def measured(value):
    """``value`` without wall times (and times per action) and the references' wording, as JSON holds it."""
    if isinstance(value, dict):
        return {k: measured(v) for k, v in value.items()
                if "seconds" not in k and "wall" not in k and "ms_per" not in k and k != "reference"}
    if isinstance(value, list):
        return [measured(v) for v in value]
    return value


def run_numbers(run: str) -> dict:
    """The measured metrics of one ``experiment:variant`` in smoke on seed 0."""
    from wmthesis.experiments import reproduce

    name, variant = run.split(":")
    metrics = reproduce(name, "smoke", 0, None if variant == "None" else variant, progress=False)
    return measured(json.loads(json.dumps({k: metrics[k] for k in KEPT if k in metrics}, default=str)))


def signals() -> dict:
    """The numbers of the module docstring's second part, from the agents the repository ships."""
    import torch

    import wmthesis
    from wmthesis.alphazero.mcts import MCTS
    from wmthesis.sokoban_search.search import Simulator, best_first
    from wmthesis.envs.levels import parse_level

    before = os.environ.get("WMTHESIS_DATA")
    os.environ["WMTHESIS_DATA"] = str(SHIPPED)
    try:
        out = {}
        alphazero = wmthesis.load("boxing-wm-alphazero")
        env = alphazero.env()
        frame, _ = env.reset(seed=5)
        for action in (0, 1, 2, 3, 4, 1, 1, 1):
            frame = env.step(action)[0]
        env.close()
        mind = alphazero.mind()
        mind.on_episode_start(0, False)
        scores, info = mind.plan(frame, train_mode=False, debug_mode=True)
        out["mcts_shipped"] = {"scores": np.round(scores, 6).tolist(),
                               "q": np.nan_to_num(info["q"], nan=-99.0).round(6).tolist(),
                               "root_value": round(float(info["root_value"]), 6)}
        tree = MCTS(ToyTree(), lambda state: (np.array([0.2, 0.3, 0.5]), 0.0), n_simulations=40, seed=0)
        counts, info = tree.plan((), train_mode=True, debug_mode=True)
        out["mcts_toy"] = {"visits": counts.tolist(), "q": np.nan_to_num(info["q"], nan=-99.0).round(9).tolist()}

        sokoban = wmthesis.load("sokoban-search")
        out["sokoban_shipped"] = [{k: sokoban.solve(level)[k] for k in ("solved", "actions")} for level in LEVELS]
        rules = []
        for level in LEVELS:
            board = parse_level(level)[1:-1, 1:-1]
            result = best_first(Simulator().expand, board, budget=5000)
            rules.append({"actions": None if result.actions is None else [int(a) for a in result.actions],
                          "expanded": int(result.expanded)})
        out["sokoban_rules"] = rules

        world_models = wmthesis.load("boxing-wm")
        env = world_models.env()
        frame, _ = env.reset(seed=1)
        frames = [frame] + [env.step(a)[0] for a in (1, 2, 3)]
        env.close()
        z = world_models.vision(np.stack(frames))
        with torch.no_grad():
            step = world_models.memory.step(z[:1], torch.tensor([1]), world_models.memory.initial_state(1))
            scores = world_models.controller(z[1:2], step.hidden)
        out["world_models_shipped"] = {"z": z[:, :4].numpy().round(5).tolist(),
                                       "scores": scores[0].numpy().round(5).tolist()}
        return out
    finally:
        if before is None:
            os.environ.pop("WMTHESIS_DATA", None)
        else:
            os.environ["WMTHESIS_DATA"] = before


class ToyTree:
    """A depth-3 tree over 3 actions: a reward of 0.1 for action 0 at the root, 1 behind (2, 0, 1)."""

    def __init__(self):
        import gymnasium as gym

        self.action_space = gym.spaces.Discrete(3)

    def transition(self, state, action):
        following = state + (action,)
        return following, 0.1 if following == (0,) else 1.0 if following == (2, 0, 1) else 0.0

    def is_terminal(self, state):
        return len(state) == 3


def versions() -> dict:
    return {p: importlib.metadata.version(p) for p in VERSIONS}


def record(path: Path = GOLDEN, only: tuple[str, ...] = ()) -> None:
    """Measure everything in a temporary data folder and write it to ``path``; ``only``: measure
    those runs again (a behaviour changed on purpose, or a run added), keeping the rest as recorded."""
    import tempfile

    import torch

    torch.set_num_threads(1)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    kept = json.loads(path.read_text()) if only else None
    with tempfile.TemporaryDirectory() as folder:
        os.environ["WMTHESIS_DATA"] = folder
        if only:
            numbers = {**kept, "runs": {run: run_numbers(run) if run in only else kept["runs"][run] for run in RUNS}}
            numbers["remeasured"] = {**kept.get("remeasured", {}), **{run: commit for run in only}}
        else:
            numbers = {"commit": commit, "versions": versions(), "runs": {run: run_numbers(run) for run in RUNS},
                       "signals": signals()}
    path.write_text(json.dumps(numbers, indent=1) + "\n")


if __name__ == "__main__":
    import sys

    record(only=tuple(sys.argv[1:]))  # python tests/same_numbers.py [RUN ...]
