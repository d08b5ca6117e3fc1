"""Everything the agent experienced, in one HDF5 file: the model's transitions and the value's labels.

Groups by kind and board shape (boards of several sizes train the same networks):

- ``transitions/HxW``: ``states``, ``next_states`` uint8 (N, h, w), ``actions`` uint8 (N,),
  ``rewards`` float32 (N,), ``dones`` bool (N,), ``rounds`` int16 (N,) (0: random play);
- ``to_go/HxW``: ``states`` uint8 (N, h, w), ``labels`` float32 (N,) steps to the end, from the
  levels the agent solved; ``rounds`` int16 (N,);
- ``solutions/HxW``: ``states`` uint8 (N, h, w), ``actions`` uint8 (N,) the action the agent
  then played, from the levels it solved; ``rounds`` int16 (N,) (older files
  have none);
- ``backed_up/HxW``: ``states`` uint8 (N, h, w) its searches expanded, ``labels`` float32 (N,)
  their backed-up steps to go (runs that keep them); ``rounds`` int16 (N,).

States are the env's grid observations (the board's inner cells); pixel frames are their
rendering (:func:`wmthesis.envs.sokoban.grid_frames` is exact), so they are not stored twice.
Rows are appended and flushed a round at a time; :meth:`Experience.drop_rounds` removes a round
that was cut off, so a resumed run adds it once.
"""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

FIELDS = {"transitions": ("states", "actions", "next_states", "rewards", "dones"),
          "to_go": ("states", "labels"),
          "solutions": ("states", "actions"),
          "backed_up": ("states", "labels")}


class Experience:
    """``add(kind, round, **arrays)``, ``arrays(kind, shape=None)``; a context manager."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self.file = h5py.File(self.path, "a")
        except OSError as error:
            raise OSError(f"cannot open experience file {self.path}: {error}; delete it to start over") from error

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        self.file.close()

    def add(self, kind: str, round_: int, **arrays) -> None:
        """Append rows of ``kind`` (``transitions`` or ``to_go``), all of one board shape."""
        fields = FIELDS[kind]
        if sorted(arrays) != sorted(fields):
            raise ValueError(f"{kind} rows need {fields}, got {sorted(arrays)}")
        n = len(arrays["states"])
        if n == 0:
            return
        h, w = arrays["states"].shape[1:]
        group = self.file.require_group(f"{kind}/{h}x{w}")
        for name, values in [*arrays.items(), ("rounds", np.full(n, round_, np.int16))]:
            values = np.asarray(values)
            if name not in group:
                group.create_dataset(name, data=values, maxshape=(None, *values.shape[1:]), chunks=True,
                                     compression="gzip", compression_opts=1)
            else:
                data = group[name]
                data.resize(len(data) + n, axis=0)
                data[-n:] = values
        self.file.flush()

    def arrays(self, kind: str, shape: tuple[int, int] | None = None) -> dict[str, dict[str, np.ndarray]]:
        """``{"HxW": {field: array}}`` of ``kind``, for one ``shape`` or all."""
        if kind not in self.file:
            return {}
        keys = [f"{shape[0]}x{shape[1]}"] if shape is not None else list(self.file[kind])
        return {k: {name: self.file[kind][k][name][()] for name in self.file[kind][k]}
                for k in keys if k in self.file[kind]}

    def solutions(self) -> dict[str, dict[str, np.ndarray]]:
        """Every (state, action) along the levels solved in the rounds, ``{"HxW": {"states",
        "actions"}}``: the ``solutions`` rows, or for a store written before they were kept, the
        same read off the transitions. A solved play's rows are consecutive and end with the
        only ``done`` of the play, and its ``to_go`` rows (labels T, T-1, ..., 1) are its states
        in order, solved plays in the same order."""
        kept = self.arrays("solutions")
        if kept:
            return {k: {"states": g["states"], "actions": g["actions"]} for k, g in kept.items()}
        found = {}
        for key, labelled in self.arrays("to_go").items():
            moves = self.arrays("transitions", tuple(int(n) for n in key.split("x")))[key]
            ends = np.flatnonzero(moves["dones"] & (moves["rounds"] > 0))
            starts = np.flatnonzero(np.r_[True, np.diff(labelled["labels"]) != -1])
            if len(ends) != len(starts):
                raise ValueError(f"{self.path}: {len(starts)} solved plays of {key} labelled, {len(ends)} in the transitions")
            rows = np.concatenate([np.arange(end - int(labelled["labels"][start]) + 1, end + 1)
                                   for start, end in zip(starts, ends)]) if len(ends) else np.zeros(0, int)
            if not np.array_equal(moves["states"][rows], labelled["states"]):
                raise ValueError(f"{self.path}: the labelled states of {key} are not the solved plays' transitions")
            found[key] = {"states": moves["states"][rows], "actions": moves["actions"][rows]}
        return found

    def count(self, kind: str = "transitions", round_: int | None = None) -> int:
        """Rows of ``kind`` (of one round, if given)."""
        total = 0
        for group in self.arrays(kind).values():
            total += len(group["rounds"]) if round_ is None else int((group["rounds"] == round_).sum())
        return total

    def drop_rounds(self, first: int) -> None:
        """Remove every row of round ``first`` and later (a round cut off before its checkpoint)."""
        for kind in FIELDS:
            for key, group in self.arrays(kind).items():
                keep = group["rounds"] < first
                if keep.all():
                    continue
                del self.file[kind][key]
                if keep.any():
                    rows = {name: group[name][keep] for name in FIELDS[kind]}
                    self.add(kind, 0, **rows)
                    self.file[kind][key]["rounds"][:] = group["rounds"][keep]
        self.file.flush()


__all__ = ["Experience", "FIELDS"]
