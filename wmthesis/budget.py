"""The real environment steps a run consumed to learn, its budget, read from its ``metrics.json``.

Every step an agent takes in the real game to learn counts: random rollouts, each CMA-ES
candidate's bouts and the controller's periodic evaluations, expert and self-play games, the
bouts a value is fitted on or chosen by, PlaNet's and Sokoban's stores. The evaluation bouts a
score is measured on do not. Steps are agent steps (4 frames each in Atari, as Atari 100k's
100k agent steps are 400k frames). A declaration names its reader (``agent_steps``); the summary
adds the budgets of the runs an experiment builds on (:mod:`wmthesis.summary`).

    >>> world_models_steps({"random_play_in_store": {"episodes": 20}, "controller_curve": [{"agent_steps": 4_591_378}]})
    Steps(parts={'random play': 35720, 'CMA-ES': 4591378}, at_most=False)

Where a file predates a count (a bout that may end early, by a knock-out, whose length was not
kept), the reader counts it at its full length and the budget is marked ``at_most``.
"""
from __future__ import annotations

from typing import NamedTuple

# A full bout in agent steps: Boxing's two minutes end a bout a random player cannot win by
# knock-out; Freeway's 2 min 16 s end every episode (tests/test_budget.py plays both).
FULL_BOUT = {"boxing": 1786, "freeway": 2048}


class Steps(NamedTuple):
    """A run's budget: agent steps per stage (``parts``); ``at_most``: some stage is counted at
    its bouts' full length, an upper bound."""
    parts: dict[str, int]
    at_most: bool = False

    @property
    def total(self) -> int:
        return int(sum(self.parts.values()))

    def __add__(self, other: "Steps") -> "Steps":
        """Both budgets' stages; a stage both name counts the steps of both."""
        parts = dict(self.parts)
        for stage, steps in other.parts.items():
            parts[stage] = parts.get(stage, 0) + steps
        return Steps(parts, self.at_most or other.at_most)


def _random_play(store: dict, game: str) -> int:
    """The random rollouts' steps: recorded (``steps``), or their bouts at full length (random play
    never ends a bout early)."""
    return int(store["steps"]) if "steps" in store else int(store["episodes"]) * FULL_BOUT[game]


def world_models_steps(metrics: dict) -> Steps:
    """World Models on Boxing: the random rollouts and CMA-ES (every candidate's bouts and the
    mean's evaluations, ``controller_curve``'s last ``agent_steps``)."""
    return Steps({"random play": _random_play(metrics["random_play_in_store"], "boxing"),
                  "CMA-ES": int(metrics["controller_curve"][-1]["agent_steps"])})


def dream_steps(metrics: dict) -> Steps:
    """World Models learning in the dream: every real step its budget spent, by stage."""
    return Steps({stage: int(steps) for stage, steps in metrics["budget"]["spent"].items()})


def sokoban_world_models_steps(metrics: dict) -> Steps:
    """World Models on Sokoban: the random rollouts (recorded, or at most an episode's limit each) and
    every controller's CMA-ES."""
    from wmthesis.envs.sokoban import MAX_STEPS

    store, collect = metrics["random_play_in_store"], metrics["settings"]["collect"]
    bounded = "steps" not in store
    random = int(store["steps"]) if not bounded else int(store["episodes"]) * int(collect["max_steps"] or MAX_STEPS)
    return Steps({"random play": random, **{f"CMA-ES ({name})": int(c["curve"][-1]["agent_steps"])
                                            for name, c in metrics["controllers"].items()}}, bounded)


def alphazero_steps(metrics: dict) -> Steps:
    """The AlphaZero coupling's own games (its last variant's run): the expert's bouts it imitates,
    the expert's bouts its memory learns (``memory_steps``, or at most full bouts), self-play and
    the tests between (each test's ``steps``, or at most ``max_steps`` a game). The World Models run it
    builds on is counted by the summary."""
    run = metrics["runs"][metrics["variants"][-1]]
    config, counted = run["config"], all("steps" in t for t in run["tests"])
    memory = run.get("memory_steps", int(config.get("memory_games", 0)) * FULL_BOUT["boxing"])
    tests = sum(t["steps"] if counted else len(t["returns"]) * int(config["max_steps"]) for t in run["tests"])
    bounded = ("memory_steps" not in run and memory > 0) or (not counted and tests > 0)
    return Steps({"expert bouts imitated": int(run.get("expert", {}).get("steps", 0)),
                  "expert bouts the memory learns": int(memory),
                  "self-play": int(sum(g["steps"] for g in run["curve"])), "tests during self-play": int(tests)},
                 bounded)


def store_steps(metrics: dict) -> Steps:
    """PlaNet's and the Sokoban search's stores: every step they were trained on (``env_steps``;
    Sokoban's, summed over its inputs)."""
    steps = metrics["env_steps"]
    return Steps({"store": int(sum(steps.values()) if isinstance(steps, dict) else steps)})


def value_steps(metrics: dict) -> Steps:
    """A learned value's own bouts: the random ones, each round's epsilon-greedy ones (at most full
    length in Boxing, where a bout may end by knock-out) and, where rounds are scored, the
    validation bouts that choose one. The PlaNet model it plans in is counted by the summary."""
    config, game = metrics["config"], metrics["env"]
    bout = FULL_BOUT[game]
    own = int(config["rounds"]) * int(config["bouts_per_round"])
    chosen = (int(config["rounds"]) + 1) * int(config["validation_bouts"]) if config.get("score_rounds", True) else 0
    return Steps({"random bouts": int(config["random_bouts"]) * bout, "the value's bouts": own * bout,
                  "validation bouts": chosen * bout}, game == "boxing" and bool(own or chosen))


def short(steps: int) -> str:
    """``4_591_378`` -> ``"4.6M"``, ``98_230`` -> ``"98k"``."""
    if steps >= 1e6:
        return f"{steps / 1e6:.1f}M"
    return f"{steps / 1e3:.0f}k" if steps >= 1e3 else str(steps)


__all__ = ["FULL_BOUT", "Steps", "world_models_steps", "dream_steps", "sokoban_world_models_steps", "alphazero_steps", "store_steps",
           "value_steps", "short"]
