"""Episodes on disk: an HDF5 episode store and chunk sampling (recording and collecting them:
:mod:`wmthesis.rollouts`).

:class:`EpisodeStore` keeps whole episodes in one HDF5 file. Row ``t`` of an episode holds
the observation ``o_t`` seen before acting, the action ``a_t``, the reward ``r_{t+1}`` and
the terminal flag after the action (the observation after the last action is not stored).
Datasets (``N`` rows, ``E`` episodes)::

    observations    uint8 (N, *obs_shape)  LZ4-compressed chunks of CHUNK_STEPS rows
    actions         int64 (N,)
    rewards         float32 (N,)
    terminals       bool (N,)
    episode_starts  int64 (E,)   first row of each episode
    episode_ends    int64 (E,)   one past its last row

Episodes start on a chunk boundary (the rows between two episodes are zero padding), so a
compressed chunk that holds a stored episode is written once and never rewritten. Appending
writes the episode's rows, flushes, and only then commits it by appending to
``episode_ends`` (and flushes again): a crash, even SIGKILL, loses at most the episode being
written. On opening, rows past the last committed episode are ignored ("r") or trimmed ("a"),
and the file uses the original (version 0) superblock, which has no "open for writing"
flags for a killed writer to leave behind (newer superblocks would need ``h5clear``).

:meth:`EpisodeStore.sample_chunks` draws sequence chunks for the memory models (PlaNet: 50
chunks of 50 steps) with their observations read from the file, never copied whole into memory
(the store may be larger than memory; only actions, rewards and terminals, 13 bytes a step, are
cached).
"""
from __future__ import annotations

import json
import os
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path

import h5py
import hdf5plugin
import numpy as np
import torch

from wmthesis.runs import atomic_path, check_space
from wmthesis.utils import check_choice

FORMAT = "wmthesis-episodes"
FORMAT_VERSION = 1
CHUNK_STEPS = 16            # observation rows per compressed chunk (12 KiB frames: 192 KiB)
SCALAR_CHUNK = 4096         # rows per chunk of the uncompressed per-step datasets
CACHE_BYTES = 16 * 2**20    # HDF5 chunk cache per open store
LIBVER = ("earliest", "v110")  # superblock v0: no "open for writing" flags a killed writer could leave
STEP_DATASETS = {"observations": np.uint8, "actions": np.int64, "rewards": np.float32,
                 "terminals": np.bool_}
SCALARS = ("actions", "rewards", "terminals")
INDEX_DATASETS = ("episode_starts", "episode_ends")
MODES = ("r", "a")
# Settings that must match when a store is reopened for appending (None: not checked).
CHECKED_ATTRS = ("env", "preprocessing", "seed", "obs_shape", "env_options")


class StoreError(OSError):
    """The file is not a readable episode store (corrupt, truncated, not a store, in use)."""


