"""What an agent thought at each step of a real bout, recorded beside what then happened.

At every step the agent's family says what it saw, imagined and weighed (a :class:`Thought`);
:class:`Recorder` writes it to a rerun recording beside the real frame, as the bout is played, so a
recording cut off (Ctrl-C) is still one that opens:

- ``reality``: the frame the agent saw; ``model/seen``: the model's reconstruction of it;
- ``imagination/j``: the frame the agent imagined j steps earlier for this step, so each of those
  panels shows dream and reality aligned; ``error/j``: its error against the frame that came
  (:func:`~wmthesis.metrics.horizon_errors`: mean squared error in [0, 1]);
- ``reward/real`` and ``reward/imagined`` (the reward predicted one step earlier for this step),
  at the same step indices;
- ``scores/NAME``: what the agent weighed per action (a controller's scores, a root's visits, Q
  and prior, a value's Q); ``series/NAME``: curves of one decision (CEM's elite return per
  iteration); ``values/NAME``: numbers of one decision (a search's size and depth);
  ``reality/plan``: a plan drawn on the frame (Sokoban's player path).

The recording carries a blueprint that opens it laid out: reality, the model's view and its
imagination side by side, the plots below. ``video`` writes the same panels side by side as an
mp4 (opencv). Nothing here knows a model: a family's ``thought(mind)`` fills the :class:`Thought`.
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Callable

import numpy as np

from wmthesis.core import Callback
from wmthesis.metrics import horizon_errors

VIDEO_HORIZONS = (1, 4, 8)  # which imagination panels a video shows beside reality


@dataclasses.dataclass
class Thought:
    """What the agent thought at one step (all optional): ``seen`` (H, W, 3) uint8, its model's
    view of the frame; ``imagined`` {j: (H, W, 3) uint8}, the frames it imagines j steps ahead
    (every j of its horizon, or the ones shown); ``imagined_rewards`` (k,), the rewards it
    predicts for the next k steps; ``scores`` per action (A,);
    ``series`` (n,) curves; ``values`` numbers; ``plan`` (n, 2) points (x, y) on the frame."""

    seen: np.ndarray | None = None
    imagined: dict = dataclasses.field(default_factory=dict)
    imagined_rewards: np.ndarray | None = None
    scores: dict = dataclasses.field(default_factory=dict)
    series: dict = dataclasses.field(default_factory=dict)
    values: dict = dataclasses.field(default_factory=dict)
    plan: np.ndarray | None = None


SPACE_CHECK_STEPS = 64  # the recorder checks the disk for the next this many steps' frames


class Recorder:
    """A rerun recording (and optionally an mp4) of bouts, written step by step (module docstring).

    ``horizon``: how many imagination panels the layout shows; ``scale``: how much larger the
    video draws its panels. :meth:`close` returns the mean error of imagination per imagined step
    over the recording (``errors``, {j: mean}) and how many steps were recorded."""

    def __init__(self, path: str | os.PathLike, *, horizon: int, video: str | os.PathLike | None = None,
                 scale: int = 4, fps: int = 15, application_id: str = "wmthesis", left_out: str | None = None):
        import rerun as rr

        self.path, self.horizon, self.scale, self.fps = Path(path), int(horizon), int(scale), int(fps)
        self.stream = rr.RecordingStream(application_id)
        self.stream.save(str(self.path))
        self.stream.send_blueprint(self.blueprint())
        if left_out:
            self.stream.log("notes", rr.TextDocument(left_out), static=True)
        self.video_path, self.video = (Path(video) if video else None), None
        self.step_index, self.pending, self.errors, self.reconstructions = 0, {}, {}, []
        self.plan_drawn = self.closed = False

    def blueprint(self):
        """Reality, the model's view and its imagination side by side; rewards, errors and what the
        agent weighed below."""
        import rerun.blueprint as rrb

        shown = sorted({1, max(1, self.horizon // 2), self.horizon})
        images = [rrb.Spatial2DView(origin="reality", name="reality"),
                  rrb.Spatial2DView(origin="model/seen", name="the model sees")]
        images += [rrb.Spatial2DView(origin=f"imagination/{j}", name=f"imagined {j} step{'s' * (j > 1)} before")
                   for j in shown]
        plots = [rrb.TimeSeriesView(origin="reward", name="reward: real and imagined"),
                 rrb.TimeSeriesView(origin="error", name="imagination against reality"),
                 rrb.TimeSeriesView(origin="values", name="the decision"),
                 rrb.BarChartView(origin="scores", name="what it weighed")]
        return rrb.Blueprint(rrb.Vertical(rrb.Horizontal(*images), rrb.Horizontal(*plots), row_shares=[3, 2]),
                             collapse_panels=True)

    # ---------------------------------------------------------------- one bout
    def start_bout(self, bout: int) -> None:
        """A new bout: imagination reaching past the last one is dropped."""
        self.pending = {}
        self._at(self.step_index)
        self._scalar("bout", bout)

    def step(self, frame: np.ndarray, thought: Thought | None = None) -> None:
        """The frame (H, W, 3) uint8 the agent sees now and what it thought of it."""
        import rerun as rr

        thought = thought or Thought()
        self._at(self.step_index)
        self.stream.log("reality", _image(frame))
        drawn = thought.plan is not None and len(thought.plan) > 0
        if drawn:
            self.stream.log("reality/plan", rr.LineStrips2D([np.asarray(thought.plan, np.float32)], colors=[255, 64, 64]))
        elif self.plan_drawn:
            self.stream.log("reality/plan", rr.Clear(recursive=False))
        self.plan_drawn = drawn
        if thought.seen is not None:
            self.stream.log("model/seen", _image(thought.seen))
            self.reconstructions.append(float(horizon_errors(np.asarray(frame)[None], np.asarray(thought.seen)[None])[0]))
        arrived = self.pending.pop(self.step_index, {})
        for j, (predicted, reward) in sorted(arrived.items()):
            if predicted is not None:
                self.stream.log(f"imagination/{j}", _image(predicted))
                error = float(horizon_errors(np.asarray(frame)[None], np.asarray(predicted)[None])[0])
                self.errors.setdefault(j, []).append(error)
                self._scalar(f"error/{j}", error)
            if j == 1 and reward is not None:
                self._scalar("reward/imagined", reward)
        for name, values in thought.scores.items():
            self.stream.log(f"scores/{name}", rr.BarChart(np.nan_to_num(np.asarray(values, np.float64))))
        for name, values in thought.series.items():
            self.stream.log(f"series/{name}", rr.BarChart(np.asarray(values, np.float64)))
        for name, value in thought.values.items():
            self._scalar(f"values/{name}", value)
        self._imagine(thought)
        self._video_frame(frame, thought.seen, arrived)
        if self.step_index % SPACE_CHECK_STEPS == 0:
            self._check_space(frame)

    def outcome(self, reward: float) -> None:
        """The real reward of the action just taken (logged at the step it arrives)."""
        self.step_index += 1
        self._at(self.step_index)
        self._scalar("reward/real", reward)

    def end_bout(self, frame: np.ndarray | None = None) -> None:
        """The bout's last frame (after its last action), where there is one; the next bout starts
        one step later."""
        if frame is not None:
            self.step(frame)
        self.step_index += 1
        self.pending = {}

    def close(self) -> dict:
        """Flush what was recorded (a valid recording, however the bout ended): the mean error of
        imagination per imagined step, that of the model's reconstruction of the frame it sees (None
        where it shows none: the floor under every imagined step's error) and the steps recorded."""
        if self.closed:  # removed on a full disk
            return {"steps": self.step_index, "errors": {}, "reconstruction": None}
        self.stream.flush()
        self.stream.disconnect()
        if self.video is not None:
            self.video.release()
        return {"steps": self.step_index, "errors": {j: float(np.mean(e)) for j, e in sorted(self.errors.items())},
                "reconstruction": float(np.mean(self.reconstructions)) if self.reconstructions else None}

    # ---------------------------------------------------------------- helpers
    def _check_space(self, frame: np.ndarray) -> None:
        """:class:`~wmthesis.runs.DiskFull` naming the folder where the next steps may not fit
        (rerun and opencv drop a failed write silently); the recording and the video, which would
        end half-written, are removed."""
        from wmthesis.runs import DiskFull, check_space

        need = SPACE_CHECK_STEPS * (2 + self.horizon) * np.asarray(frame).nbytes
        try:
            for path in filter(None, (self.path, self.video_path)):
                check_space(path.parent, need, f"{path.name} was not written (stopped at step {self.step_index})")
        except DiskFull:
            self.stream.disconnect()
            if self.video is not None:
                self.video.release()
            for path in filter(None, (self.path, self.video_path)):
                path.unlink(missing_ok=True)
            self.video = self.video_path = None
            self.closed = True
            raise

    def _imagine(self, thought: Thought) -> None:
        frames, rewards = thought.imagined, thought.imagined_rewards
        count = max(max(frames, default=0), len(rewards) if rewards is not None else 0)
        for j in range(1, count + 1):
            reward = float(rewards[j - 1]) if rewards is not None and j <= len(rewards) else None
            if j in frames or reward is not None:
                self.pending.setdefault(self.step_index + j, {})[j] = (frames.get(j), reward)

    def _at(self, step: int) -> None:
        self.stream.set_time("step", sequence=step)

    def _scalar(self, name: str, value: float) -> None:
        import rerun as rr

        self.stream.log(name, rr.Scalars([float(value)]))

    def _video_frame(self, frame, seen, arrived: dict) -> None:
        if self.video_path is None:
            return
        blank = np.zeros_like(frame)
        panels = [frame, seen if seen is not None and seen.shape == frame.shape else blank]
        for j in VIDEO_HORIZONS:
            predicted = arrived.get(j, (None, None))[0]
            panels.append(predicted if predicted is not None and predicted.shape == frame.shape else blank)
        strip = np.concatenate(panels, axis=1)
        strip = np.repeat(np.repeat(strip, self.scale, axis=0), self.scale, axis=1)
        import cv2

        if self.video is None:
            height, width = strip.shape[:2]
            self.video = cv2.VideoWriter(str(self.video_path), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, (width, height))
            if not self.video.isOpened():
                raise OSError(f"{self.video_path}: opencv cannot write an mp4 there")
        self.video.write(cv2.cvtColor(np.ascontiguousarray(strip), cv2.COLOR_RGB2BGR))


