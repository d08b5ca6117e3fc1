"""Profiles and configs; rerun recordings hold what was logged."""
import dataclasses

import gymnasium as gym
import numpy as np
import pytest

from wmthesis.config import PROFILES, CollectConfig, for_profile, profile_name
from wmthesis.core import RandomMind, loop
from wmthesis.viz import RerunRecorder, record_frames, recording_rows


def test_thesis_profile_is_the_dataclass_defaults_and_others_override():
    assert for_profile(CollectConfig, "thesis") == CollectConfig()
    assert CollectConfig().episodes == 10_000  # thesis 4.2.3
    smoke = for_profile(CollectConfig, "smoke")
    assert smoke.episodes < for_profile(CollectConfig, "quick").episodes < CollectConfig().episodes
    assert for_profile(CollectConfig, "smoke", episodes=7).episodes == 7
    with pytest.raises(dataclasses.FrozenInstanceError):
        smoke.episodes = 3


def test_profile_names_are_checked(monkeypatch):
    monkeypatch.setenv("WMTHESIS_PROFILE", "thesis")
    assert profile_name() == "thesis"
    assert profile_name("smoke") == "smoke"
    with pytest.raises(ValueError, match="smoke, quick, thesis"):
        profile_name("fast")
    with pytest.raises(TypeError, match="episdoes"):
        for_profile(CollectConfig, "smoke", episdoes=3)
    assert PROFILES == ("smoke", "quick", "thesis")


class Pictures(gym.Env):
    observation_space = gym.spaces.Box(0, 255, (8, 8, 3), np.uint8)
    action_space = gym.spaces.Discrete(3)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.zeros((8, 8, 3), np.uint8), {}

    def step(self, action):
        self.t += 1
        return np.full((8, 8, 3), self.t, np.uint8), 1.0, self.t == 7, False, {}


def test_rerun_recorder_logs_every_step_of_every_episode(tmp_path):
    path = tmp_path / "episode.rrd"
    history = loop(Pictures(), RandomMind(3, seed=0), n_episodes=2, callbacks=[RerunRecorder(path)])
    assert sum(h["steps"] for h in history) == 14
    rows = recording_rows(path)
    assert rows["/observation"] == 14 and rows["/reward"] == 14 and rows["/return"] == 14


def test_long_recordings_count_every_chunk(tmp_path):
    frames = np.zeros((3000, 4, 4, 3), np.uint8)
    rows = recording_rows(record_frames(tmp_path / "long.rrd", {"frames": frames}, {"value": np.arange(3000.0)}))
    assert rows["/frames"] == 3000 and rows["/value"] == 3000


def test_record_frames_side_by_side(tmp_path):
    truth = np.zeros((5, 8, 8, 3), np.uint8)
    rows = recording_rows(record_frames(tmp_path / "r.rrd", {"truth": truth, "prediction": truth[:3]},
                                        {"error": np.arange(5.0)}))
    assert rows["/truth"] == 5 and rows["/prediction"] == 3 and rows["/error"] == 5


@pytest.mark.parametrize("rows", [2, 3])
def test_a_figure_of_image_rows_keeps_its_title_above_the_top_row(rows):
    """Fig. 56 and 57 once drew their titles over the top row's frames (set after the layout)."""
    import matplotlib
    matplotlib.use("Agg")
    from wmthesis.viz import image_grid, image_rows

    frames = [np.zeros((64, 64, 3), np.uint8)] * 8
    for fig in (image_rows({f"row {r}": frames for r in range(rows)}, suptitle="Fig. 56: vision reconstructions"),
                image_grid(frames * rows, ncols=8, suptitle="a chunk")):
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        title = fig._suptitle.get_window_extent(renderer)
        assert title.y0 >= max(ax.get_window_extent(renderer).y1 for ax in fig.axes)
