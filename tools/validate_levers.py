"""Play planner levers on the value's validation bouts of several seeds in one pool of
processes, as many at a time as the machine has cores (issue 31's levers; see
``validate_planners``). Each bout is saved in the value run's folder as it ends, so a run cut off
resumes where it stopped, here or on the 2-core machine. The value runs must be finished: their
``metrics.json`` is read, and only the models (the PlaNet agent's checkpoint and the value's)
are needed, not the bouts they were fitted on.

    python tools/validate_levers.py --profile quick --variant lean --seeds 1 0 \\
        --levers "value seeds CEM" "the value's rewards, discount 0.5" [--workers 16]

Seeds are submitted in the order given, and within a seed the levers: on a machine cut off by a
time limit, the first ones end first.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from concurrent.futures import ThreadPoolExecutor

from wmthesis.experiments.planet_boxing_value import PLANNER_LEVERS, results_folder, validate_planners
from wmthesis.planet.value_tables import planner_lever_rows
from wmthesis.utils import process_pool


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--profile", default="quick", choices=("smoke", "quick", "thesis"))
    parser.add_argument("--variant", default="lean")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--levers", nargs="+", default=list(PLANNER_LEVERS), choices=tuple(PLANNER_LEVERS))
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--stagger", type=float, default=30.0,
                        help="seconds between seeds, for each seed's bouts to be submitted before the next's")
    args = parser.parse_args()

    def play(seed: int) -> dict:
        metrics = json.loads((results_folder(args.profile, seed, args.variant) / "metrics.json").read_text())
        return validate_planners(args.profile, seed, tuple(args.levers), variant=args.variant, executor=pool,
                                 metrics=metrics)

    with process_pool(args.workers) as pool, ThreadPoolExecutor(len(args.seeds)) as seeds:
        futures = {}
        for seed in args.seeds:  # each seed's bouts submitted before the next seed's
            futures[seed] = seeds.submit(play, seed)
            time.sleep(args.stagger)
        results = {seed: future.result() for seed, future in futures.items()}  # a seed's error raised here
    for seed in args.seeds:
        print(f"\nseed {seed}")
        for row in planner_lever_rows(results[seed], PLANNER_LEVERS):
            print(" | ".join(row))


if __name__ == "__main__":
    main()
