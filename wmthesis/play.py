"""Watch a trained agent play, without training: ``python -m wmthesis play EXPERIMENT ...``.

The agent is the one a ``quick`` run shipped in the repository (or one trained here), on the
experiment's own evaluation levels or bouts, so its results are the summary's seed row. Each
play's result is printed as it ends; ``record`` writes a rerun recording of the plays, each step's
real frame beside what the agent saw, imagined and weighed (:mod:`wmthesis.thoughts`), ``video``
an mp4 of the same panels side by side (opencv). Paths are checked before anything plays; an agent that is not
there is one line naming what is missing and the command that trains it.

Every experiment whose declaration names an agent file plays (:data:`wmthesis.declarations.AGENTS`):
the agent is loaded by :func:`wmthesis.load` and plays its scored bouts through its family's
``play_bouts``.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from wmthesis.agents import agent_file
from wmthesis.config import EXPERIMENTS, profile_name
from wmthesis.declarations import AGENTS as PLAYABLE
from wmthesis.runs import check_writable
from wmthesis.utils import check_bouts, check_choice


def check_output(path: str | os.PathLike | None, suffix: str) -> Path | None:
    """``path`` for a recording or video if it can be written (:func:`~wmthesis.runs.check_writable`:
    a file ending in ``suffix`` in a folder that takes a new file); ValueError naming it otherwise,
    before anything plays."""
    return None if path is None else check_writable(path, suffix)


DEFAULT_BOUTS = 10  # bouts play plays unless told (fewer where the agent was scored on fewer)


def play(experiment: str, *, profile: str | None = None, seed: int = 0, variant: str | None = None,
         bouts: int | None = None, record=None, video=None, on_play=print) -> dict:
    """``bouts`` plays of ``experiment``'s trained agent (``seed``'s run of ``profile``; ``variant``:
    one of its variants, None the default), loaded by :func:`wmthesis.load` and played as its
    evaluation played them (``bouts`` None: :data:`DEFAULT_BOUTS`, or all its scored bouts where
    fewer); returns ``plays`` (one dict each) and ``score`` (their mean: the solve rate for Sokoban)."""
    check_choice("experiment", experiment, EXPERIMENTS)
    if experiment not in PLAYABLE:
        raise ValueError(f"play shows {', '.join(PLAYABLE)}; {experiment} has no agent that plays")
    if bouts is not None:
        check_bouts(bouts, "--bouts")
    record, video = check_output(record, ".rrd"), check_output(video, ".mp4")
    profile = profile_name(profile)
    agent_file(experiment, variant, profile, seed)  # a bad variant is refused before anything loads
    from wmthesis.agents import load

    agent = load(experiment, variant=variant, profile=profile, seed=seed)
    if bouts is None:
        bouts = min(DEFAULT_BOUTS, agent.scored_bouts or DEFAULT_BOUTS)
    agent.check_weights()
    on_bout = lambda p: on_play(agent.bout_line(p))  # noqa: E731
    if record is None and video is None:
        plays = agent.play_bouts(bouts, on_bout=on_bout)
        on_play(agent.score_line(plays))
        return _result(agent, plays)
    note = agent.left_out()
    if note:
        on_play(note)
    kept = record or video.with_name(f".{video.stem}.rrd")  # a video alone is drawn from a recording not kept
    try:
        recorded = agent.record(bouts, kept, video=video, on_bout=on_bout)
    finally:
        if record is None:
            kept.unlink(missing_ok=True)
    on_play(agent.score_line(recorded["plays"]))
    if recorded["errors"]:
        on_play(imagination_line(recorded))
    on_play(f"recorded {recorded['steps']} steps: " + ", ".join(str(p) for p in (record, video) if p is not None)
            + (f" (open with: rerun {record})" if record else ""))
    return {**_result(agent, recorded["plays"]), "errors": recorded["errors"]}


def imagination_line(recorded: dict) -> str:
    """A recording's errors (:meth:`~wmthesis.thoughts.Recorder.close`) in one line: imagination
    against reality by steps ahead, and the model's reconstruction of the frame it sees, the floor under them."""
    line = ("imagination against reality, mean squared error in [0, 1] by steps ahead: "
            + ", ".join(f"{j}: {e:.4f}" for j, e in recorded["errors"].items()))
    if recorded.get("reconstruction") is not None:
        line += f"; the reconstruction of the frame itself: {recorded['reconstruction']:.4f}"
    return line


def _result(agent, plays: list[dict]) -> dict:
    return {"experiment": agent.experiment, "variant": agent.variant, "profile": agent.profile, "seed": agent.seed,
            "plays": plays, "score": float(np.mean([p["return"] for p in plays]))}


__all__ = ["PLAYABLE", "check_output", "imagination_line", "play"]
