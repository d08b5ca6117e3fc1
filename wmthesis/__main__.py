"""Command line: ``python -m wmthesis COMMAND ...`` (also installed as ``wmthesis``).

    collect ENV [--episodes N] [--workers K] [--out PATH] [--seed S] [--max-steps M]
        Random rollouts into an HDF5 episode store; re-running resumes up to N episodes.
    view PATH [--episode I] [--out DIR]
        Summarise a store; write a frame strip (PNG) and a rerun recording of one episode.
    reproduce EXPERIMENT [--profile smoke|quick|thesis] [--seed S]
        Run a thesis experiment end to end; results under data/results/EXPERIMENT/.
    solve-sokoban LEVELS [--profile P] [--seed S] [--out PATH] [--max-steps M]
        Play the agent that ``reproduce sokoban-search`` trained on every level of a text file
        (# wall, space floor, . target, $ box, * box on target, @ player, + player on target;
        levels after "; N" lines) or of a Boxoban source (boxoban-medium-valid:005-009);
        writes a JSON list of {level, solved, steps, actions}.
    budget-curve PLANNER [--budgets B,...] [--profile P] [--seed S] [--validation [--variant V] [--search S]]
        One planner's score against its search budget on the seed's trained models (mcts,
        cem, sokoban-search; `reproduce planning-budget` measures all three at the profile's
        budgets), with its row without search; resumable; rows into data/results/planning_budget.csv.
    play EXPERIMENT [--profile P] [--seed S] [--bouts N] [--record FILE.rrd] [--video FILE.mp4]
        A trained agent plays its experiment's evaluation levels or bouts, with no training
        (sokoban-search, boxing-wm, boxing-wm-alphazero; quick's seed-0 agents of all three
        ship); prints each play and the score.
    validate EXPERIMENT LEVER ... [--variant V] [--seeds 0,1] [--count N] [--workers K] [--profile P]
        Levers of sokoban-search (its agent's config), planet-boxing-value or planet-freeway-value
        (the planner ending in the value of --variant's run) on the validation split only
        (Boxoban valid 000-001; the value's validation bouts); resumable as it goes.
    evaluate-sokoban [--levels N] [--profile P] [--seed S]
        The pixel agent ``reproduce sokoban-search`` trained on the first N (1000) levels of each
        of Boxoban's report files (unfiltered and medium valid 005-009): the closing figures;
        resumable level by level, reusing each play of the run's other evaluations that this
        search would play the same (the same search, or a smaller budget never reached).
    search planet-boxing|planet-freeway --trials N [--workers K] [--storage URL] [--profile P]
        Random search over KL scale x free nats (optuna); re-running continues the study, and
        any optuna storage URL (e.g. PostgreSQL) lets workers on many machines share it.
    sweep EXPERIMENT[:VARIANT] ... --seeds 0-4 [--profile P] [--address ADDR] [--cpus C]
        Every (experiment, variant, seed) as a Ray task, on a Ray of this machine's own or a
        cluster's (--address auto | HOST:PORT | ray://HOST:10001); runs only what is missing;
        then the summary.
    summary [--results DIR]
        One table over every run's metrics.json: seeds, mean, std, 95% interval, published
        numbers; data/results/summary.{md,json,csv,png}.
"""
from __future__ import annotations

import argparse
import errno
import sys
from pathlib import Path

from wmthesis.config import (ATARI_ENVIRONMENTS, PLANNERS, CollectConfig, ENVIRONMENTS, EXPERIMENTS, PROFILES, check_storage,
                             for_profile, profile_name)
from wmthesis.runs import DiskFull, FolderHeld, check_space, check_writable, write_json
from wmthesis.declarations import NAMES, Declared, check_run
from wmthesis.utils import MAX_SEED, data_dir, parse_seeds


def at_least(minimum: int, most: int | None = None):
    """An argparse type: an integer >= ``minimum`` (<= ``most`` too, where given), else refused with its range."""
    valid = f"{minimum} or more" if most is None else f"{minimum} to {most:,}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer (valid: {valid})") from None
        if value < minimum or (most is not None and value > most):
            raise argparse.ArgumentTypeError(f"{value} is out of range (valid: {valid})")
        return value

    parse.__name__ = f"integer, {valid}"
    return parse


