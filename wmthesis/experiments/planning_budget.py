"""Planning that pays (issue 57; the thesis's promise, chapter 1): each planner's score against its
search budget, on a seed's trained models, the same levels for every budget. Measured so far: the
Sokoban agent (``sokoban-search``) on the first Boxoban medium report levels, without search and
under each node budget of :data:`SOKOBAN_BUDGETS`; and MCTS in the World Models memory
(``boxing-wm-alphazero``'s ``imitation`` run) on Boxing: its policy head alone, then each number of
simulations of :data:`MCTS_BUDGETS`, on the same evaluation bouts; and CEM in PlaNet's model with
the learned value (``planet-boxing-value``'s default) on Boxing: the value alone, then each
horizon x candidates x iterations of :data:`CEM_BUDGETS`, on the value's evaluation bouts. Writes the run's ``metrics.json`` and, over every
seed run in the profile, ``data/results/planning_budget.csv`` (``quick``; other profiles
``planning_budget-PROFILE.csv``)."""
from __future__ import annotations

import csv
import dataclasses
import io
import json
import time

import numpy as np

from wmthesis.alphazero.evaluation import evaluation_games, policy_head_games, trained_run
from wmthesis.config import for_profile, profile_name
from wmthesis.envs.boxoban import BOXOBAN_SPLITS
from wmthesis.metrics import aggregate
from wmthesis.planet.config import ValuePlannerConfig
from wmthesis.planet.value_runs import lever_scores
from wmthesis.planet.value_variants import value_folder
from wmthesis.runs import (atomic_path, built_on, hold, releasing_holds, results_folder, run_header, run_jobs,
                           work_folder, write_json)
from wmthesis.sokoban_search.budget import NO_SEARCH, budget_jobs, budget_plays, ms_per_action
from wmthesis.sokoban_search.config import SokobanSearchConfig
from wmthesis.sokoban_search.iteration import load_run
from wmthesis.training import with_added_defaults
from wmthesis.utils import data_dir
from wmthesis.variants import no_variant
from wmthesis.viz import save_figure

SOKOBAN_BUDGETS = {"smoke": (50, 300), "quick": (1_000, 5_000, 20_000, 40_000, 160_000),
                   "thesis": (1_000, 5_000, 20_000, 40_000, 160_000)}  # nodes a search may expand
SOKOBAN_LEVELS = {"smoke": 4, "quick": 500, "thesis": 1000}  # the first Boxoban medium report levels
MCTS_BUDGETS = {"smoke": (2, 4), "quick": (16, 64, 256), "thesis": (16, 64, 256)}  # simulations an action
BOXING_BOUTS = {"smoke": 2, "quick": 10, "thesis": 10}  # evaluation bouts a seed, the same for every budget
# CEM with the value: (horizon H, candidates J, iterations I), H x J x I imagined steps an action; the
# value alone (H = 1) is the row without search. quick's J and I are its PlaNet's; H = 3 its planner's.
CEM_BUDGETS = {"smoke": ((2, 16, 2), (3, 16, 2)), "quick": ((2, 100, 3), (3, 100, 3), (6, 100, 3), (12, 100, 3)),
               "thesis": ((3, 1000, 10), (6, 1000, 10), (12, 1000, 10))}
COLUMNS = ("planner", "game", "budget", "seed", "score", "no_search_score", "ms_per_action")


@releasing_holds
def planning_budget(profile: str | None = None, seed: int = 0, variant: str | None = None,
                    progress: bool = True) -> dict:
    """The budget curve of every planner measured so far on ``seed``'s trained models (see the
    module docstring); resumable level by level. Returns the metrics: one row per planner and
    budget (score, the same agent without search on the same levels, the paired gain over it with
    its 95% t interval over levels, milliseconds per action)."""
    no_variant("planning-budget", variant)
    profile = profile_name(profile)
    started, rows = time.time(), []
    for curve in (sokoban_curve, mcts_curve, cem_curve):  # each planner's rows saved before the next begins
        rows += curve(profile, seed, progress)
        metrics = _write_run(rows, profile, seed, time.time() - started)
    return metrics


def _write_run(rows: list[dict], profile: str, seed: int, seconds: float) -> dict:
    """The run's ``metrics.json`` (its rows so far, a summary line, the figure) and the profile's CSV."""
    out = results_folder("planning-budget", profile, seed)
    figure = save_figure(plot_budget_curves(rows), out / "budget_curve.png")
    curves = "; ".join(f"{planner} on {game}: " + ", ".join(f"{r['budget']:,}: {r['score']:.1f}" for r in rows
                                                         if (r["planner"], r["game"]) == (planner, game))
                       for planner, game in dict.fromkeys((r["planner"], r["game"]) for r in rows))
    metrics = {**run_header("planning-budget", profile, seed, seconds),
               "summary": f"score by search budget (0: no search): {curves}",
               "rows": rows, "files": {"figures": [str(figure)]}}
    write_json(out / "metrics.json", metrics)
    write_budget_table(profile)
    return metrics


