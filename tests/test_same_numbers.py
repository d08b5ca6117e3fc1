"""Behaviour unchanged: every default and every kept variant gives, in smoke on seed 0 with one
torch thread, the numbers recorded in ``tests/golden/smoke-seed0.json`` (by ``python
tests/same_numbers.py``), and the shipped agents give the recorded signals (MCTS root Q and
visits on a real state, Sokoban solutions, the World Models agent's latents and scores), which a
wrong backup or push rule changes. Wall times and the published figures' wording are left out;
integers and strings must agree exactly, floats to a relative 1e-4 (the last digits of float sums
differ from one CPU's kernels to another's).

The numbers hold for the library versions they were recorded with (another version may draw
other random numbers or step the games otherwise): elsewhere the gate is skipped, except in CI
(``CI`` set), where a version that differs from the record fails it.
"""
from __future__ import annotations

import json
import math
import os

import pytest
import torch

from same_numbers import GOLDEN, RUNS, run_numbers, signals, versions

RECORDED = json.loads(GOLDEN.read_text())
DIFFERENT = {p: (v, RECORDED["versions"][p]) for p, v in versions().items() if v != RECORDED["versions"][p]}


def agrees(got, expected) -> bool:
    """``got`` as ``expected``: the same keys and lengths, integers and strings equal, floats within
    a relative 1e-4 (:mod:`math`'s ``isclose``)."""
    if isinstance(expected, dict):
        return isinstance(got, dict) and got.keys() == expected.keys() and all(agrees(got[k], v) for k, v in expected.items())
    if isinstance(expected, list):
        return isinstance(got, list) and len(got) == len(expected) and all(map(agrees, got, expected))
    if isinstance(expected, float) and isinstance(got, (int, float)) and not isinstance(got, bool):
        return math.isclose(got, expected, rel_tol=1e-4, abs_tol=1e-9)
    return got == expected


def without_added(got, expected):
    """``got`` without the config fields added since the numbers were recorded (absent from
    ``expected``) that sit at None, the default that keeps the old behaviour."""
    if isinstance(got, dict) and isinstance(expected, dict):
        return {k: without_added(v, expected.get(k)) for k, v in got.items() if k in expected or v is not None}
    if isinstance(got, list) and isinstance(expected, list):
        return [without_added(g, e) for g, e in zip(got, expected)] + got[len(expected):]
    return got


def check_versions():
    if DIFFERENT and os.environ.get("CI"):
        pytest.fail(f"library versions differ from the record (installed, recorded): {DIFFERENT}; "
                    "record again with `python tests/same_numbers.py` on a checkout whose numbers are known good")
    if DIFFERENT:
        pytest.skip(f"the numbers were recorded with other library versions: {DIFFERENT}")


def test_the_gate_covers_every_default_and_its_signals():
    from wmthesis.experiments import VARIANTS
    from wmthesis.config import EXPERIMENTS

    assert set(RECORDED["runs"]) == set(RUNS)
    assert {run.split(":")[0] for run in RUNS} == set(EXPERIMENTS)  # every experiment's default is gated
    assert all(f"{name}:None" in RUNS for name in EXPERIMENTS)
    assert {"mcts_shipped", "mcts_toy", "sokoban_shipped", "sokoban_rules", "world_models_shipped"} <= set(RECORDED["signals"])
    assert all(p["solved"] for p in RECORDED["signals"]["sokoban_shipped"])  # a signal: the levels are solved
    assert len(set(RECORDED["signals"]["mcts_shipped"]["q"])) > 1  # a signal: the root's Q differ
    assert set(VARIANTS) <= set(EXPERIMENTS)


@pytest.fixture(scope="module")
def smoke_data(tmp_path_factory):
    """One data folder for every run, as recorded: a run finds the runs it builds on made before."""
    return tmp_path_factory.mktemp("smoke-seed0")


@pytest.mark.parametrize("run", RUNS)
def test_every_default_gives_the_numbers_it_gave(run, smoke_data, monkeypatch):
    check_versions()
    monkeypatch.setenv("WMTHESIS_DATA", str(smoke_data))
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        expected = RECORDED["runs"][run]
        assert agrees(without_added(run_numbers(run), expected), expected), run
    finally:
        torch.set_num_threads(threads)


def test_the_shipped_agents_give_the_recorded_signals():
    check_versions()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        got = signals()
    finally:
        torch.set_num_threads(threads)
    for name, expected in RECORDED["signals"].items():
        assert agrees(got[name], expected), name
