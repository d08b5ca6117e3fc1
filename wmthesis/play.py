"""Watch a trained agent play, without training: ``python -m wmthesis play EXPERIMENT ...``.

The agent is the one a ``quick`` run shipped in the repository (or one trained here), on the
experiment's own evaluation levels or bouts, so its results are the summary's seed row. Each
play's result is printed as it ends; ``record`` writes a rerun recording of the plays, ``video``
an mp4 of their frames (opencv). Paths are checked before anything plays; an agent that is not
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
from wmthesis.utils import check_choice


def check_output(path: str | os.PathLike | None, suffix: str) -> Path | None:
    """``path`` for a recording or video if it can be written (a file ending in ``suffix`` in a
    folder that exists and is writable); ValueError naming it otherwise, before anything plays."""
    if path is None:
        return None
    path = Path(path)
    if path.suffix != suffix:
        raise ValueError(f"{path}: name a {suffix} file")
    if path.is_dir() or not path.parent.is_dir() or not os.access(path.parent, os.W_OK):
        raise ValueError(f"{path} cannot be written: its folder {path.parent} is missing or not writable")
    return path


def play(experiment: str, *, profile: str | None = None, seed: int = 0, variant: str | None = None, bouts: int = 10,
         record=None, video=None, on_play=print) -> dict:
    """``bouts`` plays of ``experiment``'s trained agent (``seed``'s run of ``profile``; ``variant``:
    one of its variants, None the default), loaded by :func:`wmthesis.load` and played as its
    evaluation played them; returns ``plays`` (one dict each) and ``score`` (their mean: the solve
    rate for Sokoban)."""
    check_choice("experiment", experiment, EXPERIMENTS)
    if experiment not in PLAYABLE:
        raise ValueError(f"play shows {', '.join(PLAYABLE)}; {experiment} has no agent that plays")
    if bouts < 1:
        raise ValueError(f"--bouts must be 1 or more, got {bouts}")
    record, video = check_output(record, ".rrd"), check_output(video, ".mp4")
    profile = profile_name(profile)
    agent_file(experiment, variant, profile, seed)  # a bad variant is refused before anything loads
    from wmthesis.agents import load

    agent = load(experiment, variant=variant, profile=profile, seed=seed)
    frames = [] if record or video else None
    plays = agent.play_bouts(bouts, frames, on_bout=lambda p: on_play(agent.bout_line(p)))
    on_play(agent.score_line(plays))
    if frames:
        _keep_frames(np.concatenate(frames), record, video, agent.video_scale, agent.fps)
    return {"experiment": experiment, "variant": agent.variant, "profile": profile, "seed": seed, "plays": plays,
            "score": float(np.mean([p["return"] for p in plays]))}


def _keep_frames(frames: np.ndarray, record: Path | None, video: Path | None, scale: int, fps: int) -> None:
    """``frames`` (T, H, W, 3) uint8 as a rerun recording and an mp4 (``scale`` times larger), where asked for."""
    if record is not None:
        from wmthesis.viz import record_frames

        record_frames(record, {"frame": frames})
    if video is not None:
        _write_video(video, np.repeat(np.repeat(frames, scale, axis=1), scale, axis=2), fps=fps)


def _write_video(path: Path, frames: np.ndarray, fps: int = 8) -> None:
    """``frames`` (T, H, W, 3) RGB as an mp4 at ``path``."""
    import cv2

    height, width = frames.shape[1:3]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    try:
        for frame in frames:
            writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    finally:
        writer.release()


__all__ = ["PLAYABLE", "check_output", "play"]
