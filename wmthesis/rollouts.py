"""Episodes played and recorded: :class:`EpisodeBuffer` keeps the episode that
:func:`wmthesis.core.loop` plays, :class:`EpisodeRecorder` writes each one to an
:class:`~wmthesis.data.EpisodeStore`, and :func:`collect` gathers random rollouts in worker
processes (thesis 4.2.3), resumably; every episode's seeds come from :func:`episode_seeds`."""
from __future__ import annotations

import atexit
import multiprocessing as mp
import os
import signal
import threading
from collections import deque
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from itertools import islice
from pathlib import Path

import numpy as np
from tqdm import tqdm

from wmthesis.core import Callback, RandomMind, loop
from wmthesis.data import EpisodeStore
from wmthesis.envs import ATARI_GAMES, make_env
from wmthesis.utils import derive_seeds

_WORKER: dict = {}


class EpisodeBuffer(Callback):
    """Buffers the current episode's steps; after ``on_episode_end`` its arrays are in
    :attr:`episode` (the keyword arguments of :meth:`EpisodeStore.append_episode`)."""

    def __init__(self):
        self.episode: dict[str, np.ndarray] | None = None
        self._steps: list = []

    def on_episode_start(self, episode, train_mode):
        self._steps = []

    def on_step_taken(self, step, transition, info):
        self._steps.append((np.array(transition.state, copy=True), transition.action,
                            transition.reward, transition.is_terminal))

    def on_episode_end(self, episode, train_mode):
        self.episode = self._arrays() if self._steps else None
        self._steps = []

    def on_loop_end(self, is_aborted):
        self._steps = []  # a partial episode is dropped

    def _arrays(self) -> dict[str, np.ndarray]:
        states, actions, rewards, terminals = zip(*self._steps)
        return {"observations": np.stack(states), "actions": np.array(actions, np.int64),
                "rewards": np.array(rewards, np.float32), "terminals": np.array(terminals, np.bool_)}


class EpisodeRecorder(EpisodeBuffer):
    """A :func:`~wmthesis.core.loop` callback that writes each finished episode to `store`.

    Steps are buffered in memory and the whole episode is appended at ``on_episode_end``
    (also for episodes cut by ``max_steps``); a partial episode left by an aborted loop is
    dropped. Metrics: ``episodes_written`` and ``steps_written`` so far.
    """

    def __init__(self, store: EpisodeStore):
        super().__init__()
        self.store = store
        self.episodes_written = 0
        self.steps_written = 0

    def on_episode_end(self, episode, train_mode):
        super().on_episode_end(episode, train_mode)
        if self.episode is not None:
            self.store.append_episode(**self.episode)
            self.episodes_written += 1
            self.steps_written += len(self.episode["actions"])
            self.episode = None

    @property
    def metrics(self) -> dict:
        return {"episodes_written": self.episodes_written, "steps_written": self.steps_written}


# ---------------------------------------------------------------------------- collection
def collect(env_name: str, episodes: int, out: str | os.PathLike, *, workers: int = 1, seed: int = 0,
            preprocessing: str | None = None, max_steps: int | None = None, progress: bool = True,
            **env_options) -> Path:
    """Random rollouts of `env_name` into the store at `out` until it holds `episodes` episodes.

    Episode ``i`` is played by :class:`~wmthesis.core.RandomMind` with the environment reset
    and the actions seeded from ``SeedSequence([seed, i])``, so the store does not depend on
    `workers`, and re-running resumes: a store with ``k`` complete episodes only collects
    episodes ``k .. episodes-1`` (its env, preprocessing, seed and options must match).
    ``workers > 1`` plays episodes in that many spawned processes; the parent writes them in
    episode order. `preprocessing` defaults to ``world_models`` for Atari games; Sokoban
    takes none. `max_steps` and `env_options` go to :func:`wmthesis.envs.make_env`.
    Ctrl-C stops the workers and keeps every episode completed so far (then re-raises).
    Returns the store's path.
    """
    if episodes < 0 or workers < 1:
        raise ValueError(f"need episodes >= 0 and workers >= 1, got {episodes}, {workers}")
    options = _collect_options(env_name, preprocessing, max_steps, env_options)
    obs_shape = _observation_shape(env_name, options)
    out = Path(out)
    with EpisodeStore(out, "a", env=env_name, preprocessing=options.get("preprocessing", "none"),
                      seed=seed, obs_shape=obs_shape, env_options=options) as store:
        todo = range(len(store), episodes)
        with tqdm(total=episodes, initial=len(store), unit="episode", desc=f"collect {env_name}",
                  disable=not progress or not todo) as bar:
            rollouts = _rollouts(env_name, options, seed, todo, workers)
            try:
                with _interrupt_between_episodes() as interrupted:
                    for rollout in rollouts:
                        store.append_episode(**rollout)
                        bar.update()
                        bar.set_postfix(steps=store.num_steps, refresh=False)
                        if interrupted():
                            raise KeyboardInterrupt
            except KeyboardInterrupt:  # what was kept, for the one line the caller says
                raise KeyboardInterrupt(f"{out} keeps {len(store)} complete episodes") from None
            finally:
                rollouts.close()
    return out


