"""A trained PlaNet agent in one file, to ship and to play: the RSSM (its observation decoder left
behind: planning never decodes), the learned value and the planner that ends in it where the agent
has one, the game, the bouts its score was measured on, the configs and the commit, with a format
version. A value's agent keeps its value in half precision (as its scored bouts played it) and, in
place of the RSSM, names the PlaNet agent's file it plans with (beside it where both ship).

    save_agent(path, game, planet_run, bouts, commit, value_run=work, planner=planner)
    agent = load_agent(path)
    rewards = play_agent(agent, *agent.info["bouts"][0])   # one bout, its rewards
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import torch

from wmthesis.planet.config import ValuePlannerConfig
from wmthesis.planet.own_rewards import planner_model
from wmthesis.planet.shipped import (AGENT_NAME, DECODER, FORMAT, FORMAT_VERSION, Agent, NoDecoder,  # noqa: F401
                                     load_agent, play_agent, sha256)
from wmthesis.runs import save_agent_file


def save_agent(path: str | os.PathLike, game: str, planet_run: Path, bouts: list, commit: str | None,
               value_run: Path | None = None, planner: ValuePlannerConfig | None = None) -> Path:
    """Write the agent of the PlaNet run in ``planet_run`` (with the chosen value of the value run
    in ``value_run`` and CEM ``planner`` ending in it, where given) for ``game`` to ``path``,
    atomically, with the ``bouts`` ((env seed, mind seed) pairs) it was scored on; returns the path.
    A value's agent names the PlaNet run's own agent file (its SHA-256 checked when read) and keeps
    only the model's weights that differ from it (a refit reward head), the value in half precision."""
    path = Path(path)
    model, planet, value = planner_model(planet_run, value_run, planner)  # with the reward head it plans with
    state = {k: v for k, v in model.state_dict().items() if not k.startswith(DECODER)}
    base = Path(planet_run) / AGENT_NAME
    shared = {} if value is None or not base.is_file() else load_agent(base).model.state_dict()
    return save_agent_file(
        path, FORMAT, FORMAT_VERSION, game=game, n_actions=model.n_actions, planet=dataclasses.asdict(planet),
        bouts=[list(map(int, b)) for b in bouts], commit=commit,
        model={k: v for k, v in state.items() if k not in shared or not torch.equal(v, shared[k])},
        model_file=None if not shared else {"path": os.path.relpath(base, path.parent), "sha256": sha256(base)},
        value=None if value is None else {"state": {k: v.half() for k, v in value.state_dict().items()},
                                          "hidden": value.heads[0][0].out_features, "heads": len(value.heads),
                                          "log": value.log},
        planner=None if planner is None else dataclasses.asdict(planner))


__all__ = ["Agent", "AGENT_NAME", "FORMAT", "FORMAT_VERSION", "save_agent", "sha256", "load_agent", "play_agent"]