SEED = at_least(0, MAX_SEED)  # a run's seed: every generator and store of the package takes 31 bits


def figures_to_files() -> None:
    """matplotlib drawing into files (its Agg backend), never a window: loaded here, when a command draws."""
    import matplotlib

    matplotlib.use("Agg")


def default_store_path(env: str, preprocessing: str | None) -> Path:
    return data_dir() / f"{env}-{preprocessing or 'raw'}.h5"


def cmd_collect(args) -> int:
    cfg = for_profile(CollectConfig, args.profile)
    episodes = cfg.episodes if args.episodes is None else args.episodes
    if episodes == 0:
        print("--episodes 0: nothing to collect")
        return 0
    max_steps = args.max_steps if args.max_steps is not None else cfg.max_steps
    preprocessing = args.preprocessing or ("world_models" if args.env in ATARI_ENVIRONMENTS else None)
    out = Path(args.out) if args.out else default_store_path(args.env, preprocessing)
    if args.out:  # the user's path, checked before anything plays (the default folder is made)
        check_writable(out, ".h5", make_folder=True)
    from wmthesis.rollouts import collect  # heavy: the emulator and torch

    workers = cfg.workers if args.workers is None else args.workers
    path = collect(args.env, episodes, out, workers=workers, seed=args.seed,
                   preprocessing=preprocessing, max_steps=max_steps)
    print(f"{path}: {episodes} episodes")
    return 0


def cmd_view(args) -> int:
    figures_to_files()
    import numpy as np

    from wmthesis.data import EpisodeStore
    from wmthesis.viz import image_grid, record_frames

    with EpisodeStore(args.path) as store:
        attrs = dict(store.attrs)
        if not 0 <= args.episode < len(store):
            raise SystemExit(f"{args.path}: episode {args.episode} out of range (store has {len(store)})")
        returns = [float(store.episode(i)["rewards"].sum()) for i in range(len(store))]
        episode = store.episode(args.episode)
    print(f"{args.path}: {len(returns)} episodes, env={attrs.get('env')}, "
          f"preprocessing={attrs.get('preprocessing')}, seed={attrs.get('seed')}")
    print(f"returns: mean {np.mean(returns):.2f}, std {np.std(returns):.2f}, "
          f"min {np.min(returns):.1f}, max {np.max(returns):.1f}")
    out = Path(args.out) if args.out else Path(args.path).with_suffix("")
    out.mkdir(parents=True, exist_ok=True)
    frames = episode["observations"]
    picks = np.linspace(0, len(frames) - 1, num=min(16, len(frames))).astype(int)
    fig = image_grid([frames[i] for i in picks], ncols=8, titles=[f"t={i}" for i in picks])
    fig.savefig(out / f"episode{args.episode}.png", dpi=80)
    recording = record_frames(out / f"episode{args.episode}.rrd", {"observation": frames},
                              {"reward": episode["rewards"], "action": episode["actions"]})
    print(f"wrote {out / f'episode{args.episode}.png'} and {recording} (open with: rerun {recording})")
    return 0


def cmd_reproduce(args) -> int:
    check_run(args.experiment, args.variant)  # before torch loads
    figures_to_files()
    from wmthesis.experiments import reproduce

    metrics = reproduce(args.experiment, args.profile, args.seed, args.variant)
    summary = metrics.get("headline") or metrics.get("summary")
    if summary is None:
        score = metrics["score"]
        summary = f"score {score['mean']:.1f} +- {score['std']:.1f} over {score['episodes']} episodes"
    print(f"{args.experiment} ({metrics['profile']}, seed {args.seed}): {summary}; "
          f"wall time {metrics['wall_seconds']:.0f} s")
    files = metrics["files"]
    print("results:", *files["figures"], *([files["recording"]] if "recording" in files else []), sep="\n  ")
    return 0


SOLUTION_BYTES = 4096  # a solved level's record in solve-sokoban's JSON, at most (its moves, its search's counts)


