"""HDF5 episode store, recorder, chunk sampling and collection."""
import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

from wmthesis.core import Mind, RandomMind, loop
from wmthesis.rollouts import EpisodeRecorder, collect
from wmthesis.data import EpisodeStore, StoreError, chunk_starts

ROOT = Path(__file__).resolve().parents[1]
SHAPE = (4, 4, 3)


def make_episode(index: int, steps: int, shape=SHAPE, terminal=True) -> dict:
    """Random episode whose first pixel channels encode (index, step // 256, step % 256)."""
    rng = np.random.default_rng([index, steps])
    observations = rng.integers(0, 256, (steps, *shape), dtype=np.uint8)
    observations[:, 0, 0, 0] = index
    observations[:, 0, 0, 1] = np.arange(steps) // 256
    observations[:, 0, 0, 2] = np.arange(steps) % 256
    terminals = np.zeros(steps, bool)
    terminals[-1] = terminal
    return dict(observations=observations, actions=np.arange(steps) % 7,
                rewards=rng.normal(size=steps).astype(np.float32), terminals=terminals)


def assert_same_episode(stored: dict, expected: dict) -> None:
    assert stored.keys() == {"observations", "actions", "rewards", "terminals"}
    for key, value in expected.items():
        assert stored[key].dtype == np.dtype({"observations": np.uint8, "actions": np.int64,
                                              "rewards": np.float32, "terminals": np.bool_}[key])
        assert np.array_equal(stored[key], value), key


def new_store(path, **settings) -> EpisodeStore:
    return EpisodeStore(path, "a", env="boxing", preprocessing="world_models", seed=0,
                        obs_shape=SHAPE, **settings)


