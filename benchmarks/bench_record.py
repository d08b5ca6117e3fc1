"""Recording what every shipped agent thinks: wall time and size of ``play --record`` beside ``play``.

    python benchmarks/bench_record.py [--agents boxing-wm,...] [--out PATH]

Each row runs ``python -m wmthesis play EXPERIMENT [--variant V] --bouts N`` in a fresh process,
once as it is and once with ``--record``, on what the repository ships (no training): one bout of
each Boxing and Freeway agent, five levels of each Sokoban seed. The targets: every shipped agent
records; a one-bout Boxing recording (every Boxing row) at most 200 MB and at most 3x the wall time
of ``play`` without ``--record``. Writes ``benchmarks/results/record.json``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[1])]  # _results, wmthesis

from _results import machine_meta, print_table, write_results  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "record.json"
AGENTS = {  # name: (experiment, extra arguments, bouts)
    "boxing-wm": ("boxing-wm", [], 1),
    "boxing-wm-alphazero own-memory": ("boxing-wm-alphazero", ["--variant", "own-memory"], 1),
    "boxing-wm-alphazero own-reward": ("boxing-wm-alphazero", ["--variant", "own-reward"], 1),
    "boxing-wm-alphazero imitation": ("boxing-wm-alphazero", ["--variant", "imitation"], 1),
    "planet-boxing-agent": ("planet-boxing-agent", [], 1),
    "planet-boxing-value": ("planet-boxing-value", [], 1),
    "planet-freeway": ("planet-freeway", [], 1),
    **{f"sokoban-search seed {s}": ("sokoban-search", ["--seed", str(s)], 5) for s in range(3)},
}
MAX_MB, MAX_RATIO = 200, 3.0


def timed(command: list[str], root: Path) -> tuple[float, str]:
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "wmthesis", *command], cwd=root, capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"{' '.join(command)} failed: {done.stderr.strip()[-500:]}")
    return time.perf_counter() - start, done.stdout


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agents", default=",".join(AGENTS), help="comma-separated names of the rows to run")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    root, rows = Path(__file__).resolve().parents[1], []
    with tempfile.TemporaryDirectory() as folder:
        for name in args.agents.split(","):
            experiment, extra, bouts = AGENTS[name]
            command = ["play", experiment, *extra, "--bouts", str(bouts)]
            play_s, _ = timed(command, root)
            path = Path(folder) / f"{name.replace(' ', '-')}.rrd"
            record_s, out = timed([*command, "--record", str(path)], root)
            errors = next((line.split(": ", 1)[1] for line in out.splitlines() if line.startswith("imagination")), "")
            mb = path.stat().st_size / 1e6
            rows.append({"agent": name, "bouts": bouts, "play_s": play_s, "record_s": record_s,
                         "load_average": os.getloadavg()[0],
                         "ratio": record_s / play_s, "size_mb": mb, "errors_by_steps_ahead": errors,
                         "met": mb <= MAX_MB and (record_s / play_s <= MAX_RATIO or "boxing" not in name)})
            print_table(rows[-1:])
    if args.out.is_file():  # the rows of agents not run now stay, each with the load it ran under
        ran = {row["agent"] for row in rows}
        rows = [r for r in json.loads(args.out.read_text())["results"] if r["agent"] not in ran] + rows
    print_table(rows, ["agent", "bouts", "play_s", "record_s", "ratio", "size_mb", "met"])
    write_results(args.out, machine_meta(max_mb=MAX_MB, max_ratio=MAX_RATIO), rows)


if __name__ == "__main__":
    main()