def cmd_solve_sokoban(args) -> int:
    from wmthesis.envs.boxoban import load_levels  # light: numpy and gymnasium, no torch

    boards = load_levels(args.levels)  # the levels and the output's path and space, checked before any model loads
    boxoban = args.levels.startswith("boxoban-")
    out = Path(args.out) if args.out else data_dir("results", "solutions") / f"{args.levels.replace(':', '_')}.json" \
        if boxoban else Path(args.levels).with_suffix(".solutions.json")
    check_writable(out, ".json")
    check_space(out.parent, len(boards) * SOLUTION_BYTES, f"{out}, the solutions of {len(boards):,} level{'s' * (len(boards) != 1)},")
    from wmthesis.experiments.sokoban_search import work_folder
    from wmthesis.sokoban_search.config import SokobanSearchConfig
    from wmthesis.sokoban_search.evaluation import solve_boards
    from wmthesis.sokoban_search.iteration import evaluation_search, load_run

    profile = profile_name(args.profile)
    folder = work_folder(profile, args.seed) / "pixels"
    run = load_run(folder)
    if run is None:
        raise ValueError(f"no trained agent in {folder}: run `python -m wmthesis reproduce sokoban-search "
                         f"--profile {profile} --seed {args.seed}` first")
    cfg = for_profile(SokobanSearchConfig, profile, seed=args.seed, inputs="pixels")
    results = solve_boards(run.agent(evaluation_search(cfg)), boards, max_steps=args.max_steps)
    write_json(out, results)
    print(f"{out}: {sum(r['solved'] for r in results)} of {len(results)} levels solved")
    return 0


def cmd_budget_curve(args) -> int:
    from wmthesis.budget_curves import check_planners, parse_budgets, row_line

    check_planners([args.planner])  # bad input refused before anything loads or plays
    if args.variant and not args.validation:
        raise ValueError("--variant chooses what the validation bouts measure (with --validation); the report's "
                         "curve is the default variant's")
    if args.variant:
        from wmthesis.alphazero.variants import VARIANTS

        VARIANTS.check(args.variant)
    if args.search and not args.validation:
        raise ValueError("--search chooses the root the validation bouts measure (with --validation); the report's "
                         "curve searches with the profile's root (BudgetCurveConfig.mcts_search)")
    if args.validation and args.planner != "mcts":
        raise ValueError(f"--validation plays MCTS's validation bouts; {args.planner} chooses on its own validation "
                         "(sokoban-search: `validate`; cem: planet-boxing-value's validation bouts)")
    budgets = None if args.budgets is None else {args.planner: parse_budgets(args.planner, args.budgets)}
    from wmthesis.alphazero.config import search_settings, search_tag

    search = None if args.search is None else search_settings(args.profile, args.search)
    figures_to_files()
    from wmthesis.experiments.planning_budget import mcts_validation, planning_budget

    if args.validation:
        metrics = mcts_validation(args.profile, args.seed, budgets=(budgets or {}).get("mcts"), variant=args.variant,
                                  search=search)
        print(f"validation bouts, {metrics['variant']}, {search_tag(search or search_settings(args.profile))}:")
    else:
        metrics = planning_budget(args.profile, args.seed, planners=(args.planner,), budgets=budgets)
    for row in (r for r in metrics["rows"] if r["planner"] == args.planner):
        print(row_line(row))
    return 0


def cmd_play(args) -> int:
    from wmthesis.play import play  # light: it checks the paths before anything heavy loads or plays

    try:
        play(args.experiment, profile=args.profile, seed=args.seed, variant=args.variant, bouts=args.bouts,
             record=args.record, video=args.video)
    except KeyboardInterrupt:
        kept = " ".join(p for p in (args.record, args.video) if p)
        print("play interrupted" + (f": what was played is kept in {kept}" if kept else ""), file=sys.stderr)
        return 130
    return 0


def cmd_validate(args) -> int:
    from wmthesis.validation import check_levers, lever_lines, validate  # light: torch loads when a lever runs

    check_levers(args.experiment, args.levers)
    seeds = parse_seeds(args.seeds)
    results = validate(args.experiment, args.levers, profile=args.profile, seeds=seeds, variant=args.variant,
                       count=args.count, workers=args.workers)
    for seed, levers in results.items():
        print(f"{args.experiment}, seed {seed}" + (f", {args.variant}'s value" if args.variant else ""))
        print(*lever_lines(args.experiment, levers), sep="\n")
    return 0


