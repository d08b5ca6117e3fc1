"""A shipped PlaNet agent read back (thesis 4.4): the RSSM without its observation decoder, the
game, the bouts its score was measured on, the configs and the commit
(:mod:`~wmthesis.planet.agent_file` writes it). A learned value's agent, in the same format, is
read by :mod:`wmthesis.value.shipped`.

    agent = load_agent(path)
    rewards = play_agent(agent, *agent.info["bouts"][0])   # one bout, its rewards
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

from torch import nn

from wmthesis.planet.agent import play_greedy
from wmthesis.planet.config import PlaNetConfig
from wmthesis.planet.frames import make_planet_env
from wmthesis.planet.networks import build_model
from wmthesis.planet.rssm import RSSM
from wmthesis.runs import file_sha256, read_agent_file
from wmthesis.training import with_added_defaults

FORMAT = "wmthesis-planet-agent"
FORMAT_VERSION = 1
AGENT_NAME = "agent.pt"
DECODER = "decoder."  # the observation model's keys in the RSSM's state: not shipped
INFO = ("game", "bouts", "commit")  # what a loaded agent's ``info`` holds


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
    config and ``info`` (game, bouts, commit)."""
    model: RSSM
    planet: PlaNetConfig
    info: dict


def sha256(path: Path) -> str:
    """The SHA-256 of the file at ``path``, in hex."""
    return file_sha256(path)


def read_saved(path: Path) -> dict:
    """The fields of the agent file at ``path``; a missing, corrupt or foreign file raises an
    error naming it."""
    return read_agent_file(path, "PlaNet", FORMAT, FORMAT_VERSION)


def saved_planet(saved: dict) -> PlaNetConfig:
    """The PlaNet config an agent file was trained with."""
    return PlaNetConfig(**with_added_defaults(PlaNetConfig, saved["planet"]))


def saved_model(path: Path, saved: dict, weights: dict) -> RSSM:
    """The RSSM of the agent file at ``path`` (its fields ``saved``) with ``weights`` (eval mode),
    its observation decoder a :class:`NoDecoder`; weights that do not fit raise an error naming the file."""
    model = build_model(saved_planet(saved), saved["n_actions"])
    weights = {k: v for k, v in weights.items() if not k.startswith(DECODER)}
    missing, unexpected = model.load_state_dict(weights, strict=False)
    if unexpected or any(not k.startswith(DECODER) for k in missing):
        raise ValueError(f"{path}: its model does not fit the RSSM (missing {missing}, unexpected {unexpected})")
    model.decoder = NoDecoder(path)
    return model.eval()


def load_agent(path: str | os.PathLike) -> Agent:
    """The PlaNet agent saved at ``path``; a missing, corrupt or foreign file raises an error
    naming it, and so does a learned value's agent (:func:`wmthesis.value.shipped.load_value_agent` reads it)."""
    path = Path(path)
    saved = read_saved(path)
    if saved.get("value") is not None or saved.get("model_file"):
        raise ValueError(f"{path} is a learned value's agent: wmthesis.value.shipped.load_value_agent reads it "
                         "(or wmthesis.load)")
    return Agent(saved_model(path, saved, dict(saved["model"])), saved_planet(saved), {k: saved[k] for k in INFO})


def play_agent(agent: Agent, env_seed: int, mind_seed: int, frames: list | None = None) -> list[float]:
    """One greedy bout of ``agent`` in its game (reset with ``env_seed``, the planner's noise from
    ``mind_seed``): its rewards, one per agent step; ``frames`` (a list) gets its frames where given."""
    return in_its_game(agent, lambda env: play_greedy(env, agent.model, agent.planet, env_seed, mind_seed, frames))


def in_its_game(agent, play):
    """``play(env)`` in a fresh environment of ``agent``'s game and frames (its ``info["game"]``,
    its ``planet`` config), closed afterwards: what ``play`` returns."""
    env = make_planet_env(agent.info["game"], agent.planet)
    try:
        return play(env)
    finally:
        env.close()


__all__ = ["Agent", "AGENT_NAME", "DECODER", "FORMAT", "FORMAT_VERSION", "INFO", "NoDecoder", "sha256", "read_saved",
           "saved_planet", "saved_model", "load_agent", "play_agent", "in_its_game"]