def digest(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def stores_equal(first, second) -> bool:
    with EpisodeStore(first) as a, EpisodeStore(second) as b:
        if len(a) != len(b):
            return False
        for i in range(len(a)):
            x, y = a.episode(i), b.episode(i)
            if not all(np.array_equal(x[key], y[key]) for key in x):
                return False
        return True


# ------------------------------------------------------------------ store: writing and reading
def test_round_trip_is_exact_and_survives_reopening(tmp_path):
    path = tmp_path / "store.h5"
    lengths = [1, 15, 16, 17, 40]
    episodes = [make_episode(i, n, terminal=i % 2 == 0) for i, n in enumerate(lengths)]
    with new_store(path) as store:
        for i, episode in enumerate(episodes[:3]):
            assert store.append_episode(**episode) == i
    with new_store(path) as store:
        for episode in episodes[3:]:
            store.append_episode(**episode)
    with EpisodeStore(path) as store:
        assert len(store) == 5 and store.num_steps == sum(lengths)
        assert store.episode_lengths.tolist() == lengths
        for i, episode in enumerate(episodes):
            assert_same_episode(store.episode(i), episode)
        assert_same_episode(store.episode(-1), episodes[-1])
        attrs = store.attrs
    assert attrs["env"] == "boxing" and attrs["preprocessing"] == "world_models"
    assert attrs["seed"] == 0 and attrs["obs_shape"] == SHAPE
    for key in ("numpy_version", "h5py_version", "gymnasium_version", "ale_py_version",
                "wmthesis_version", "created"):
        assert attrs[key]


def test_episode_index_out_of_range(tmp_path):
    with new_store(tmp_path / "s.h5") as store:
        store.append_episode(**make_episode(0, 3))
        with pytest.raises(IndexError, match="s.h5"):
            store.episode(1)


# ------------------------------------------------------------------ sampling
@pytest.fixture
def sample_store(tmp_path):
    path = tmp_path / "sample.h5"
    with new_store(path) as store:
        for i, steps in enumerate([30, 5, 300, 12, 51]):
            store.append_episode(**make_episode(i, steps))
    with EpisodeStore(path) as store:
        yield store


def test_chunks_have_the_right_shapes_and_never_cross_episodes(sample_store):
    chunks = sample_store.sample_chunks(64, 12, np.random.default_rng(0))
    assert chunks["observations"].shape == (64, 12, *SHAPE) and chunks["observations"].dtype == torch.uint8
    assert chunks["actions"].shape == (64, 12) and chunks["actions"].dtype == torch.int64
    assert chunks["rewards"].shape == (64, 12) and chunks["rewards"].dtype == torch.float32
    assert chunks["terminals"].shape == (64, 12) and chunks["terminals"].dtype == torch.bool
    pixels = chunks["observations"][:, :, 0, 0].long()
    episode, step = pixels[..., 0], pixels[..., 1] * 256 + pixels[..., 2]
    assert torch.all(episode == episode[:, :1])                 # one episode per chunk
    assert torch.all(step[:, 1:] - step[:, :-1] == 1)           # consecutive steps
    assert set(episode[:, 0].tolist()) <= {0, 2, 3, 4}          # episode 1 (5 steps) is too short
    for b in range(64):  # actions, rewards, terminals are the same rows as the observations
        stored = sample_store.episode(int(episode[b, 0]))
        rows = step[b].numpy()
        assert np.array_equal(chunks["actions"][b].numpy(), stored["actions"][rows])
        assert np.array_equal(chunks["rewards"][b].numpy(), stored["rewards"][rows])
        assert np.array_equal(chunks["terminals"][b].numpy(), stored["terminals"][rows])
        assert np.array_equal(chunks["observations"][b].numpy(), stored["observations"][rows])


def test_same_generator_seed_gives_the_same_batch(sample_store):
    first = sample_store.sample_chunks(8, 10, np.random.default_rng(5))
    second = sample_store.sample_chunks(8, 10, np.random.default_rng(5))
    other = sample_store.sample_chunks(8, 10, np.random.default_rng(6))
    assert all(torch.equal(first[key], second[key]) for key in first)
    assert not torch.equal(first["observations"], other["observations"])


def test_chunk_starts_are_uniform_over_valid_positions(sample_store):
    chunks = sample_store.sample_chunks(4000, 12, np.random.default_rng(1))
    pixels = chunks["observations"][:, 0, 0, 0].long()
    starts = list(zip(pixels[:, 0].tolist(), (pixels[:, 1] * 256 + pixels[:, 2]).tolist()))
    valid = {(e, s) for e, n in enumerate([30, 5, 300, 12, 51]) for s in range(n - 12 + 1)}
    assert set(starts) <= valid and len(set(starts)) > 0.9 * len(valid)
    per_episode = np.bincount([e for e, _ in starts], minlength=5) / len(starts)
    expected = np.array([19, 0, 289, 1, 40]) / 349
    assert np.allclose(per_episode, expected, atol=0.03)


def test_chunks_can_be_drawn_from_some_episodes_only(sample_store):
    chunks = sample_store.sample_chunks(200, 10, np.random.default_rng(2), episodes=[0, 4])
    assert set(chunks["observations"][:, 0, 0, 0, 0].tolist()) == {0, 4}
    with pytest.raises(ValueError, match="no episode of those asked for has 10 steps"):
        sample_store.sample_chunks(2, 10, np.random.default_rng(0), episodes=[1])
    with pytest.raises(IndexError, match="sample.h5"):
        sample_store.sample_chunks(2, 10, np.random.default_rng(0), episodes=[5])


def test_chunk_starts_works_on_any_episode_layout():
    starts, ends = np.array([0, 3, 10]), np.array([3, 10, 12])  # no padding between episodes
    rows = chunk_starts(starts, ends, 5000, 2, np.random.default_rng(0))
    assert np.array_equal(np.unique(rows), [0, 1, 3, 4, 5, 6, 7, 8, 10])
    counts = np.bincount(rows)[np.unique(rows)]
    assert counts.max() / counts.min() < 1.3  # uniform over the 9 valid starts


def test_no_episode_long_enough_is_a_clear_error(sample_store):
    with pytest.raises(ValueError, match=r"sample\.h5.*no episode has 301 steps.*longest has 300"):
        sample_store.sample_chunks(2, 301, np.random.default_rng(0))
    with pytest.raises(TypeError, match="numpy.random.Generator"):
        sample_store.sample_chunks(2, 3, 0)


# ------------------------------------------------------------------ bad input
def test_missing_file_in_read_mode(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere.h5"):
        EpisodeStore(tmp_path / "nowhere.h5")
    assert not (tmp_path / "nowhere.h5").exists()


def test_corrupt_and_truncated_files(tmp_path):
    junk = tmp_path / "junk.h5"
    junk.write_bytes(np.random.default_rng(0).bytes(10_000))
    with pytest.raises(StoreError, match="junk.h5"):
        EpisodeStore(junk)
    with pytest.raises(StoreError, match="junk.h5"):
        EpisodeStore(junk, "a", obs_shape=SHAPE)
    assert len(junk.read_bytes()) == 10_000

    cut = tmp_path / "cut.h5"
    with new_store(cut) as store:
        for i in range(3):
            store.append_episode(**make_episode(i, 50))
    data = cut.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(StoreError, match="cut.h5"):
        EpisodeStore(cut)

    other = tmp_path / "other.h5"
    import h5py
    with h5py.File(other, "w") as f:
        f["x"] = [1, 2, 3]
    with pytest.raises(StoreError, match="other.h5.*not a wmthesis episode store"):
        EpisodeStore(other)


@pytest.mark.parametrize("setting, value", [("env", "freeway"), ("preprocessing", "planet"),
                                            ("obs_shape", (64, 64, 3)), ("seed", 1)])
def test_appending_with_other_settings_fails_and_leaves_the_file_alone(tmp_path, setting, value):
    path = tmp_path / "store.h5"
    with new_store(path) as store:
        store.append_episode(**make_episode(0, 20))
    before = digest(path)
    settings = dict(env="boxing", preprocessing="world_models", seed=0, obs_shape=SHAPE)
    settings[setting] = value
    with pytest.raises(ValueError, match=rf"store\.h5.*{setting}"):
        EpisodeStore(path, "a", **settings)
    assert digest(path) == before


def test_bad_episodes_are_refused_and_nothing_is_damaged(tmp_path):
    path = tmp_path / "store.h5"
    good = make_episode(0, 20)
    with new_store(path) as store:
        store.append_episode(**good)
        bad = [dict(good, observations=good["observations"][:, :2]),            # frame shape
               dict(good, observations=good["observations"].astype(np.float32)),  # dtype
               dict(good, actions=good["actions"][:-1]),                          # length
               dict(good, actions=good["actions"].astype(float)),
               dict(good, rewards=np.array(["a"] * 20)),
               dict(good, terminals=good["terminals"].astype(np.int64)),
               dict(good, terminals=np.ones(20, bool)),                           # early terminal
               dict(good, observations=good["observations"][:0], actions=[], rewards=[], terminals=[])]
        for episode in bad:
            with pytest.raises(ValueError, match="store.h5"):
                store.append_episode(**episode)
        assert len(store) == 1
    with EpisodeStore(path) as store:
        assert len(store) == 1
        assert_same_episode(store.episode(0), good)
        with pytest.raises(ValueError, match="read-only"):
            store.append_episode(**good)


# ------------------------------------------------------------------ recorder
class CountingEnv(gym.Env):
    """Observations count steps; an episode terminates after `length` steps."""

    observation_space = gym.spaces.Box(0, 255, SHAPE, np.uint8)
    action_space = gym.spaces.Discrete(3)

    def __init__(self, length=7):
        self.length, self.t = length, 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.full(SHAPE, self.t, np.uint8), {}

    def step(self, action):
        self.t += 1
        return np.full(SHAPE, self.t, np.uint8), float(action), self.t >= self.length, False, {}


class StopAt(Mind):
    """Random scores; raises KeyboardInterrupt at a given plan call."""

    def __init__(self, calls):
        self.calls, self.random = calls, RandomMind(3, seed=0)

    def plan(self, state, train_mode=True, debug_mode=False):
        self.calls -= 1
        if self.calls < 0:
            raise KeyboardInterrupt
        return self.random.plan(state)


def test_recorder_writes_finished_and_cut_episodes(tmp_path):
    with new_store(tmp_path / "rec.h5") as store:
        recorder = EpisodeRecorder(store)
        history = loop(CountingEnv(), RandomMind(3, seed=0), n_episodes=2, callbacks=[recorder])
        loop(CountingEnv(), RandomMind(3, seed=1), n_episodes=1, max_steps=4, callbacks=[recorder])
        assert history[-1]["episodes_written"] == 2 and history[-1]["steps_written"] == 14
        assert recorder.metrics == {"episodes_written": 3, "steps_written": 18}
        assert store.episode_lengths.tolist() == [7, 7, 4]
        first, cut = store.episode(0), store.episode(2)
    assert first["observations"][:, 0, 0, 0].tolist() == list(range(7))  # o_t before acting
    assert np.array_equal(first["rewards"], first["actions"].astype(np.float32))
    assert first["terminals"].tolist() == [False] * 6 + [True]
    assert not cut["terminals"].any()  # truncated, not terminal


def test_recorder_drops_the_partial_episode_of_an_aborted_loop(tmp_path):
    with new_store(tmp_path / "rec.h5") as store:
        recorder = EpisodeRecorder(store)
        with pytest.raises(KeyboardInterrupt):
            loop(CountingEnv(), StopAt(10), n_episodes=3, callbacks=[recorder])
        assert len(store) == 1 and recorder.metrics["episodes_written"] == 1
        loop(CountingEnv(), RandomMind(3), n_episodes=1, callbacks=[recorder])
        assert store.episode_lengths.tolist() == [7, 7]


# ------------------------------------------------------------------ collect
COLLECT = dict(max_steps=15, progress=False)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """4 Boxing episodes of at most 15 steps, collected in this process."""
    return collect("boxing", 4, tmp_path_factory.mktemp("ref") / "ref.h5", **COLLECT)


def test_collect_writes_random_rollouts_with_its_settings(reference):
    with EpisodeStore(reference) as store:
        assert len(store) == 4 and store.episode_lengths.tolist() == [15] * 4
        attrs = store.attrs
        actions = np.concatenate([store.episode(i)["actions"] for i in range(4)])
        observations = store.episode(0)["observations"]
    assert attrs["env"] == "boxing" and attrs["preprocessing"] == "world_models"
    assert attrs["obs_shape"] == (64, 64, 3) and attrs["seed"] == 0
    assert attrs["env_options"] == {"preprocessing": "world_models", "max_steps": 15}
    assert len(np.unique(actions)) > 10  # random actions over Boxing's 18
    assert not np.array_equal(observations[0], observations[-1])


def test_collect_sokoban_keeps_its_own_observations(tmp_path):
    pytest.importorskip("wmthesis.envs.sokoban")
    path = collect("sokoban-small", 2, tmp_path / "sokoban.h5", max_steps=6, observation="grid",
                   progress=False)
    with EpisodeStore(path) as store:
        assert store.attrs["preprocessing"] == "none" and store.obs_shape == (25,)
        assert store.episode_lengths.tolist() == [6, 6]
    with pytest.raises(ValueError, match="no preprocessing"):
        collect("sokoban-small", 1, tmp_path / "other.h5", preprocessing="world_models", progress=False)


def test_collect_does_not_depend_on_workers(reference, tmp_path):
    path = collect("boxing", 4, tmp_path / "two.h5", workers=2, **COLLECT)
    assert stores_equal(reference, path)


def test_collect_resumes(reference, tmp_path):
    path = tmp_path / "resumed.h5"
    collect("boxing", 2, path, **COLLECT)
    collect("boxing", 4, path, **COLLECT)
    assert stores_equal(reference, path)
    with pytest.raises(ValueError, match=r"resumed\.h5.*seed"):
        collect("boxing", 5, path, seed=1, **COLLECT)
    with pytest.raises(ValueError, match=r"resumed\.h5.*env_options"):
        collect("boxing", 5, path, max_steps=20, progress=False)


def run_python(code: str, **popen) -> subprocess.Popen:
    """Start ``python -c code`` that can import wmthesis; stdout is piped unless told."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    return subprocess.Popen([sys.executable, "-c", code], env=env, text=True,
                            **{"stdout": subprocess.PIPE, **popen})


def wait_for_size(path: Path, size: int, child: subprocess.Popen) -> None:
    """Wait until the file at `path` is larger than `size` bytes (episodes are being written) while
    ``child``, which writes it, runs: on that event, not a clock (a busy machine is only slower)."""
    while not (path.exists() and path.stat().st_size > size):
        assert child.poll() is None, f"the writer of {path} ended (status {child.returncode}) before it grew past {size} bytes"
        time.sleep(0.02)


def alive(pid: int) -> bool:
    """Whether process `pid` runs (a zombie does not)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc to find the workers")
def test_sigkill_while_collecting_keeps_complete_episodes_and_ends_the_workers(tmp_path):
    path = tmp_path / "killed.h5"
    child = run_python(f"from wmthesis.rollouts import collect\n"
                       f"collect('boxing', 400, {str(path)!r}, workers=2, max_steps=15, progress=False)")
    wait_for_size(path, 200_000, child)  # several episodes are written
    time.sleep(np.random.default_rng().uniform(0, 0.2))
    workers = [int(pid) for pid in Path(f"/proc/{child.pid}/task/{child.pid}/children").read_text().split()]
    child.send_signal(signal.SIGKILL)
    child.wait()
    with EpisodeStore(path) as store:
        kept = len(store)
        assert 0 < kept < 400 and all(store.episode_lengths == 15)
    clean = collect("boxing", kept + 2, tmp_path / "clean.h5", **COLLECT)
    collect("boxing", kept + 2, path, **COLLECT)  # repairs, trims and resumes
    assert stores_equal(clean, path)
    deadline = time.time() + 10
    while any(map(alive, workers)) and time.time() < deadline:
        time.sleep(0.05)
    assert len(workers) >= 2 and not any(map(alive, workers))


def test_a_store_held_by_a_live_writer_is_not_repaired(tmp_path):
    path = tmp_path / "held.h5"
    child = run_python(f"import time\nfrom wmthesis.data import EpisodeStore\n"
                       f"store = EpisodeStore({str(path)!r}, 'a', obs_shape={SHAPE})\n"
                       f"print('open', flush=True)\ntime.sleep(60)")
    try:
        assert child.stdout.readline().strip() == "open"
        before = digest(path)
        with pytest.raises(StoreError, match="held.h5"):
            EpisodeStore(path)
        assert digest(path) == before
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
    with EpisodeStore(path) as store:  # readable again once its writer is gone
        assert len(store) == 0


def test_ctrl_c_stops_the_workers_and_keeps_complete_episodes(reference, tmp_path):
    path = tmp_path / "interrupted.h5"
    child = run_python(f"from wmthesis.rollouts import collect\n"
                       f"collect('boxing', 4000, {str(path)!r}, workers=2, max_steps=15, progress=False)",
                       stdout=None, stderr=subprocess.PIPE, start_new_session=True)
    wait_for_size(path, 100_000, child)
    os.killpg(child.pid, signal.SIGINT)  # what Ctrl-C in a terminal does
    _, stderr = child.communicate(timeout=30)
    assert child.returncode != 0 and "KeyboardInterrupt" in stderr
    assert f"KeyboardInterrupt: {path} keeps " in stderr and "complete episodes" in stderr
    with EpisodeStore(path) as store:
        assert 0 < len(store) < 4000 and all(store.episode_lengths == 15)
        with EpisodeStore(reference) as ref:
            for i in range(min(len(store), len(ref))):
                assert np.array_equal(store.episode(i)["observations"], ref.episode(i)["observations"])