class EpisodeStore:
    """Whole episodes in one HDF5 file (see the module docstring for the layout).

    ``mode="r"`` reads an existing store; ``mode="a"`` creates one or appends to it. When
    creating, ``obs_shape`` is required and ``env``, ``preprocessing``, ``seed`` and
    ``env_options`` (a JSON-able dict) are stored as file attributes, with the versions of
    the libraries and the creation time. When reopening, each of those given (not None) must
    equal the stored one, else ``ValueError``.

    Errors name the file: ``FileNotFoundError`` (missing in "r" mode), :class:`StoreError`
    (corrupt, not a store, or held by a live writer), ``ValueError`` (settings or episode
    mismatch). `chunk_steps` (observation rows per compressed chunk) applies when creating;
    `cache_bytes` sizes HDF5's chunk cache. Use as a context manager or call :meth:`close`.

    ``len(store)`` complete episodes; :attr:`num_steps`, :attr:`episode_lengths`,
    :attr:`attrs`; :meth:`episode`, :meth:`sample_chunks`, :meth:`append_episode`.
    """

    def __init__(self, path: str | os.PathLike, mode: str = "r", *, env: str | None = None,
                 preprocessing: str | None = None, seed: int | None = None,
                 obs_shape: tuple[int, ...] | None = None, env_options: dict | None = None,
                 chunk_steps: int = CHUNK_STEPS, cache_bytes: int = CACHE_BYTES):
        check_choice("store mode", mode, MODES)
        self.path = Path(path)
        self.mode = mode
        self._cache_bytes = int(cache_bytes)
        wanted = dict(env=env, preprocessing=preprocessing, seed=seed,
                      obs_shape=None if obs_shape is None else tuple(int(n) for n in obs_shape),
                      env_options=None if env_options is None else _json(env_options))
        if not self.path.exists():
            if mode == "r":
                raise FileNotFoundError(f"{self.path}: no such episode store")
            _create_store(self.path, wanted, int(chunk_steps))
        self._file = self._open("r")  # a store that is rejected is not even opened for writing
        try:
            self._check_format()
            self._check_wanted(wanted)
            if mode == "a":
                self._file.close()
                self._file = self._open("r+")
                self._check_format()
            self._load_index()
            if mode == "a":
                self._trim()
        except BaseException:
            self._file.close()
            raise

    # ------------------------------------------------------------------ opening
    def _open(self, mode: str) -> h5py.File:
        try:
            return h5py.File(self.path, mode, libver=LIBVER, rdcc_nbytes=self._cache_bytes,
                             rdcc_nslots=100_003)
        except OSError as error:
            if "unable to lock file" in str(error):
                raise StoreError(f"{self.path} is open for writing in another process (HDF5's file lock: {error}); "
                                 "wait for that run to end, or use another file") from error
            raise StoreError(f"{self.path}: cannot open as an HDF5 episode store ({error}); if it is truncated "
                             "or corrupt, delete it and run again to collect it anew") from error

    def _check_format(self) -> None:
        f = self._file
        if f.attrs.get("format") != FORMAT:
            raise StoreError(f"{self.path}: not a wmthesis episode store (no format={FORMAT!r} attribute)")
        missing = [name for name in (*STEP_DATASETS, *INDEX_DATASETS) if name not in f]
        missing += [f"attribute {key}" for key in ("chunk_steps", "obs_shape") if key not in f.attrs]
        if missing:
            raise StoreError(f"{self.path}: episode store lacks {', '.join(missing)}")
        for name, dtype in STEP_DATASETS.items():
            if f[name].dtype != dtype:
                raise StoreError(f"{self.path}: dataset {name!r} has dtype {f[name].dtype}, "
                                 f"expected {np.dtype(dtype)}")
        self.chunk_steps = int(f.attrs["chunk_steps"])
        self.obs_shape = tuple(int(n) for n in f.attrs["obs_shape"])
        self._data = {name: f[name] for name in STEP_DATASETS}
        self._scalar_cache = {name: np.empty(0, STEP_DATASETS[name]) for name in SCALARS}

    def _check_wanted(self, wanted: dict) -> None:
        stored = self.attrs
        for key in CHECKED_ATTRS:
            want, have = wanted[key], stored.get(key)
            if key == "env_options" and have is not None:
                have = _json(have)
            if want is not None and want != have:
                raise ValueError(f"{self.path}: the store has {key}={have!r} but {want!r} was asked for; "
                                 "use another path or the store's settings")

    def _load_index(self) -> None:
        """Read the committed episodes: the longest valid prefix of (starts, ends)."""
        starts = self._file["episode_starts"][:]
        ends = self._file["episode_ends"][:]
        count = min(len(starts), len(ends))
        starts, ends = starts[:count].astype(np.int64), ends[:count].astype(np.int64)
        rows = min(len(d) for d in self._data.values())
        expected = _align(np.concatenate([[0], ends[:-1]]), self.chunk_steps)[:count]
        valid = (starts == expected) & (starts < ends) & (ends <= rows)
        committed = count if valid.all() else int(np.argmin(valid))
        self._starts, self._ends = starts[:committed], ends[:committed]

    def _trim(self) -> None:
        """Drop what a crashed writer left past the last committed episode ("a" mode)."""
        rows = int(_align(self._ends[-1], self.chunk_steps)) if len(self) else 0
        try:
            for dataset in self._data.values():
                if len(dataset) > rows:
                    dataset.resize(rows, axis=0)
            for name in INDEX_DATASETS:
                if len(self._file[name]) > len(self):
                    self._file[name].resize(len(self), axis=0)
            self._file.flush()
        except (OSError, ValueError) as error:
            raise StoreError(f"{self.path}: cannot trim the rows after episode {len(self)} "
                             f"left by an interrupted write ({error}); open it in 'r' mode") from error

    # ------------------------------------------------------------------ reading
    def __len__(self) -> int:
        """Number of complete episodes."""
        return len(self._ends)

    @property
    def episode_lengths(self) -> np.ndarray:
        """Steps of each episode, int64 (E,)."""
        return self._ends - self._starts

    @property
    def num_steps(self) -> int:
        """Steps (rows) in all complete episodes."""
        return int(self.episode_lengths.sum())

    @property
    def attrs(self) -> dict:
        """The file's attributes as plain Python values (``obs_shape`` a tuple)."""
        out = {key: _plain(value) for key, value in self._file.attrs.items()}
        out["obs_shape"] = tuple(out["obs_shape"])
        if "env_options" in out:
            out["env_options"] = json.loads(out["env_options"])
        return out

    def episode(self, index: int) -> dict[str, np.ndarray]:
        """Episode `index` (negative counts from the end) as numpy arrays:
        ``observations`` (T, *obs_shape) uint8, ``actions`` (T,) int64, ``rewards`` (T,)
        float32, ``terminals`` (T,) bool."""
        if not -len(self) <= index < len(self):
            raise IndexError(f"{self.path}: episode {index} out of range ({len(self)} episodes)")
        rows = slice(int(self._starts[index]), int(self._ends[index]))
        try:
            return {name: dataset[rows] for name, dataset in self._data.items()}
        except OSError as error:
            raise self._corrupt(f"episode {index}", error) from None

    def sample_chunks(self, batch: int, length: int, generator: np.random.Generator,
                      episodes=None) -> dict[str, torch.Tensor]:
        """`batch` chunks of `length` consecutive steps, each within one episode.

        Start positions are uniform over all valid ones (an episode of T steps has
        T - length + 1) of all episodes or of those indexed by `episodes` (e.g. a training
        split), drawn with the numpy `generator`. Returns torch tensors: ``observations``
        (B, L, *obs_shape) uint8, ``actions`` (B, L) int64, ``rewards`` (B, L) float32,
        ``terminals`` (B, L) bool. Reads only those observations from the file.
        """
        rows = chunk_starts(self._starts, self._ends, batch, length, generator, episodes, where=self.path)
        observations = np.empty((batch, length, *self.obs_shape), np.uint8)
        for b in np.argsort(rows, kind="stable"):  # file order: neighbouring chunks stay cached
            source = np.s_[int(rows[b]):int(rows[b]) + length]
            try:
                self._data["observations"].read_direct(observations, source, np.s_[b])
            except OSError as error:
                raise self._corrupt(f"steps {int(rows[b])}-{int(rows[b]) + length - 1}", error) from None
        steps = rows[:, None] + np.arange(length)
        out = {name: torch.from_numpy(array[steps]) for name, array in self._scalars().items()}
        return {"observations": torch.from_numpy(observations), **out}

    def _corrupt(self, what: str, error: OSError) -> "StoreError":
        """The :class:`StoreError` of a read that HDF5 could not decode."""
        return StoreError(f"{self.path}: cannot read {what} ({error}); the file is damaged: "
                          "delete it and collect again")

    def _scalars(self) -> dict[str, np.ndarray]:
        """Actions, rewards and terminals of every row, kept in memory once read (13 bytes a
        step; reading them per chunk would double the sampling time). Observations never are."""
        rows = int(self._ends[-1]) if len(self) else 0
        cached = len(self._scalar_cache["actions"])
        if cached < rows:
            for name, array in self._scalar_cache.items():
                self._scalar_cache[name] = np.concatenate([array, self._data[name][cached:rows]])
        return self._scalar_cache

    # ------------------------------------------------------------------ writing
    def append_episode(self, observations, actions, rewards, terminals) -> int:
        """Write a whole episode of T steps; return its index.

        `observations` (T, *obs_shape) uint8, `actions` (T,) integers, `rewards` (T,) numbers,
        `terminals` (T,) bools of which only the last may be True. The episode counts (and
        survives a crash) only once everything is flushed.
        """
        if self.mode != "a":
            raise ValueError(f"{self.path}: opened read-only; use mode='a' to append")
        episode = self._validated(observations, actions, rewards, terminals)
        steps = len(episode["actions"])
        check_space(self.path.parent, sum(a.nbytes for a in episode.values()),
                    f"episode {len(self)} of {self.path.name} (the {len(self)} before it are kept)")
        start = int(_align(self._ends[-1], self.chunk_steps)) if len(self) else 0
        rows = int(_align(start + steps, self.chunk_steps))
        for name, data in episode.items():
            self._data[name].resize(rows, axis=0)
            self._data[name][start:start + steps] = data
        self._append_index("episode_starts", start)
        self._file.flush()
        self._append_index("episode_ends", start + steps)  # the commit
        self._file.flush()
        self._starts = np.append(self._starts, start)
        self._ends = np.append(self._ends, start + steps)
        return len(self) - 1

    def _append_index(self, name: str, value: int) -> None:
        dataset = self._file[name]
        dataset.resize(len(self) + 1, axis=0)
        dataset[len(self)] = value

    def _validated(self, observations, actions, rewards, terminals) -> dict[str, np.ndarray]:
        """Check shapes and dtypes of one episode; return arrays of the stored dtypes."""
        obs = np.asarray(observations)
        actions, rewards, terminals = (np.asarray(a) for a in (actions, rewards, terminals))
        steps = len(obs) if obs.ndim else 0
        if steps < 1 or obs.shape[1:] != self.obs_shape:
            raise ValueError(f"{self.path}: episode observations have shape {obs.shape}, "
                             f"expected (T >= 1, {', '.join(map(str, self.obs_shape))})")
        if obs.dtype != np.uint8:
            raise ValueError(f"{self.path}: episode observations have dtype {obs.dtype}, expected uint8")
        for name, array in (("actions", actions), ("rewards", rewards), ("terminals", terminals)):
            if array.shape != (steps,):
                raise ValueError(f"{self.path}: episode {name} have shape {array.shape}, expected ({steps},)")
        if actions.dtype.kind not in "iu":
            raise ValueError(f"{self.path}: episode actions have dtype {actions.dtype}, expected integers")
        if rewards.dtype.kind not in "iuf":
            raise ValueError(f"{self.path}: episode rewards have dtype {rewards.dtype}, expected numbers")
        if rewards.dtype.kind == "f" and not np.isfinite(rewards).all():
            raise ValueError(f"{self.path}: episode rewards hold NaN or infinity "
                             f"(step {int(np.argmin(np.isfinite(rewards)))} of {steps})")
        if terminals.dtype != np.bool_:
            raise ValueError(f"{self.path}: episode terminals have dtype {terminals.dtype}, expected bool")
        if terminals[:-1].any():
            raise ValueError(f"{self.path}: episode has a terminal step before its last one "
                             f"(step {int(np.argmax(terminals))} of {steps})")
        return {"observations": obs, "actions": actions.astype(np.int64),
                "rewards": rewards.astype(np.float32), "terminals": terminals}

    # ------------------------------------------------------------------ lifetime
    def close(self) -> None:
        """Flush and close the file (idempotent)."""
        if self._file.id.valid:
            self._file.close()

    def __enter__(self) -> "EpisodeStore":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        state = f"{len(self)} episodes, {self.num_steps} steps" if self._file.id.valid else "closed"
        return f"EpisodeStore({str(self.path)!r}, mode={self.mode!r}, {state})"


