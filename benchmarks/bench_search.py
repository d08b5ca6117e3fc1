"""Random search: trials per hour with 1 and 2 worker processes on smoke-sized trials.

    python benchmarks/bench_search.py [--trials 6] [--game planet-boxing] [--workers 1 2] [--out PATH]

Each row runs a fresh study of ``--trials`` smoke-profile PlaNet trials (tiny RSSM, 48 agent
steps, open-loop evaluation and figure) in a fresh SQLite file, with K worker processes
(``run_search(..., workers=K)``; K = 1 runs in this process). Wall time includes starting the
worker processes (spawn: each imports torch), so short studies understate the steady rate;
``speed-up`` is the rate over the 1-worker rate (ideal: K, up to the number of free cores).
Workers get ``cores // K`` torch threads. Writes ``benchmarks/results/search.json``.
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[1])]  # _results, wmthesis

from _results import machine_meta, print_table, write_json  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "search.json"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=6)
    parser.add_argument("--game", default="planet-boxing")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    os.environ["WMTHESIS_DATA"] = tempfile.mkdtemp(prefix="bench-search-")
    os.environ.setdefault("MPLBACKEND", "Agg")
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    from wmthesis.planet.tuning import run_search, trial_rows

    rows = []
    for workers in args.workers:
        storage = f"sqlite:///{Path(os.environ['WMTHESIS_DATA']) / f'bench-{workers}.db'}"
        start = time.perf_counter()
        study = run_search(args.game, trials=args.trials, workers=workers, storage=storage, profile="smoke")
        seconds = time.perf_counter() - start
        done = sum(row["state"] == "COMPLETE" for row in trial_rows(study))
        rows.append({"workers": workers, "trials": done, "seconds": seconds, "trials_per_hour": 3600 * done / seconds})
    for row in rows:
        row["speedup"] = row["trials_per_hour"] / rows[0]["trials_per_hour"]
    print_table(rows)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    print(f"load average {load}")
    meta = machine_meta(host=platform.node(), load_average_1min=load, game=args.game)
    write_json(args.out, {**meta, "rows": rows})     # one flat object, as this file always was


if __name__ == "__main__":
    main()