class Watcher(Callback):
    """The callback that records a :func:`wmthesis.core.loop` bout. Once the mind has planned
    (before the step changes it) ``snapshot()`` keeps what the agent thought; ``thoughts(kept)``
    turns up to ``batch`` snapshots at once into :class:`Thought` s (a family whose thoughts are
    cheaper in batches works there), which go to ``recorder`` in step order with their frames
    and rewards. :meth:`flush` writes what is held (at each bout's end, and on an interruption)."""

    def __init__(self, recorder: Recorder, snapshot: Callable, thoughts: Callable[[list], list[Thought]],
                 batch: int = 32):
        self.recorder, self.snapshot, self.thoughts, self.batch = recorder, snapshot, thoughts, int(batch)
        self.held, self.kept, self.last, self.bout = [], None, None, 0

    def on_episode_start(self, episode, train_mode):
        self.recorder.start_bout(self.bout)

    def on_action_planned(self, step, scores, info):
        self.kept = self.snapshot()

    def on_step_taken(self, step, transition, info):
        self.held.append((np.asarray(transition.state), self.kept, float(transition.reward)))
        self.kept, self.last = None, transition.next_state
        if len(self.held) >= self.batch:
            self.flush()

    def on_episode_end(self, episode, train_mode):
        self.flush()
        self.recorder.end_bout(None if self.last is None else np.asarray(self.last))
        self.last, self.bout = None, self.bout + 1

    def flush(self) -> None:
        """Write the held steps, in order."""
        held, self.held = self.held, []
        if not held:
            return
        for (frame, _, reward), thought in zip(held, self.thoughts([kept for _, kept, _ in held])):
            self.recorder.step(frame, thought)
            self.recorder.outcome(reward)


