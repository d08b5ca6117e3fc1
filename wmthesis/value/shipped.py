"""A shipped learned value's agent read back: PlaNet's frozen model (named by the PlaNet agent
file it plans with, only the weights that differ kept), the value, the CEM planner that ends in
it, the game, the bouts its score was measured on and the commit
(:mod:`~wmthesis.value.agent_file` writes it, in PlaNet's agent format).

    agent = load_value_agent(path)
    rewards = play_value_agent(agent, *agent.info["bouts"][0])   # one bout, its rewards
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

from wmthesis.planet.config import PlaNetConfig
from wmthesis.planet.rssm import RSSM
from wmthesis.planet.shipped import INFO, in_its_game, load_agent, read_saved, saved_model, saved_planet, sha256
from wmthesis.training import with_added_defaults
from wmthesis.value.config import ValuePlannerConfig
from wmthesis.value.latent_value import LatentValue
from wmthesis.value.planner import play_value_planner


class ShippedValue(NamedTuple):
    """A loaded value's agent: the ``model`` (an RSSM without its decoder's weights), its
    ``planet`` config, the ``value``, its ``planner`` and ``info`` (game, bouts, commit)."""
    model: RSSM
    planet: PlaNetConfig
    value: LatentValue
    planner: ValuePlannerConfig
    info: dict


def load_value_agent(path: str | os.PathLike) -> ShippedValue:
    """The value's agent saved at ``path``; a missing, corrupt or foreign file raises an error
    naming it, and so does one whose PlaNet agent file is missing or has changed since, or one
    without a value (:func:`wmthesis.planet.shipped.load_agent` reads PlaNet's own)."""
    path = Path(path)
    saved = read_saved(path)
    if saved.get("value") is None:
        raise ValueError(f"{path} holds no learned value: wmthesis.planet.shipped.load_agent reads it")
    weights = dict(saved["model"])
    if saved.get("model_file"):  # the PlaNet agent this value was fitted on
        base = path.parent / saved["model_file"]["path"]
        if not base.is_file() or sha256(base) != saved["model_file"]["sha256"]:
            raise ValueError(f"{path} plans with the model of {base}, which is "
                             f"{'missing' if not base.is_file() else 'not the file it was fitted on (its SHA-256 differs)'}")
        weights = {**load_agent(base).model.state_dict(), **weights}
    model = saved_model(path, saved, weights)
    v = saved["value"]
    value = LatentValue(model.belief_size + model.state_size, v["hidden"], v["heads"], v["log"])
    value.load_state_dict({k: t.float() for k, t in v["state"].items()})
    value = value.to(next(model.parameters()).device).eval()
    planner = ValuePlannerConfig(**with_added_defaults(ValuePlannerConfig, saved["planner"]))
    return ShippedValue(model, saved_planet(saved), value, planner, {k: saved[k] for k in INFO})


def play_value_agent(agent: ShippedValue, env_seed: int, mind_seed: int, frames: list | None = None) -> list[float]:
    """One bout of CEM with the value in its game (reset with ``env_seed``, the planner's noise from
    ``mind_seed``): its rewards, one per agent step; ``frames`` (a list) gets its frames where given."""
    return in_its_game(agent, lambda env: play_value_planner(env, agent.model, agent.value, agent.planet, agent.planner,
                                                             env_seed, mind_seed, frames))


__all__ = ["ShippedValue", "load_value_agent", "play_value_agent"]
