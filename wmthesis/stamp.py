"""Where a result came from: the code's commit, the CPU, the torch threads, the wall time.

A notebook ends with :func:`stamp`, one line a reader (and ``tests/test_notebooks.py``) can check:

    run stamp · commit 41365a0 · 2026-11-27 · profile quick · Intel(R) Xeon(R) CPU @ 2.20GHz (2 cores)
        · 2 torch threads · wall time 86 s · from shipped runs

(the last part, where given: ``trained here`` for a notebook run with ``TRAIN = True``, ``from
shipped runs`` for one that read the committed runs and shipped agents)

``commit`` is the checkout's ``HEAD``, with ``+changes`` when files of the package differ from it
(the committed outputs must come from committed code: the tests refuse such a stamp).
"""
from __future__ import annotations

import os
import platform
import re
import subprocess
import time
from datetime import date
from pathlib import Path

CHECKOUT = Path(__file__).resolve().parents[1]
STAMP = re.compile(r"run stamp · commit (?P<commit>[0-9a-f]{7,40})(?P<changes>\+changes)? · (?P<date>[\d-]+) · "
                   r"profile (?P<profile>\w+) · (?P<cpu>.+?) · (?P<threads>\d+) torch threads? · "
                   r"wall time (?P<seconds>\d+) s(?: · (?P<how>trained here|from shipped runs))?")


def git_commit(checkout: Path = CHECKOUT) -> str | None:
    """The checkout's short commit, ``+changes`` appended when the package's files differ from it;
    None outside a git checkout."""
    def git(*args) -> str:
        return subprocess.run(["git", "-C", str(checkout), *args], capture_output=True, text=True,
                              check=True, timeout=30).stdout.strip()
    try:
        commit = git("rev-parse", "--short", "HEAD")
        changed = git("status", "--porcelain", "--", "wmthesis")
    except (OSError, subprocess.SubprocessError):
        return None
    return commit + ("+changes" if changed else "")


def cpu_model() -> str:
    """The CPU's model name (from ``/proc/cpuinfo`` where there is one) and its core count."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model} ({os.cpu_count()} cores)"


def stamp(profile: str, started: float, train: bool | None = None) -> str:
    """The line that ends a notebook: commit, date, ``profile``, CPU, torch threads, the wall
    time since ``started`` (a ``time.time()``) and, where ``train`` is given, how it ran
    (``trained here`` or ``from shipped runs``)."""
    import torch  # heavy: loaded when a notebook ends, not when the package is imported

    threads = torch.get_num_threads()
    return (f"run stamp · commit {git_commit() or 'unknown'} · {date.today().isoformat()} · profile {profile} · "
            f"{cpu_model()} · {threads} torch thread{'s' if threads > 1 else ''} · wall time {time.time() - started:.0f} s"
            + ("" if train is None else " · trained here" if train else " · from shipped runs"))


def read_stamp(text: str) -> dict | None:
    """The fields of the last stamp in ``text`` (None if it has none): commit, changes (bool),
    date, profile, cpu, threads and seconds (ints), how (None where the stamp does not say)."""
    found = list(STAMP.finditer(text))
    if not found:
        return None
    fields = found[-1].groupdict()
    return {**fields, "changes": bool(fields["changes"]), "threads": int(fields["threads"]),
            "seconds": int(fields["seconds"])}


__all__ = ["stamp", "read_stamp", "git_commit", "cpu_model"]
