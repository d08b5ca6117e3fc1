"""A newcomer's first agent: from ``git clone`` to a Boxing agent playing its first bout.

    python benchmarks/bench_fresh_clone.py [--rev HEAD] [--keep] [--out PATH]

Clones this repository at ``--rev`` into a temporary folder, makes a fresh virtual environment,
installs ``requirements.txt`` into it (with whatever index or wheel folder pip is set up to use
here), then plays ``python -m wmthesis play boxing-wm --profile quick --bouts 1`` from the shipped
agent, no training. Each step is timed; the target (issue 56): the bout's score printed within 5
minutes of the install starting. The score itself is checked against the summary's seed-0 bout
(the played bout must be the evaluation's first). Writes ``benchmarks/results/fresh_clone.json``.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parent)]  # _results

from _results import load_average, machine_meta, print_table, write_results  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "fresh_clone.json"
TARGET_SECONDS = 5 * 60
PLAY = ["-m", "wmthesis", "play", "boxing-wm", "--profile", "quick", "--bouts", "1"]


def timed(name: str, command: list[str], cwd: Path, env: dict | None = None) -> tuple[dict, str]:
    """Run ``command`` in ``cwd``; its row (step, seconds, load average at its end) and its output.
    A failing step raises, printing what it said."""
    start = time.perf_counter()
    done = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"{name} failed ({done.returncode}):\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    return {"step": name, "seconds": seconds, "load_1min": (load_average() or [None])[0]}, done.stdout


def shipped_first_bout() -> float:
    """The score of seed 0's first evaluation bout, as its committed metrics hold it."""
    metrics = json.loads((ROOT / "data/results/boxing-wm/quick-seed0/separable-64/metrics.json").read_text())
    return float(metrics["returns"][0])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rev", default="HEAD")
    parser.add_argument("--keep", action="store_true", help="keep the clone and its environment")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    rev = subprocess.run(["git", "rev-parse", args.rev], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout.strip()
    folder = Path(tempfile.mkdtemp(prefix="wmthesis-clone-"))
    clone, venv = folder / "wmthesis", folder / "venv"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "WMTHESIS_DATA", "VIRTUAL_ENV")}
    python = str(venv / "bin" / "python")
    try:
        rows = [timed("git clone", ["git", "clone", "--quiet", str(ROOT), str(clone)], folder)[0]]
        subprocess.run(["git", "checkout", "--quiet", rev], cwd=clone, check=True)
        rows.append(timed("python -m venv", [sys.executable, "-m", "venv", str(venv)], folder)[0])
        rows.append(timed("pip install -r requirements.txt",
                          [python, "-m", "pip", "install", "--quiet", "-r", "requirements.txt"], clone, env)[0])
        row, said = timed("play boxing-wm --bouts 1", [python, *PLAY], clone, env)
        rows.append(row)
        torch = subprocess.run([python, "-c", "from importlib.metadata import version; print(version('torch'))"],
                               capture_output=True, text=True).stdout.strip()  # the clone's, not this script's
    finally:
        if not args.keep:
            shutil.rmtree(folder, ignore_errors=True)
    scores = [float(s) for s in re.findall(r"^bout 0: ([+-]?\d+) in", said, re.M)]
    install_to_play = sum(r["seconds"] for r in rows if r["step"] != "git clone" and r["step"] != "python -m venv")
    rows.append({"step": "pip install to the bout's score", "seconds": install_to_play,
                 "load_1min": (load_average() or [None])[0]})
    print(said.strip())
    print_table(rows)
    expected = shipped_first_bout()
    played = scores[0] if scores else None
    print(f"bout 0: {played} (its evaluation: {expected}); pip install to the score: {install_to_play:.0f} s "
          f"(target {TARGET_SECONDS} s)")
    write_results(args.out, machine_meta(rev=rev, torch=torch, target_seconds=TARGET_SECONDS, bout_score=played,
                                         evaluation_score=expected, met=install_to_play <= TARGET_SECONDS
                                         and played == expected), rows)


if __name__ == "__main__":
    main()
