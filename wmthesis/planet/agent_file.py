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
import hashlib
import os
from pathlib import Path
from typing import NamedTuple

import torch
from torch import nn

from wmthesis.planet.agent import play_greedy
from wmthesis.planet.config import PlaNetConfig, ValuePlannerConfig
from wmthesis.planet.rssm import RSSM
from wmthesis.planet.own_rewards import planner_model
from wmthesis.planet.train import build_model, make_planet_env
from wmthesis.planet.value import LatentValue
from wmthesis.planet.value_planner import play_value_planner
from wmthesis.runs import read_agent_file, save_agent_file
from wmthesis.training import with_added_defaults

FORMAT = "wmthesis-planet-agent"
FORMAT_VERSION = 1
AGENT_NAME = "agent.pt"
DECODER = "decoder."  # the observation model's keys in the RSSM's state: not shipped


class NoDecoder(nn.Module):
    """Where a shipped model's observation decoder was: decoding raises an error naming the file."""

    def __init__(self, path: Path):
        super().__init__()
        self.path = str(path)

    def forward(self, features):
        raise RuntimeError(f"{self.path} ships no observation decoder (planning never decodes), and no decoder.pt "
                           "lies beside it: `python tools/fit_decoders.py planet` fits one to the frozen model")


class Agent(NamedTuple):
    """A loaded agent: the ``model`` (an RSSM without its decoder's weights), its ``planet``
    config, the ``value`` and its ``planner`` (None for PlaNet's own CEM) and ``info`` (game,
    bouts, commit)."""
    model: RSSM
    planet: PlaNetConfig
    value: LatentValue | None
    planner: ValuePlannerConfig | None
    info: dict


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


def sha256(path: Path) -> str:
    """The SHA-256 of the file at ``path``, in hex."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def load_agent(path: str | os.PathLike) -> Agent:
    """The agent saved at ``path``; a missing, corrupt or foreign file raises an error naming it,
    and so does a value's agent whose PlaNet agent file is missing or has changed since."""
    path = Path(path)
    saved = read_agent_file(path, "PlaNet", FORMAT, FORMAT_VERSION)
    planet = PlaNetConfig(**with_added_defaults(PlaNetConfig, saved["planet"]))
    model = build_model(planet, saved["n_actions"])
    weights = dict(saved["model"])
    if saved.get("model_file"):  # the PlaNet agent this value was fitted on
        base = path.parent / saved["model_file"]["path"]
        if not base.is_file() or sha256(base) != saved["model_file"]["sha256"]:
            raise ValueError(f"{path} plans with the model of {base}, which is "
                             f"{'missing' if not base.is_file() else 'not the file it was fitted on (its SHA-256 differs)'}")
        weights = {**load_agent(base).model.state_dict(), **weights}
    weights = {k: v for k, v in weights.items() if not k.startswith(DECODER)}
    missing, unexpected = model.load_state_dict(weights, strict=False)
    if unexpected or any(not k.startswith(DECODER) for k in missing):
        raise ValueError(f"{path}: its model does not fit the RSSM (missing {missing}, unexpected {unexpected})")
    model.decoder = NoDecoder(path)
    value, planner = None, None
    if saved["value"] is not None:
        v = saved["value"]
        value = LatentValue(model.belief_size + model.state_size, v["hidden"], v["heads"], v["log"])
        value.load_state_dict({k: t.float() for k, t in v["state"].items()})
        value = value.to(next(model.parameters()).device).eval()
        planner = ValuePlannerConfig(**with_added_defaults(ValuePlannerConfig, saved["planner"]))
    return Agent(model.eval(), planet, value, planner, {k: saved[k] for k in ("game", "bouts", "commit")})


def play_agent(agent: Agent, env_seed: int, mind_seed: int, frames: list | None = None) -> list[float]:
    """One greedy bout of ``agent`` in its game (reset with ``env_seed``, the planner's noise from
    ``mind_seed``): its rewards, one per agent step; ``frames`` (a list) gets its frames where given."""
    env = make_planet_env(agent.info["game"], agent.planet)
    try:
        if agent.value is None:
            return play_greedy(env, agent.model, agent.planet, env_seed, mind_seed, frames)
        return play_value_planner(env, agent.model, agent.value, agent.planet, agent.planner, env_seed, mind_seed,
                                  frames)
    finally:
        env.close()


__all__ = ["Agent", "AGENT_NAME", "FORMAT", "FORMAT_VERSION", "save_agent", "sha256", "load_agent", "play_agent"]
