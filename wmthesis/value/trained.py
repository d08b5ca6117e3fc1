"""A learned value's agent as :func:`wmthesis.load` gives it: PlaNet's frozen RSSM (with its
observation decoder where one ships beside the PlaNet agent it plans with), CEM ending in the value
(:mod:`~wmthesis.value.planner`) and the value, on the game as it was scored.

    agent = wmthesis.load("planet-boxing-value")
    mind = agent.mind(); mind.plan(frame)           # one CEM plan ending in the value
    agent.play(bouts=1)                             # its first scored bout
"""
from __future__ import annotations

from pathlib import Path

import torch

from wmthesis.planet.trained import PlanetAgent
from wmthesis.value.latent_value import action_values
from wmthesis.value.planner import value_planner_mind
from wmthesis.value.shipped import load_value_agent, play_value_agent


class ValueAgent(PlanetAgent):
    """A value experiment's agent: ``model`` (the frozen RSSM), ``value`` (the learned action
    value) and ``planner`` (its :class:`~wmthesis.value.config.ValuePlannerConfig`)."""

    read = staticmethod(load_value_agent)
    play_one = staticmethod(play_value_agent)

    def mind(self, seed: int = 0):
        """CEM with the value as it played its scored bouts, CEM's noise from ``seed``."""
        return value_planner_mind(self.model, self.value, self.config, self.planner, seed)

    @torch.inference_mode()
    def thought(self, mind):
        """PlaNet's thought (:meth:`PlanetAgent.thought`) with the value's Q per first action."""
        thought = super().thought(mind)
        thought.scores["value_q"] = action_values(self.model, self.value, mind.belief, mind.state)[0].cpu().numpy()
        return thought


def load_trained(path: Path, *, experiment: str, variant: str | None, profile: str, seed: int) -> ValueAgent:
    return ValueAgent(path, experiment, variant, profile, seed)


__all__ = ["ValueAgent", "load_trained"]