def plot_budget_curves(rows: list[dict]):
    """Score against budget (log scale; no search at the left edge), one panel per planner and
    game, each seed a line, the mean over seeds in black with its 95% t interval. Returns the figure."""
    import matplotlib.pyplot as plt

    panels = sorted({(r["planner"], r["game"]) for r in rows})
    fig, axes = plt.subplots(1, len(panels), figsize=(4.5 * len(panels), 3.4), squeeze=False)
    for ax, (planner, game) in zip(axes[0], panels):
        mine = [r for r in rows if (r["planner"], r["game"]) == (planner, game)]
        searched = sorted({r["budget"] for r in mine if r["budget"] != NO_SEARCH})
        x = {NO_SEARCH: searched[0] / 4 if searched else 1, **{b: b for b in searched}}
        for seed in sorted({r["seed"] for r in mine}):
            line = sorted((r for r in mine if r["seed"] == seed), key=lambda r: r["budget"])
            ax.plot([x[r["budget"]] for r in line], [r["score"] for r in line], "o-", lw=1, ms=3, alpha=0.6,
                    label=f"seed {seed}")
        over = [aggregate([r["score"] for r in mine if r["budget"] == b]) for b in x]
        ax.plot(list(x.values()), [a["mean"] for a in over], "k-", lw=2, label="mean")
        if all(a["ci_low"] is not None for a in over):
            ax.fill_between(list(x.values()), [a["ci_low"] for a in over], [a["ci_high"] for a in over], color="k",
                            alpha=0.12, label="95% interval")
        ax.set_xscale("log")
        ax.set_xticks(list(x.values()), ["none", *(f"{b:,}" for b in searched)], rotation=30, fontsize=7)
        ax.set_xlabel("search budget")
        ax.set_ylabel("score")
        ax.set_title(f"{planner} on {game}", fontsize=9)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def sokoban_curve(profile: str, seed: int, progress: bool) -> list[dict]:
    """The Sokoban agent's rows: without search (budget 0) and under each of :data:`SOKOBAN_BUDGETS`."""
    cfg = for_profile(SokobanSearchConfig, profile, seed=seed, inputs="pixels")
    folder = work_folder(profile, "sokoban-search", seed) / "pixels"
    if load_run(folder, cfg) is None:
        built_on("sokoban-search", profile, seed, progress=progress)
    work = hold(work_folder(profile, "planning-budget", seed))
    budgets = (NO_SEARCH, *SOKOBAN_BUDGETS[profile])
    jobs = budget_jobs(work, folder, cfg, BOXOBAN_SPLITS["report"]["medium"], SOKOBAN_LEVELS[profile], budgets)
    run_jobs(jobs, progress)
    plays = {budget: budget_plays(jobs, budget) for budget in budgets}
    solved = {budget: 100.0 * np.array([p["solved"] for p in plays[budget]], np.float64) for budget in budgets}
    return [_row("sokoban-search", "boxoban-medium", budget, seed, solved[budget], solved[NO_SEARCH],
                 ms_per_action(plays[budget])) for budget in budgets]


def mcts_curve(profile: str, seed: int, progress: bool) -> list[dict]:
    """MCTS in the World Models memory on Boxing: the ``imitation`` run's policy head alone (budget
    0), then its search under each of :data:`MCTS_BUDGETS`, on the same :data:`BOXING_BOUTS` bouts."""
    built_on("boxing-wm-alphazero", profile, seed, "imitation", progress)
    work = work_folder(profile, "boxing-wm-alphazero", seed)
    run, vision, memory, cfg = trained_run(work_folder(profile, "boxing-wm", seed), work, "imitation")
    cfg = dataclasses.replace(cfg, eval_episodes=BOXING_BOUTS[profile])
    head = policy_head_games(run, vision, memory, cfg, work / "imitation", seed)
    without = np.array(head["returns"])
    rows = [_row("mcts", "boxing", NO_SEARCH, seed, without, without, head["ms_per_action"])]
    for budget in MCTS_BUDGETS[profile]:
        games = evaluation_games(run, vision, memory, cfg, work / "imitation", seed, simulations=budget)
        ms = 1000 * sum(g.seconds for g in games) / max(1, sum(len(g.actions) for g in games))
        rows.append(_row("mcts", "boxing", budget, seed, np.array([g.score for g in games]), without, ms))
    return rows