def chunk_starts(starts, ends, batch: int, length: int, generator: np.random.Generator,
                 episodes=None, where: str | os.PathLike = "episodes") -> np.ndarray:
    """First rows of `batch` chunks of `length` steps, uniform over all valid start positions.

    Episode ``i`` holds rows ``starts[i]:ends[i]`` (int arrays (E,)); only the episodes indexed
    by `episodes` (default: all) are drawn from, an episode of T steps offering T - length + 1
    starts. `generator` is a ``numpy.random.Generator``; `where` names the data in errors.
    Returns int64 (B,).
    """
    if not isinstance(generator, np.random.Generator):
        raise TypeError(f"generator must be a numpy.random.Generator, got {type(generator).__name__}")
    if batch < 1 or length < 1:
        raise ValueError(f"batch and length must be >= 1, got {batch}, {length}")
    starts, ends = np.asarray(starts, np.int64), np.asarray(ends, np.int64)
    chosen = np.arange(len(ends)) if episodes is None else np.asarray(episodes, np.int64).reshape(-1)
    if chosen.size and not (-len(ends) <= chosen.min() and chosen.max() < len(ends)):
        raise IndexError(f"{where}: episodes {chosen.min()}..{chosen.max()} asked for, "
                         f"out of range ({len(ends)} episodes)")
    lengths = ends[chosen] - starts[chosen]
    room = np.maximum(lengths - length + 1, 0)
    total = int(room.sum())
    if total == 0:
        scope = "" if episodes is None else " of those asked for"
        raise ValueError(f"{where}: no episode{scope} has {length} steps to sample a chunk from "
                         f"({len(chosen)} episodes, the longest has {int(lengths.max(initial=0))})")
    draws = generator.integers(0, total, size=batch)
    cumulative = np.cumsum(room)
    pick = np.searchsorted(cumulative, draws, side="right")
    return starts[chosen[pick]] + draws - (cumulative[pick] - room[pick])


