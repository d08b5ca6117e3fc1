"""The schema of a run's ``metrics.json``, versioned and checked where it is read back (jsonschema).

A run writes its header with ``schema_version`` (:data:`METRICS_VERSION`); files written before
the field existed are version 1, the same shape. What a reader relies on is checked: the
experiment, profile and seed, the date, machine, threads and wall times, each number finite
(JSON's ``NaN`` and ``Infinity`` parse to floats, which jsonschema's "number" would take). A file
that fails is refused in one line naming the file and the field:

    check_metrics(json.loads(path.read_text()), path)   # ValueError: "...metrics.json: seed: -5 is ..."
"""
from __future__ import annotations

import math
from pathlib import Path

from wmthesis.config import PROFILES
from wmthesis.utils import MAX_SEED

METRICS_VERSION = 1
_SECONDS = {"type": "number", "minimum": 0}
METRICS_SCHEMA = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "wmthesis metrics.json",
    "type": "object",
    "required": ["experiment", "profile", "seed"],
    "properties": {
        "schema_version": {"const": METRICS_VERSION},
        "experiment": {"type": "string", "minLength": 1},
        "variant": {"type": ["string", "null"]},
        "profile": {"enum": list(PROFILES)},
        "seed": {"type": "integer", "minimum": 0, "maximum": MAX_SEED},
        "date": {"type": "string", "pattern": r"^\d{4}-\d{2}-\d{2}"},
        "machine": {"type": ["string", "null"]},
        "threads": {"type": ["integer", "null"], "minimum": 1},
        "wall_seconds": _SECONDS,
        "first_run_wall_seconds": _SECONDS,
    },
}


def _finite_number(checker, instance) -> bool:
    """jsonschema's "number", less booleans, NaN and infinity."""
    return isinstance(instance, (int, float)) and not isinstance(instance, bool) and math.isfinite(instance)


def _validator():
    from jsonschema import Draft202012Validator, validators

    checker = Draft202012Validator.TYPE_CHECKER.redefine("number", _finite_number)
    return validators.extend(Draft202012Validator, type_checker=checker)(METRICS_SCHEMA)


def check_metrics(metrics, path: str | Path) -> dict:
    """``metrics`` (a parsed ``metrics.json``) if it fits :data:`METRICS_SCHEMA`; ValueError in one
    line naming ``path`` and the first field that does not. (Its score is read, and a NaN or
    infinite one refused, by :mod:`wmthesis.scores`; a diagnosis may hold NaN where it is undefined,
    a correlation of constants.)"""
    error = next(iter(sorted(_validator().iter_errors(metrics), key=lambda e: list(e.absolute_path))), None)
    if error is not None:
        field = ".".join(map(str, error.absolute_path)) or "(the file)"
        raise ValueError(f"{path}: {field}: {error.message}")
    return metrics


__all__ = ["METRICS_SCHEMA", "METRICS_VERSION", "check_metrics"]
