"""How the experiments write their results: the header of every ``metrics.json``, figures,
JSON caches, the wall time of the first run."""
from __future__ import annotations

import json
import os
import platform
from datetime import date
from pathlib import Path

import numpy as np


def _run_header(experiment: str, profile: str, seed: int, seconds: float, **run) -> dict:
    """The first entries of a ``metrics.json``: the experiment, ``run``'s own (its variant, ...),
    profile and seed, today's date, this machine and the wall time of ``seconds``."""
    return {"experiment": experiment, **run, "profile": profile, "seed": seed, "date": date.today().isoformat(),
            "machine": f"{platform.node()} ({platform.machine()}, {os.cpu_count()} cores)",
            "wall_seconds": round(seconds, 1)}


def _first_run_seconds(path: Path, seconds: float) -> float:
    """The wall time of the run that computed everything: kept from an earlier metrics file at
    ``path`` (its ``first_run_wall_seconds``, or the ``wall_seconds`` of a file written before
    that field; a resumed or cached run is faster), else this run's ``seconds``."""
    try:
        earlier = json.loads(path.read_text())
        return float(earlier.get("first_run_wall_seconds", earlier["wall_seconds"]))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return seconds


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