# ---------------------------------------------------------------------------- file helpers
def _create_store(path: Path, wanted: dict, chunk_steps: int) -> None:
    """Write an empty store next to `path` and move it into place (never half-created)."""
    obs_shape = wanted["obs_shape"]
    if obs_shape is None:
        raise ValueError(f"{path}: creating an episode store needs obs_shape")
    if chunk_steps < 1:
        raise ValueError(f"chunk_steps must be >= 1, got {chunk_steps}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise StoreError(f"{path}: cannot create its folder ({error.strerror}); choose a folder you can write") from None
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise StoreError(f"{path}: its folder {path.parent} cannot be written; choose a folder you can write")
    with atomic_path(path) as tmp, h5py.File(tmp, "w", libver=LIBVER) as f:
        f.create_dataset("observations", shape=(0, *obs_shape), maxshape=(None, *obs_shape),
                         dtype=np.uint8, chunks=(chunk_steps, *obs_shape), **hdf5plugin.LZ4())
        for name in SCALARS:
            f.create_dataset(name, shape=(0,), maxshape=(None,), dtype=STEP_DATASETS[name],
                             chunks=(SCALAR_CHUNK,))
        for name in INDEX_DATASETS:
            f.create_dataset(name, shape=(0,), maxshape=(None,), dtype=np.int64, chunks=(1024,))
        f.attrs.update(_creation_attrs(wanted, chunk_steps))


def _creation_attrs(wanted: dict, chunk_steps: int) -> dict:
    attrs = {"format": FORMAT, "format_version": FORMAT_VERSION, "chunk_steps": chunk_steps,
             "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
             "hdf5_version": h5py.version.hdf5_version}
    for package in ("wmthesis", "numpy", "h5py", "gymnasium", "ale-py", "torch"):
        attrs[f"{package.replace('-', '_')}_version"] = _version(package)
    attrs.update({key: value for key, value in wanted.items() if value is not None})
    return attrs


def _version(package: str) -> str:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "not installed"


def _json(options: dict | str) -> str:
    """Options as canonical JSON (sorted keys) so that equal settings compare equal."""
    return json.dumps(json.loads(options) if isinstance(options, str) else options, sort_keys=True)


def _plain(value):
    """An HDF5 attribute value as a plain Python value."""
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _align(rows, chunk_steps: int):
    """Round `rows` (int or array) up to a multiple of `chunk_steps`."""
    return -(-np.asarray(rows) // chunk_steps) * chunk_steps




__all__ = ["EpisodeStore", "StoreError", "chunk_starts"]
