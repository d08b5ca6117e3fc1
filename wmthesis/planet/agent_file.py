"""A trained PlaNet agent in one file, to ship and to play: the RSSM (its observation decoder left
behind: planning never decodes), the game, the bouts its score was measured on, the configs and
the commit, with a format version (:mod:`~wmthesis.planet.shipped` reads it back).

    save_agent(path, game, planet_run, bouts, commit)
    agent = load_agent(path)
    rewards = play_agent(agent, *agent.info["bouts"][0])   # one bout, its rewards
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from wmthesis.planet.shipped import (AGENT_NAME, DECODER, FORMAT, FORMAT_VERSION, Agent, NoDecoder,  # noqa: F401
                                     load_agent, play_agent, sha256)
from wmthesis.planet.train import load_planet
from wmthesis.runs import save_agent_file


def save_agent(path: str | os.PathLike, game: str, planet_run: Path, bouts: list, commit: str | None) -> Path:
    """Write the agent of the PlaNet run in ``planet_run`` for ``game`` to ``path``, atomically,
    with the ``bouts`` ((env seed, mind seed) pairs) it was scored on; returns the path."""
    model, planet, _ = load_planet(planet_run)
    return save_agent_file(
        Path(path), FORMAT, FORMAT_VERSION, game=game, n_actions=model.n_actions, planet=dataclasses.asdict(planet),
        bouts=[list(map(int, b)) for b in bouts], commit=commit,
        model={k: v for k, v in model.state_dict().items() if not k.startswith(DECODER)},
        model_file=None, value=None, planner=None)


__all__ = ["Agent", "AGENT_NAME", "FORMAT", "FORMAT_VERSION", "save_agent", "sha256", "load_agent", "play_agent"]