def cmd_evaluate_sokoban(args) -> int:
    from wmthesis.experiments.sokoban_search import evaluate_report
    from wmthesis.sokoban_search.tables import solved_line

    result = evaluate_report(args.profile, args.seed, args.levels)
    print(solved_line(f"pixel agent (seed {args.seed}), report files", result["rows"]))
    return 0


def cmd_search(args) -> int:
    check_storage(args.storage)
    figures_to_files()
    from wmthesis.planet.tuning import GAMES, ranked, run_search, trial_rows

    study = run_search(args.name, trials=args.trials, workers=args.workers, storage=args.storage,
                       profile=args.profile, objective=args.objective, seed=args.seed)
    rows = trial_rows(study)
    states = {state: sum(row["state"] == state for row in rows) for state in ("COMPLETE", "PRUNED", "FAIL")}
    print(f"{study.study_name}: " + ", ".join(f"{n} {state.lower()}" for state, n in states.items()))
    best, game = ranked(study), GAMES[args.name]
    if best:
        top = best[0]
        print(f"best: trial {top['number']}: KL scale {top['kl_scale']:.3g}, free nats {top['free_nats']:.2f}, "
              f"score {top['score']:.1f}, open-loop error at +{top['horizon']} {top['error']:.4f}")
    print(f"thesis: KL scale {game.thesis_kl_scale:g}, free nats {game.thesis_free_nats:g}")
    return 0


def cmd_sweep(args) -> int:
    seeds = parse_seeds(args.seeds)  # names and seeds refused before torch or Ray load
    for spec in args.runs:
        check_run(*(spec.partition(":")[::2]))
    figures_to_files()
    from wmthesis.summary import markdown_table, write_summary
    from wmthesis.sweep import RayStartFailed, check_address, parse_runs, sweep

    runs = parse_runs(args.runs, seeds)
    if args.address is not None:
        check_address(args.address)
    profile = profile_name(args.profile)
    print(f"sweep ({profile}): {len(runs)} runs: " + ", ".join(map(str, runs)))
    try:
        outcome = sweep(runs, profile, args.address, cpus=args.cpus, gpus=args.gpus, retries=args.retries)
    except KeyboardInterrupt:
        print("sweep interrupted: the finished runs are kept; run it again to run only what is missing",
              file=sys.stderr)
        return 130
    except RayStartFailed as error:  # not bad input: the machine was too busy
        print(f"error: {error}", file=sys.stderr)
        return 1
    for run, result in outcome.items():
        detail = result.get("error") or result.get("path")
        print(f"  {run}: {result['status']} ({detail})")
    print(markdown_table(write_summary()))
    failed = [run for run, result in outcome.items() if result["status"] == "failed"]
    if failed:
        print(f"{len(failed)} of {len(runs)} runs failed: " + ", ".join(map(str, failed)), file=sys.stderr)
    return 1 if failed else 0


