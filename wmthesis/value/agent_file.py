"""A learned value's agent in one file, to ship and to play, in PlaNet's agent format: the value in
half precision (as its scored bouts played it), the CEM planner that ends in it, and, in place of
the RSSM, the PlaNet agent's file it plans with (its SHA-256 checked when read) with only the
model's weights that differ from it (a refit reward head); :mod:`~wmthesis.value.shipped` reads it back.

    save_value_agent(path, game, planet_run, bouts, commit, value_run=work, planner=planner)
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import torch

from wmthesis.planet.shipped import AGENT_NAME, DECODER, FORMAT, FORMAT_VERSION, load_agent, sha256
from wmthesis.runs import save_agent_file
from wmthesis.value.config import ValuePlannerConfig
from wmthesis.value.own_rewards import planner_model


def save_value_agent(path: str | os.PathLike, game: str, planet_run: Path, bouts: list, commit: str | None,
                     value_run: Path, planner: ValuePlannerConfig) -> Path:
    """Write the agent of ``planet_run``'s model with the chosen value of the value run in
    ``value_run`` and CEM ``planner`` ending in it, for ``game``, to ``path``, atomically, with the
    ``bouts`` ((env seed, mind seed) pairs) it was scored on; returns the path."""
    path = Path(path)
    model, planet, value = planner_model(planet_run, value_run, planner)  # with the reward head it plans with
    state = {k: v for k, v in model.state_dict().items() if not k.startswith(DECODER)}
    base = Path(planet_run) / AGENT_NAME
    shared = {} if not base.is_file() else load_agent(base).model.state_dict()
    return save_agent_file(
        path, FORMAT, FORMAT_VERSION, game=game, n_actions=model.n_actions, planet=dataclasses.asdict(planet),
        bouts=[list(map(int, b)) for b in bouts], commit=commit,
        model={k: v for k, v in state.items() if k not in shared or not torch.equal(v, shared[k])},
        model_file=None if not shared else {"path": os.path.relpath(base, path.parent), "sha256": sha256(base)},
        value={"state": {k: v.half() for k, v in value.state_dict().items()},
               "hidden": value.heads[0][0].out_features, "heads": len(value.heads), "log": value.log},
        planner=dataclasses.asdict(planner))


__all__ = ["save_value_agent"]