def _image(frame: np.ndarray):
    """A frame (H, W, 3) uint8 as a lossless PNG rerun image (what a test reads back exactly)."""
    import cv2
    import rerun as rr

    ok, png = cv2.imencode(".png", np.ascontiguousarray(np.asarray(frame, np.uint8)[..., ::-1]))
    return rr.EncodedImage(contents=png.tobytes(), media_type="image/png")


def read_recording(path: str | os.PathLike) -> dict:
    """A recording read back with rerun's reader: per entity path, ``steps`` (its step indices)
    and ``values`` (decoded images (H, W, 3) uint8, scalars as floats, bar charts as arrays, line
    strips as (n, 2) points)."""
    import cv2
    from rerun.chunk import RrdReader

    out: dict = {}
    for chunk in RrdReader(str(path)).store().stream():
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if "step" not in names:
            continue
        steps = batch.column(names.index("step")).to_pylist()
        entry = out.setdefault(chunk.entity_path, {"steps": [], "values": []})
        for name in names:
            if not name.endswith((":blob", "Scalars:scalars", "BarChart:values", "LineStrips2D:strips")):
                continue
            column = batch.column(names.index(name)).to_pylist()
            if name.endswith(":blob"):
                decoded = [cv2.imdecode(np.frombuffer(bytes(v[0]), np.uint8), cv2.IMREAD_COLOR)[..., ::-1] for v in column]
            elif name.endswith("Scalars:scalars"):
                decoded = [float(v[0]) for v in column]
            elif name.endswith("BarChart:values"):
                decoded = [np.asarray(v[0]["buffer"] if isinstance(v[0], dict) else v[0], np.float64) for v in column]
            elif name.endswith(":strips"):
                decoded = [np.asarray(v[0], np.float32) for v in column]
            entry["steps"] += steps
            entry["values"] += decoded
    for entry in out.values():
        order = np.argsort(entry["steps"], kind="stable")
        entry["steps"] = [entry["steps"][i] for i in order]
        entry["values"] = [entry["values"][i] for i in order]
    return out