@contextmanager
def _interrupt_between_episodes():
    """Defer the first Ctrl-C to the end of the episode being written: yields a function that
    says whether one came. A KeyboardInterrupt raised inside the process pool's locks and waits
    can hang its shutdown; a second Ctrl-C still interrupts at once. Outside the main thread
    (where signals cannot be handled) nothing is deferred."""
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    came = threading.Event()

    def defer(signum, frame):
        came.set()
        signal.signal(signal.SIGINT, signal.default_int_handler)

    previous = signal.signal(signal.SIGINT, defer)
    try:
        yield came.is_set
    finally:
        signal.signal(signal.SIGINT, previous)


def _collect_options(env_name: str, preprocessing: str | None, max_steps: int | None,
                     env_options: dict) -> dict:
    """The keyword arguments of :func:`~wmthesis.envs.make_env` for a collection."""
    options = dict(env_options)
    if env_name in ATARI_GAMES:
        options["preprocessing"] = preprocessing or "world_models"
    elif preprocessing not in (None, "none"):
        raise ValueError(f"{env_name!r} takes no preprocessing, got {preprocessing!r}")
    if max_steps is not None:
        options["max_steps"] = max_steps
    return options


def _observation_shape(env_name: str, options: dict) -> tuple[int, ...]:
    """Make the environment once (checking the options) and return its observation shape."""
    env = make_env(env_name, **options)
    try:
        return tuple(env.observation_space.shape)
    finally:
        env.close()


def _rollouts(env_name: str, options: dict, seed: int, indices: range, workers: int):
    """Generator of the episodes `indices`, in order, played here or in worker processes."""
    if not indices:
        return
    if min(workers, len(indices)) == 1:
        from wmthesis.envs import make_env

        env = make_env(env_name, **options)
        try:
            for index in indices:
                yield play_random_episode(env, seed, index)
        finally:
            env.close()
        return
    yield from _parallel_rollouts(env_name, options, seed, indices, min(workers, len(indices)))


def _parallel_rollouts(env_name: str, options: dict, seed: int, indices: range, workers: int):
    """Episodes `indices` in order from `workers` spawned processes (safe whatever threads the
    parent runs: torch, OpenCV, tqdm), at most two episodes in flight per worker."""
    pool = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"),
                               initializer=_init_worker, initargs=(env_name, options, seed))
    todo = iter(indices)
    try:
        pending = deque(pool.submit(_play_in_worker, index) for index in islice(todo, 2 * workers))
        while pending:
            try:
                rollout = pending.popleft().result()
            except BrokenProcessPool as error:
                raise RuntimeError(
                    "a collect worker process died; if none could start, the main script could not be "
                    "imported by the spawned workers (run it from a file with an "
                    "`if __name__ == '__main__':` guard, not from standard input)") from error
            pending.extend(pool.submit(_play_in_worker, index) for index in islice(todo, 1))
            yield rollout
    finally:  # also on Ctrl-C or an error: drop queued episodes, let running ones end
        pool.shutdown(wait=True, cancel_futures=True)


def _init_worker(env_name: str, options: dict, seed: int) -> None:
    """Make the worker's environment once. Ctrl-C is left to the parent, and the worker exits
    when the parent dies (even by SIGKILL) instead of waiting for work forever."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent = mp.parent_process()
    if parent is not None:
        threading.Thread(target=_exit_with, args=(parent,), daemon=True).start()
    _WORKER.update(env=make_env(env_name, **options), seed=seed)
    atexit.register(_close_worker_env)


def _close_worker_env() -> None:
    """Close and drop the worker's environment before the interpreter tears ale-py down."""
    env = _WORKER.pop("env", None)
    if env is not None:
        env.close()


def _exit_with(parent) -> None:
    parent.join()
    os._exit(1)


def _play_in_worker(index: int) -> dict[str, np.ndarray]:
    return play_random_episode(_WORKER["env"], _WORKER["seed"], index)


def play_random_episode(env, seed: int, index: int) -> dict[str, np.ndarray]:
    """Episode `index` of a collection seeded with `seed`: random actions, the env reset and
    the actions seeded from ``SeedSequence([seed, index])``. Returns the arrays of
    :meth:`EpisodeStore.append_episode`."""
    env_seed, mind_seed = episode_seeds(seed, index)
    buffer = EpisodeBuffer()
    loop(env, RandomMind(env.action_space.n, seed=mind_seed), seed=env_seed, callbacks=[buffer])
    return buffer.episode


def episode_seeds(seed: int, index: int) -> tuple[int, int]:
    """The (environment reset, random actions) seeds of episode `index` of a collection."""
    env_seed, mind_seed = derive_seeds(seed, index, n=2)
    return int(env_seed), int(mind_seed)


__all__ = ["EpisodeBuffer", "EpisodeRecorder", "collect", "play_random_episode", "episode_seeds"]