def cmd_summary(args) -> int:
    folder = Path(args.results) if args.results else None
    if folder is not None and not folder.is_dir():  # before matplotlib and torch load
        raise ValueError(f"--results {args.results}: no such folder")
    figures_to_files()
    from wmthesis.headline import BEGIN
    from wmthesis.summary import markdown_table, write_summary

    readme = Path(__file__).resolve().parents[1] / "README.md"  # the checkout's front door, where its results block is
    with_table = folder is None and readme.is_file() and BEGIN in readme.read_text()
    rows = write_summary(folder, readme if with_table else None, force=args.force)
    print(markdown_table(rows))
    if with_table:
        print(f"the results table in {readme} is written anew")
    return 0


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(prog="python -m wmthesis", description=__doc__,
                                  formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = top.add_subparsers(dest="command", required=True)

    collect = commands.add_parser("collect", help="random rollouts into an HDF5 store")
    collect.add_argument("env", choices=ENVIRONMENTS)
    collect.add_argument("--episodes", type=at_least(0), help="episodes wanted in the store (default: profile's)")
    collect.add_argument("--workers", type=at_least(1))
    collect.add_argument("--out", help="store path (default: data/ENV-PREPROCESSING.h5)")
    collect.add_argument("--seed", type=SEED, default=0)
    collect.add_argument("--max-steps", type=at_least(1), help="cut episodes after this many steps")
    collect.add_argument("--preprocessing", choices=("none", "world_models", "planet"))
    collect.add_argument("--profile", choices=PROFILES)
    collect.set_defaults(run=cmd_collect)

    view = commands.add_parser("view", help="summarise a store, write a frame strip and a rerun recording")
    view.add_argument("path")
    view.add_argument("--episode", type=at_least(0), default=0)
    view.add_argument("--out", help="folder for the PNG and .rrd (default: next to the store)")
    view.set_defaults(run=cmd_view)

    reproduce = commands.add_parser("reproduce", help="run a thesis experiment end to end (resumable)")
    reproduce.add_argument("experiment", choices=EXPERIMENTS)
    reproduce.add_argument("--profile", choices=PROFILES)
    reproduce.add_argument("--seed", type=SEED, default=0)
    reproduce.add_argument("--variant", help="a variant of the experiment (PlaNet's: see its --help)")
    reproduce.set_defaults(run=cmd_reproduce)

    solve = commands.add_parser("solve-sokoban", help="play the trained Sokoban search agent on levels from a text file")
    solve.add_argument("levels", help="a text file of levels (# wall, . target, $ box, @ player; '; N' lines between), "
                                      "or Boxoban levels: boxoban-SET[:FILES], e.g. boxoban-medium-valid:005-009")
    solve.add_argument("--profile", choices=PROFILES)
    solve.add_argument("--seed", type=SEED, default=0, help="the seed of the trained run")
    solve.add_argument("--out", help="JSON results (default: LEVELS.solutions.json)")
    solve.add_argument("--max-steps", type=at_least(1), default=120, help="steps allowed per level")
    solve.set_defaults(run=cmd_solve_sokoban)

    budget = commands.add_parser("budget-curve", help="one planner's score against its search budget (resumable)")
    budget.add_argument("planner", help=f"one of {', '.join(PLANNERS)}")
    budget.add_argument("--budgets", help="budgets in place of the profile's: 16,64,256 (mcts: simulations; "
                                          "sokoban-search: nodes) or 6x100x3,12x100x3 (cem: horizon x candidates x iterations)")
    budget.add_argument("--profile", choices=PROFILES)
    budget.add_argument("--seed", type=SEED, default=0, help="the seed of the trained models")
    budget.add_argument("--validation", action="store_true",
                        help="mcts: play the validation bouts (to choose on; written to validation-VARIANT.json, "
                             "not reported)")
    budget.add_argument("--variant", help="with --validation: the boxing-wm-alphazero variant searched (default: "
                                          "the default)")
    budget.add_argument("--search", help="with --validation: the MCTS root's settings, e.g. root=gumbel,c_scale=0.03 "
                                         "(root, tie_break, considered, gumbel_scale, c_scale, c_visit; default: the profile's)")
    budget.set_defaults(run=cmd_budget_curve)

    player = commands.add_parser("play", help="a trained agent plays, with no training")
    player.add_argument("experiment", choices=EXPERIMENTS)
    player.add_argument("--profile", choices=PROFILES)
    player.add_argument("--seed", type=SEED, default=0, help="the seed of the trained run")
    player.add_argument("--variant", help="a variant of the experiment (default: its default)")
    player.add_argument("--bouts", type=at_least(1), help="bouts or levels to play (default 10, or all its scored "
                                                          "bouts where it was scored on fewer)")
    player.add_argument("--record", help="a rerun recording (.rrd) of every step: the real frame beside what the "
                                         "agent saw, imagined and weighed (open with: rerun FILE.rrd)")
    player.add_argument("--video", help="an mp4 of the same panels side by side: reality, the model's view, "
                                        "what it imagined 1, 4 and 8 steps before")
    player.set_defaults(run=cmd_play)

    validate = commands.add_parser("validate", help="levers of an experiment on its validation split only")
    validate.add_argument("experiment", choices=Declared(lambda d: d.levers is not None))
    validate.add_argument("levers", nargs="+", metavar="LEVER", help="the levers to play (a wrong one lists the valid)")
    validate.add_argument("--variant", help="a PlaNet value's run whose agent the planners end in (default: its default)")
    validate.add_argument("--seeds", default="0", help="the trained runs' seeds: a range 0-2, a list 0,2, or one seed")
    validate.add_argument("--count", type=at_least(1), help="levels (Sokoban) or bouts (a value) each: default the profile's")
    validate.add_argument("--workers", type=at_least(1), help="processes sharing a value's bouts (default 2)")
    validate.add_argument("--profile", choices=PROFILES)
    validate.set_defaults(run=cmd_validate)

    report = commands.add_parser("evaluate-sokoban", help="the Sokoban pixel agent (trained first if need be) on "
                                                          "more of Boxoban's report files than the experiment plays")
    report.add_argument("--levels", type=at_least(1), default=1000, help="the first N levels of each report set "
                                                                         "(default 1000)")
    report.add_argument("--profile", choices=PROFILES)
    report.add_argument("--seed", type=SEED, default=0, help="the seed of the trained run")
    report.set_defaults(run=cmd_evaluate_sokoban)

    search = commands.add_parser("search", help="random search over KL scale x free nats (optuna)")
    search.add_argument("name", choices=(NAMES.planet_boxing, NAMES.planet_freeway))
    search.add_argument("--trials", type=at_least(1), help="finished trials wanted in the study (default: profile's)")
    search.add_argument("--workers", type=at_least(1), help="worker processes on this machine")
    search.add_argument("--storage", help="optuna storage URL (default: sqlite file under data/search/)")
    search.add_argument("--profile", choices=PROFILES)
    search.add_argument("--objective", choices=("score", "error", "both"))
    search.add_argument("--seed", type=SEED, help="study seed (the sampler's and every trial's)")
    search.set_defaults(run=cmd_search)

    sweep = commands.add_parser("sweep", help="seeds of experiments as Ray tasks, then the summary (resumable)")
    sweep.add_argument("runs", nargs="+", metavar="EXPERIMENT[:VARIANT]",
                       help=f"experiments, a variant after a colon (e.g. planet-freeway:freeway-tuned); "
                            f"one of {', '.join(EXPERIMENTS)}")
    sweep.add_argument("--seeds", required=True, help="seeds: a range 0-4, a list 0,2,7, or one seed")
    sweep.add_argument("--profile", choices=PROFILES)
    sweep.add_argument("--address", help="a Ray cluster to join: auto, HOST:PORT or ray://HOST:10001 "
                                         "(default: start a Ray of this machine's own)")
    sweep.add_argument("--cpus", type=at_least(1), default=1, help="CPUs (torch threads) per run (default 1)")
    sweep.add_argument("--gpus", type=float, help="GPUs per run (default: 1 where the cluster has one, else 0)")
    sweep.add_argument("--retries", type=at_least(0), default=3, help="restarts of a run whose worker died")
    sweep.set_defaults(run=cmd_sweep)

    summary = commands.add_parser("summary", help="one table over every run: seeds, mean, std, 95%% interval")
    summary.add_argument("--results", help="the folder of results (default: data/results)")
    summary.add_argument("--force", action="store_true", help="write the README's table even where it holds fewer runs")
    summary.set_defaults(run=cmd_summary)
    return top


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        return args.run(args)
    except (ValueError, TypeError, OSError, FolderHeld) as error:  # bad input: a clear message, no traceback
        full = isinstance(error, OSError) and error.errno == errno.ENOSPC  # nothing half-written is left behind
        print(f"error: {error.strerror if isinstance(error, DiskFull) else error}", file=sys.stderr)
        return 1 if full else 2
    except KeyboardInterrupt as error:  # every step a run finished is on disk: running it again resumes after it
        print(f"{args.command} interrupted: {str(error) or 'what it finished is kept'}; run the same command again to "
              "resume", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
