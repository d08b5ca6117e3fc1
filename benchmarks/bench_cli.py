"""The command line's answer time: how long a newcomer waits for ``--help`` or for a wrong argument.

    python benchmarks/bench_cli.py [--repeats 5] [--out PATH]

Each row runs one command in a fresh ``python`` process ``--repeats`` times and reports the
median and the slowest wall time. The target (issue 56): ``--help`` under 1 s, and a wrong
argument refused before torch, Ray or ale-py load. Writes ``benchmarks/results/cli.json``.
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[1])]  # _results, wmthesis

from _results import machine_meta, print_table, write_results  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "cli.json"
COMMANDS = {"--help": ["--help"], "reproduce --seed abc": ["reproduce", "boxing-wm", "--seed", "abc"],
            "an unknown command": ["nope"], "reproduce --help": ["reproduce", "--help"]}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    root = Path(__file__).resolve().parents[1]
    rows = []
    for name, command in COMMANDS.items():
        seconds = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            subprocess.run([sys.executable, "-m", "wmthesis", *command], cwd=root, capture_output=True)
            seconds.append(time.perf_counter() - start)
        rows.append({"command": name, "median_s": statistics.median(seconds), "slowest_s": max(seconds)})
    print_table(rows)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    write_results(args.out, machine_meta(repeats=args.repeats, load_average_1min=load), rows)


if __name__ == "__main__":
    main()
