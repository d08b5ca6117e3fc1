"""A shipped PlaNet agent read back (thesis 4.4): the RSSM without its observation decoder, the
learned value and the planner that ends in it where the agent has one, the game, the bouts its
score was measured on, the configs and the commit (:mod:`~wmthesis.planet.agent_file` writes it).

    agent = load_agent(path)
    rewards = play_agent(agent, *agent.info["bouts"][0])   # one bout, its rewards
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

from torch import nn

from wmthesis.planet.agent import play_greedy
from wmthesis.planet.config import PlaNetConfig, ValuePlannerConfig
from wmthesis.planet.frames import make_planet_env
from wmthesis.planet.networks import build_model
from wmthesis.planet.rssm import RSSM
from wmthesis.planet.value import LatentValue
from wmthesis.planet.value_planner import play_value_planner
from wmthesis.runs import file_sha256, read_agent_file
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


def sha256(path: Path) -> str:
    """The SHA-256 of the file at ``path``, in hex."""
    return file_sha256(path)


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


__all__ = ["Agent", "AGENT_NAME", "DECODER", "FORMAT", "FORMAT_VERSION", "NoDecoder", "sha256", "load_agent",
           "play_agent"]
