"""Played games: the :class:`Game` record, the seeds of a game, and :class:`Replay`, the latest
games kept in memory and in an HDF5 file beside the self-play checkpoint.

The checkpoint names the games of the replay by their serial numbers (the order in which they
entered it) and never holds the games themselves: in the ``thesis`` profile the replay is
1,000 full Boxing games, about 2 GB, which a pickled checkpoint would rewrite after every
training round. In the HDF5 file each game is a group ``games/<serial>``, written whole and
flushed as it is played; games that left the window are deleted once a checkpoint no longer
names them (HDF5 reuses their space while the file stays open). A resumed run writes the file
anew with its checkpoint's games, so games played after the checkpoint go, and so does the
space of deleted ones.
"""
from __future__ import annotations

import dataclasses
import os
from collections import deque
from pathlib import Path

import h5py
import numpy as np

from wmthesis.runs import atomic_path
from wmthesis.utils import derive_seeds

REPLAY_NAME = "replay.h5"
FORMAT = "wmthesis-replay"
_ARRAYS = ("features", "policies", "actions", "rewards", "predicted_rewards", "root_values", "depths", "q",
           "last_features", "frames")
_SCALARS = ("index", "terminated", "seconds")


@dataclasses.dataclass
class Game:
    """One played game, for training and diagnosis; T steps, F = L + H features, A actions.

    ``features`` (T, F): the roots' ``[z_t h_{t-1}]``; ``policies`` (T, A): root visit
    distributions (the policy targets); ``actions``, ``rewards`` (T,): what happened in the real
    game; ``predicted_rewards`` (T,): the memory's reward for each real step; ``root_values``,
    ``depths`` (T,) and ``q`` (T, A): search statistics (``q`` nan where unvisited);
    ``terminated``: the game ended (not cut by ``max_steps``); ``last_features`` (F,): the state
    after the last step (bootstraps a cut game); ``frames``: the observations, when kept.
    """

    index: int
    features: np.ndarray
    policies: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    predicted_rewards: np.ndarray
    root_values: np.ndarray
    depths: np.ndarray
    q: np.ndarray
    terminated: bool
    last_features: np.ndarray
    seconds: float
    frames: np.ndarray | None = None

    @property
    def score(self) -> float:
        return float(self.rewards.sum())

    def __len__(self) -> int:
        return len(self.rewards)


def game_seeds(seed: int) -> tuple[int, int]:
    """The seeds of the game seeded with ``seed``: the env's reset (and the policy's sampling),
    and the search's noise; non-negative 31-bit ints."""
    env_seed, search_seed = (int(s) >> 1 for s in derive_seeds(seed, n=2))
    return env_seed, search_seed


class Replay:
    """The latest ``capacity`` :class:`Game` records: iterable, sized, ``append`` / ``extend``.

    In memory until :meth:`attach` gives it a file: from then on every appended game is
    written there at once, and :attr:`serials` names the games of the window for the
    checkpoint. :meth:`load` reads back the games a checkpoint names.
    """

    def __init__(self, capacity: int, games=(), serials=(), next_serial: int = 0):
        if capacity < 1:
            raise ValueError(f"a replay holds at least one game, got capacity {capacity}")
        self.capacity, self.next_serial = capacity, next_serial
        self.games: deque = deque(games, maxlen=capacity)
        self.serials: deque = deque(serials, maxlen=capacity)
        self.path: Path | None = None
        self._file: h5py.File | None = None

    @classmethod
    def load(cls, path: str | os.PathLike, capacity: int, serials, next_serial: int) -> "Replay":
        """The games ``serials`` of the replay file at ``path`` (read only)."""
        serials = list(serials)[-capacity:]
        try:
            with h5py.File(path, "r") as f:
                group = f["games"]
                missing = [s for s in serials if str(s) not in group]
                if missing:
                    raise ValueError(f"{path} lacks games {missing[:5]} that the checkpoint names")
                games = [_read_game(group[str(s)]) for s in serials]
        except (OSError, KeyError, ValueError) as error:
            raise ValueError(f"{path}: cannot read the self-play replay ({error}); delete it and the checkpoint "
                             "beside it to start self-play again") from error
        return cls(capacity, games, serials, next_serial)

    def attach(self, path: str | os.PathLike) -> None:
        """From now on keep the games in the HDF5 file ``path``: it is written anew with the
        games held now (anything else there, e.g. games played after the last checkpoint,
        goes), then kept open for appending."""
        self.close()
        with atomic_path(path) as tmp:
            with h5py.File(tmp, "w", libver="earliest") as f:
                f.attrs["format"] = FORMAT
                group = f.create_group("games")
                for serial, game in zip(self.serials, self.games):
                    _write_game(group.create_group(str(serial)), game)
        self.path, self._file = Path(path), h5py.File(path, "a", libver="earliest")

    def append(self, game: Game) -> None:
        serial, self.next_serial = self.next_serial, self.next_serial + 1
        if self._file is not None:
            _write_game(self._file["games"].create_group(str(serial)), game)
            self._file.flush()
        self.games.append(game)
        self.serials.append(serial)

    def extend(self, games) -> None:
        for game in games:
            self.append(game)

    def prune(self) -> None:
        """Delete the games that left the window; call it once a checkpoint naming
        :attr:`serials` is written (until then, the last checkpoint's games must stay)."""
        if self._file is not None:
            group = self._file["games"]
            for name in set(group) - {str(s) for s in self.serials}:
                del group[name]
            self._file.flush()

    def __iter__(self):
        return iter(self.games)

    def __len__(self) -> int:
        return len(self.games)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def _write_game(group: h5py.Group, game: Game) -> None:
    for key in _ARRAYS:
        value = getattr(game, key)
        if value is not None:
            group.create_dataset(key, data=np.asarray(value))
    for key in _SCALARS:
        group.attrs[key] = getattr(game, key)


def _read_game(group: h5py.Group) -> Game:
    arrays = {key: group[key][()] for key in _ARRAYS if key in group}
    scalars = {key: group.attrs[key].item() for key in _SCALARS}
    return Game(**arrays, index=int(scalars["index"]), terminated=bool(scalars["terminated"]),
                seconds=float(scalars["seconds"]))
