"""How the experiments write their results: the header of every ``metrics.json``, figures,
JSON caches, episodes saved one by one as they end, the wall time of the first run."""
from __future__ import annotations

import json
import os
import platform
from collections.abc import Callable
from datetime import date
from pathlib import Path

import numpy as np

from wmthesis.utils import atomic_path, parallel_calls


def _run_header(experiment: str, profile: str, seed: int, seconds: float, **run) -> dict:
    """The first entries of a ``metrics.json``: the experiment, ``run``'s own (its variant, ...),
    profile and seed, today's date, this machine, its torch threads (a seed repeats its curve on
    a CPU only with the same number: reductions split differently) and the wall time of ``seconds``."""
    import torch

    return {"experiment": experiment, **run, "profile": profile, "seed": seed, "date": date.today().isoformat(),
            "machine": f"{platform.node()} ({platform.machine()}, {os.cpu_count()} cores)",
            "threads": torch.get_num_threads(), "wall_seconds": round(seconds, 1)}


def _first_run_seconds(path: Path, seconds: float) -> float:
    """The wall time of the run that computed everything: kept from an earlier metrics file at
    ``path`` (its ``first_run_wall_seconds``, or the ``wall_seconds`` of a file written before
    that field; a resumed or cached run is faster), else this run's ``seconds``."""
    try:
        earlier = json.loads(path.read_text())
        return float(earlier.get("first_run_wall_seconds", earlier["wall_seconds"]))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return seconds


def same_training(cached: dict | None, run: dict) -> bool:
    """Whether a cached ``metrics.json`` was written for this PlaNet training (``run`` as
    :func:`~wmthesis.planet.train.train_planet` returns it): the same updates and the same
    training curve, so a model retrained to the same length is evaluated again."""
    return (cached is not None and cached.get("updates") == run["updates"]
            and cached.get("curve") == json.loads(json.dumps(run["curve"])))  # as a metrics file holds it


def _read_json(path: Path) -> dict | None:
    """A cached JSON file, or None when it is missing or corrupt (the step runs again)."""
    try:
        return json.loads(path.read_text()) if path.is_file() else None
    except ValueError:
        return None


def _jsonable(value):
    """``value`` with numpy arrays and scalars as lists and numbers, NaN as None (strict JSON)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.integer, np.bool_)):
        return value.item()
    if isinstance(value, (float, np.floating)):
        return None if not np.isfinite(value) else float(value)
    return value


def played_bouts(path: Path, key: dict, progress: bool, calls: list[tuple],
                 read_key: Callable[[dict], dict] | None = None) -> list[dict]:
    """``calls`` (one bout each), each bout saved in ``path`` as it ends: a run cut off plays
    only the bouts it had not finished (those saved for the same ``key``, :func:`cached_for`)."""
    return played_groups([(path, key, calls, read_key)], progress)[0]


def played_groups(groups: list[tuple], progress: bool, executor=None) -> list[list[dict]]:
    """:func:`played_bouts` for each ``(path, key, calls, read_key)`` of ``groups``, all in one
    pool (``executor``, a :func:`~wmthesis.utils.process_pool`; two at a time by default),
    submitted group by group: the first groups end first. Returns each group's plays."""
    done, todo = [], []
    for g, (path, key, calls, read_key) in enumerate(groups):
        saved = cached_for(path, key, read_key)
        done.append({int(i): play for i, play in (saved or {}).get("plays", {}).items()})
        todo += [(g, i) for i in range(len(calls)) if i not in done[g]]

    def save(index: int, play: dict) -> None:
        g, i = todo[index]
        done[g][i] = play
        with atomic_path(groups[g][0]) as tmp:
            tmp.write_text(json.dumps({"key": groups[g][1], "plays": done[g]}, indent=1))

    parallel_calls([groups[g][2][i] for g, i in todo], progress, on_done=save, executor=executor)
    return [[done[g][i] for i in range(len(calls))] for g, (_, _, calls, _) in enumerate(groups)]


def cached_for(path: Path, key: dict, read_key: Callable[[dict], dict] | None = None) -> dict | None:
    """The JSON cache at ``path`` if it was written for ``key``, else None. ``read_key`` brings a
    saved key up to date first (a config saved before a field was added reads as what it did)."""
    cached = _read_json(path)
    if cached is None or not isinstance(cached.get("key"), dict):
        return None
    saved = dict(cached["key"]) if read_key is None else read_key(dict(cached["key"]))
    return cached if saved == key else None