def still(recording: dict, start: int, steps: int = 8, ahead: tuple[int, ...] = (1, 4, 8), every: int = 1):
    """One still of a recording (:func:`read_recording`): over ``steps`` steps from ``start``
    (every ``every``-th), reality on top, the model's view below it, then for each j in ``ahead``
    what was imagined j steps before for that step; returns the matplotlib figure."""
    import matplotlib.pyplot as plt

    shown = [start + every * k for k in range(steps)]
    rows = [("reality", "/reality"), ("the model sees", "/model/seen")]
    rows += [(f"imagined {j} step{'s' * (j > 1)} before", f"/imagination/{j}") for j in ahead]
    rows = [(label, entity) for label, entity in rows if entity in recording]
    fig, axes = plt.subplots(len(rows), len(shown), figsize=(1.3 * len(shown), 1.35 * len(rows)), squeeze=False)
    for r, (label, entity) in enumerate(rows):
        entry = recording[entity]
        for c, step in enumerate(shown):
            ax = axes[r, c]
            ax.set_xticks([])
            ax.set_yticks([])
            if step in entry["steps"]:
                ax.imshow(entry["values"][entry["steps"].index(step)], interpolation="nearest")
            if r == 0:
                ax.set_title(f"step {step}", fontsize=8)
        axes[r, 0].set_ylabel(label, fontsize=8, rotation=0, ha="right", va="center")
    fig.tight_layout()
    return fig


def recorded_still(agent, steps: int = 120, start: int = 100, shown: int = 8, every: int = 1, path=None):
    """Record the first ``steps`` steps of ``agent``'s first scored bout (to ``path``, a temporary
    file by default) and draw :func:`still` from step ``start``; returns the figure and the
    recording's summary (``errors`` by steps ahead)."""
    import tempfile

    kept, agent.max_steps = agent.max_steps, steps
    try:
        with tempfile.TemporaryDirectory() as folder:
            target = Path(path) if path else Path(folder) / "bout.rrd"
            summary = agent.record(1, target)
            figure = still(read_recording(target), start, shown, ahead=tuple(j for j in (1, 4, 8) if j <= agent.horizon),
                           every=every)
    finally:
        agent.max_steps = kept
    return figure, summary


__all__ = ["Thought", "Recorder", "Watcher", "read_recording", "still", "recorded_still", "VIDEO_HORIZONS"]
