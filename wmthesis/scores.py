"""How each experiment's headline score is read from its ``metrics.json``: one reader a declaration
names (:mod:`wmthesis.declarations`), each returning the run's score per variant it ran (``{None:
score}`` for an experiment without variants). A file of another shape raises KeyError or TypeError."""
from __future__ import annotations

import math


def number(value, field: str = "score") -> float:
    """``value`` as a float where it is a finite JSON number; TypeError naming ``field`` otherwise
    (a boolean is not a number here, though Python counts ``True`` as 1)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise TypeError(f"its {field} is {value!r}, not a finite number")
    return float(value)


def variant_score(metrics: dict) -> dict:
    """The score's mean, under the variant the run names (None where it names none)."""
    return {metrics.get("variant"): number(metrics["score"]["mean"])}


def no_score(metrics: dict) -> dict:
    """None: the run reports errors or a curve, not a score."""
    return {}


def alphazero_scores(metrics: dict) -> dict:
    """Every variant the file ran, its search's mean over the evaluation games."""
    return {v: number(metrics["scores"][f"AlphaZero {v}"]["mean"]) for v in metrics["variants"]}


def value_scores(metrics: dict) -> dict:
    """The value agent's mean, and CEM's with the value at its horizon where it was measured."""
    planner, variant = metrics.get("value_planner"), metrics.get("variant")
    return {variant: number(metrics["value"]["mean"]),
            **({"cem-with-value" if variant is None else f"{variant}, cem-with-value": number(planner["full"]["mean"])}
               if planner else {})}


def agent_score(metrics: dict) -> dict:
    """The PlaNet agent's mean over its full evaluation bouts."""
    return {None: number(metrics["agent"]["full"]["mean"])}


def sokoban_world_models_scores(metrics: dict) -> dict:
    """World Models on Sokoban: the percent of evaluation levels its controller solved (the thesis's
    measure: "failed to learn how to solve any level"), and its vision's, the percent of frames
    whose reconstruction shows exactly one player (Fig. 54's claim: the vision "successfully learned")."""
    episodes = int(number(metrics["score"]["episodes"], "episodes"))
    one_player = metrics["baselines"]["vae reconstruction"]["at_cutoff"]["one_player"]
    return {None: 100.0 * number(metrics["controllers"]["mdn"]["solved"], "levels solved") / episodes,
            SOKOBAN_VISION: 100.0 * number(one_player, "reconstructions with one player")}


SOKOBAN_VISION = "vision, reconstructions showing one player (%)"  # the summary's key of the vision's row


def sokoban_scores(metrics: dict) -> dict:
    """Percent solved of the generated levels, and of Boxoban's report files where measured."""
    boxoban = metrics.get("boxoban", {}).get("tables", {})
    return {None: 100.0 * number(metrics["score"]["mean"]),
            **{f"boxoban-{kind}": 100.0 * number(rows["agent, learned model (pixels)"]["solve_rate"])
               for kind, rows in boxoban.items()}}


__all__ = ["number", "SOKOBAN_VISION", "sokoban_world_models_scores", "variant_score", "no_score", "alphazero_scores", "value_scores", "agent_score", "sokoban_scores"]