def cem_curve(profile: str, seed: int, progress: bool) -> list[dict]:
    """CEM with the value on PlaNet's Boxing model: the default value run's planner with its horizon,
    candidates and iterations set by :data:`CEM_BUDGETS` (budget H x J x I), and the value alone (H = 1:
    budget 0), on the first :data:`BOXING_BOUTS` of the value's evaluation bouts."""
    metrics = built_on("planet-boxing-value", profile, seed, progress=progress)
    base = with_added_defaults(ValuePlannerConfig, metrics["value_planner"]["config"])
    budgets = {NO_SEARCH: dict(horizon=1), **{h * j * i: dict(horizon=h, candidates=j, iterations=i)
                                              for h, j, i in CEM_BUDGETS[profile]}}
    planners = {f"budget {budget}": ValuePlannerConfig(**{**base, **changes}) for budget, changes in budgets.items()}
    scores = lever_scores(work_folder(profile, "planet-boxing-agent", seed), value_folder(profile, seed),
                          metrics, planners, metrics["bouts"][:BOXING_BOUTS[profile]], progress, folder="planning-budget")
    without = np.array(scores[f"budget {NO_SEARCH}"]["returns"])
    return [_row("cem", "boxing", budget, seed, np.array(scores[f"budget {budget}"]["returns"]), without,
                 scores[f"budget {budget}"].get("ms_per_action", float("nan"))) for budget in budgets]


def _row(planner: str, game: str, budget: int, seed: int, scores: np.ndarray, without: np.ndarray,
         ms: float) -> dict:
    """A budget's row: the mean of ``scores`` (one per bout or level), the same agent's without
    search on the same bouts or levels, and the paired gain with its 95% t interval."""
    gain = aggregate(scores - without)
    return {"planner": planner, "game": game, "budget": budget, "seed": seed, "score": float(scores.mean()),
            "no_search_score": float(without.mean()), "ms_per_action": ms, "gain": gain["mean"],
            "gain_ci_low": gain["ci_low"], "gain_ci_high": gain["ci_high"], "levels": len(scores)}


def budget_table(rows: list[dict]) -> list[dict]:
    """Per planner, game and budget over its seeds: the mean score, the paired gain over no search
    with its 95% t interval over seeds (each seed's bouts or levels paired), and ms per action."""
    keys = dict.fromkeys((r["planner"], r["game"], r["budget"]) for r in rows)
    out = []
    for planner, game, budget in keys:
        mine = [r for r in rows if (r["planner"], r["game"], r["budget"]) == (planner, game, budget)]
        gain = aggregate([r["score"] - r["no_search_score"] for r in mine])
        out.append({"planner": planner, "game": game, "budget": budget, "seeds": len(mine),
                    "score": float(np.mean([r["score"] for r in mine])), "gain": gain["mean"],
                    "gain_ci_low": gain["ci_low"], "gain_ci_high": gain["ci_high"],
                    "ms_per_action": float(np.mean([r["ms_per_action"] for r in mine]))})
    return out


def read_budget_rows(profile: str) -> list[dict]:
    """The rows :func:`write_budget_table` wrote for ``profile`` (numbers as numbers)."""
    name = "planning_budget.csv" if profile == "quick" else f"planning_budget-{profile}.csv"
    with open(data_dir("results") / name) as f:
        return [{**r, "budget": int(r["budget"]), "seed": int(r["seed"]),
                 **{k: float(r[k]) for k in ("score", "no_search_score", "ms_per_action")}} for r in csv.DictReader(f)]


def write_budget_table(profile: str) -> str:
    """Every seed's rows of ``profile`` (each run's ``metrics.json``) as one CSV of :data:`COLUMNS`,
    ``data/results/planning_budget.csv`` (``planning_budget-PROFILE.csv`` outside ``quick``);
    returns its text."""
    results = data_dir("results")
    rows = []
    for path in sorted(results.glob(f"planning-budget/{profile}-seed*/metrics.json")):
        rows += json.loads(path.read_text())["rows"]
    rows.sort(key=lambda r: (r["planner"], r["game"], r["seed"], r["budget"]))
    text = io.StringIO()
    writer = csv.DictWriter(text, COLUMNS, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    writer.writerows({**r, **{k: round(r[k], 3) for k in ("score", "no_search_score", "ms_per_action")}}
                     for r in rows)
    name = "planning_budget.csv" if profile == "quick" else f"planning_budget-{profile}.csv"
    with atomic_path(results / name) as tmp:
        tmp.write_text(text.getvalue())
    return text.getvalue()


__all__ = ["planning_budget", "sokoban_curve", "mcts_curve", "cem_curve", "MCTS_BUDGETS", "BOXING_BOUTS", "CEM_BUDGETS", "budget_table",
           "read_budget_rows", "write_budget_table", "plot_budget_curves", "SOKOBAN_BUDGETS", "SOKOBAN_LEVELS", "COLUMNS"]
