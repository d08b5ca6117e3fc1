"""Behaviour unchanged by the one-house move: every default (and each kept value variant) gives,
in smoke on seed 0 with one torch thread, the numbers it gave before the move (commit 7824a1b,
``tests/golden/``). Wall times and the published figures' wording are left out; everything
measured must agree: integers and strings exactly, floats (losses, errors, means) to a relative 1e-4 (the
last digits of float sums differ from one CPU's kernels to another's: recorded on an AMD EPYC,
the suite runs on Intel Xeons too). Run where the libraries are the versions the numbers were
recorded with (another version may draw other random numbers or step the games otherwise)."""
from __future__ import annotations

import importlib.metadata
import json
import math
from pathlib import Path

import pytest
import torch

from wmthesis.experiments import reproduce

GOLDEN = json.loads((Path(__file__).parent / "golden" / "smoke-seed0-7824a1b.json").read_text())
KEPT = ("score", "value", "value_planner", "agent", "random", "summary", "open_loop", "scores", "controller_curve", "curve",
        "tables", "boxoban")


def _measured(value):
    """``value`` without wall times (and times per action) and the references' wording, as JSON holds it."""
    if isinstance(value, dict):
        return {k: _measured(v) for k, v in value.items()
                if "seconds" not in k and "wall" not in k and "ms_per" not in k and k != "reference"}
    if isinstance(value, list):
        return [_measured(v) for v in value]
    return value


def _agrees(got, expected) -> bool:
    """``got`` as ``expected``: the same keys and lengths, integers and strings equal, floats within
    a relative 1e-4 (:mod:`math`'s ``isclose``)."""
    if isinstance(expected, dict):
        return isinstance(got, dict) and got.keys() == expected.keys() and all(_agrees(got[k], v) for k, v in expected.items())
    if isinstance(expected, list):
        return isinstance(got, list) and len(got) == len(expected) and all(map(_agrees, got, expected))
    if isinstance(expected, float) and isinstance(got, (int, float)) and not isinstance(got, bool):
        return math.isclose(got, expected, rel_tol=1e-4, abs_tol=1e-9)
    return got == expected


def _without_added(got, expected):
    """``got`` without the config fields added since the numbers were recorded (absent from
    ``expected``) that sit at None, the default that keeps the old behaviour."""
    if isinstance(got, dict) and isinstance(expected, dict):
        return {k: _without_added(v, expected.get(k)) for k, v in got.items() if k in expected or v is not None}
    if isinstance(got, list) and isinstance(expected, list):
        return [_without_added(g, e) for g, e in zip(got, expected)] + got[len(expected):]
    return got


@pytest.mark.skipif(any(importlib.metadata.version(p) != v for p, v in GOLDEN["versions"].items()),
                    reason="the numbers were recorded with other library versions")
def test_every_default_gives_the_numbers_it_gave_before_the_move(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        for run, expected in GOLDEN["runs"].items():
            name, variant = run.split(":")
            metrics = reproduce(name, "smoke", 0, None if variant == "None" else variant, progress=False)
            got = _measured(json.loads(json.dumps({k: metrics[k] for k in KEPT if k in metrics}, default=str)))
            assert _agrees(_without_added(got, expected), expected), run
    finally:
        torch.set_num_threads(threads)
