"""Planning that pays (the thesis's promise, chapter 1): each planner's score against its
search budget on a seed's trained models, the same bouts or levels for every budget:

- the Sokoban agent (``sokoban-search``) on the first Boxoban medium report levels, without search
  and under each node budget of the profile's ``sokoban_budgets`` (:func:`curve_sizes`);
- MCTS in the World Models memory (``boxing-wm-alphazero``'s default run) on Boxing: its
  policy head alone, then each number of simulations of ``mcts_budgets``;
- CEM in PlaNet's model with the learned value (``planet-boxing-value``'s default) on Boxing: CEM
  at horizon 1 (its candidates scored by the value alone), then each horizon x candidates x iterations of ``cem_budgets``.

Writes the run's ``metrics.json`` and every seed's rows of the profile
(:mod:`wmthesis.budget_curves`)."""
from __future__ import annotations

import time

import numpy as np

from wmthesis.alphazero.budget import alphazero_agent, head_games, search_changes, searched_games
from wmthesis.alphazero.config import search_settings, search_tag
from wmthesis.alphazero.variants import VARIANTS as ALPHAZERO
from wmthesis.budget_curves import BudgetCurveConfig, PLANNERS, check_planners, plot_budget_curves, write_budget_table
from wmthesis.config import for_profile, profile_name
from wmthesis.declarations import NAMES
from wmthesis.envs.boxoban import BOXOBAN_SPLITS
from wmthesis.metrics import aggregate
from wmthesis.value.config import ValuePlannerConfig
from wmthesis.value.comparison import frozen_agent, lever_scores
from wmthesis.value.variants import VALUE_VARIANTS
from wmthesis.runs import (built_on, hold, read_json, releasing_holds, results_folder, run_header, run_jobs,
                           work_folder, write_json)
from wmthesis.sokoban_search.budget import NO_SEARCH, budget_jobs, budget_plays, ms_per_action
from wmthesis.sokoban_search.config import SokobanSearchConfig
from wmthesis.sokoban_search.iteration import load_run
from wmthesis.training import with_added_defaults
from wmthesis.variants import no_variant
from wmthesis.viz import save_figure

def curve_sizes(profile: str | None) -> BudgetCurveConfig:
    """The profile's budgets and levels or bouts (:class:`~wmthesis.budget_curves.BudgetCurveConfig`)."""
    return for_profile(BudgetCurveConfig, profile)


@releasing_holds
def planning_budget(profile: str | None = None, seed: int = 0, variant: str | None = None,
                    progress: bool = True, planners: tuple[str, ...] = PLANNERS,
                    budgets: dict | None = None) -> dict:
    """The budget curve of each of ``planners`` (:data:`~wmthesis.budget_curves.PLANNERS`) on
    ``seed``'s trained models (see the module docstring); resumable level by level and bout by
    bout. ``budgets``: planner -> its budgets in place of the profile's
    (:func:`~wmthesis.budget_curves.parse_budgets`). Returns the metrics: one row per planner and
    budget (score, the same agent without search on the same levels, the paired gain over it with
    its 95% t interval over levels, milliseconds per action), the other planners' rows kept."""
    no_variant(NAMES.planning_budget, variant)
    profile, budgets = profile_name(profile), budgets or {}
    check_planners([*planners, *budgets])
    earlier = read_json(results_folder(NAMES.planning_budget, profile, seed) / "metrics.json") or {}
    started, rows = time.time(), [r for r in earlier.get("rows", []) if r["planner"] not in planners]
    curves = {"sokoban-search": sokoban_curve, "mcts": mcts_curve, "cem": cem_curve}
    for planner in planners:  # each planner's rows saved before the next begins
        rows += curves[planner](profile, seed, progress, budgets.get(planner))
        metrics = _write_run(rows, profile, seed, time.time() - started)
    return metrics


def mcts_validation(profile: str | None = None, seed: int = 0, progress: bool = True,
                    budgets: tuple | None = None, variant: str | None = None, search: dict | None = None) -> dict:
    """The MCTS curve (:func:`mcts_curve`) of ``variant`` (default: the default) with the root
    ``search`` (default: the profile's) on the validation bouts, the evidence a choice of the
    search, its variant, its root or its budget is made on: written to the run's
    ``validation-<variant>.json`` (``validation-<variant>-<search>.json`` for another root than the
    profile's), never to the report's rows, the CSV or the summary; the file's rows of other budgets
    on as many bouts are kept (a call with new budgets adds to it). Resumable bout by bout."""
    profile, started = profile_name(profile), time.time()
    variant = ALPHAZERO.check(variant).name
    rows = mcts_curve(profile, seed, progress, budgets, split="validation", variant=variant, search=search)
    name = variant if search is None else f"{variant}-{search_tag(search).replace(' ', '-')}"
    path = results_folder(NAMES.planning_budget, profile, seed) / f"validation-{name}.json"
    measured = {r["budget"] for r in rows}
    kept = [r for r in (read_json(path) or {}).get("rows", [])
            if r["budget"] not in measured and r.get("levels") == rows[0]["levels"]]
    result = {**run_header(NAMES.planning_budget, profile, seed, time.time() - started, variant=variant,
                           bouts="validation"), "rows": sorted(rows + kept, key=lambda r: r["budget"])}
    write_json(path, result)
    return result


def _write_run(rows: list[dict], profile: str, seed: int, seconds: float) -> dict:
    """The run's ``metrics.json`` (its rows so far, a summary line, the figure) and the profile's CSV."""
    out = results_folder(NAMES.planning_budget, profile, seed)
    figure = save_figure(plot_budget_curves(rows), out / "budget_curve.png")
    curves = "; ".join(f"{planner} on {game}: " + ", ".join(f"{r['budget']:,}: {r['score']:.1f}" for r in rows
                                                         if (r["planner"], r["game"]) == (planner, game))
                       for planner, game in dict.fromkeys((r["planner"], r["game"]) for r in rows))
    metrics = {**run_header(NAMES.planning_budget, profile, seed, seconds),
               "summary": f"score by search budget (0: no search): {curves}",
               "rows": rows, "files": {"figures": [str(figure)]}}
    write_json(out / "metrics.json", metrics)
    write_budget_table(profile)
    return metrics


def sokoban_curve(profile: str, seed: int, progress: bool, budgets: tuple | None = None) -> list[dict]:
    """The Sokoban agent's rows: without search (budget 0) and under each node budget of
    ``budgets`` (default the profile's ``sokoban_budgets``)."""
    cfg = for_profile(SokobanSearchConfig, profile, seed=seed, inputs="pixels")
    folder = work_folder(profile, NAMES.sokoban_search, seed) / "pixels"
    if load_run(folder, cfg) is None:
        built_on(NAMES.sokoban_search, profile, seed, progress=progress)
    work = hold(work_folder(profile, NAMES.planning_budget, seed))
    budgets = (NO_SEARCH, *(budgets or curve_sizes(profile).sokoban_budgets))
    jobs = budget_jobs(work, folder, cfg, BOXOBAN_SPLITS["report"]["medium"], curve_sizes(profile).sokoban_levels, budgets)
    run_jobs(jobs, progress)
    plays = {budget: budget_plays(jobs, budget) for budget in budgets}
    solved = {budget: 100.0 * np.array([p["solved"] for p in plays[budget]], np.float64) for budget in budgets}
    return [_row("sokoban-search", "boxoban-medium", budget, seed, solved[budget], solved[NO_SEARCH],
                 ms_per_action(plays[budget])) for budget in budgets]


def mcts_curve(profile: str, seed: int, progress: bool, budgets: tuple | None = None,
               split: str = "evaluation", variant: str | None = None, search: dict | None = None) -> list[dict]:
    """MCTS in the World Models memory on Boxing, on the loaded agent of ``variant`` (default: the
    default; trained first where it is not there): its policy head alone (budget 0), then its search
    under each number of simulations of ``budgets`` (default the profile's ``mcts_budgets``) with the
    root ``search`` (default the profile's ``mcts_search``: :func:`~wmthesis.alphazero.config.search_settings`), on the same
    ``boxing_bouts`` bouts of ``split`` (``"validation"``: games none of the evaluation bouts plays,
    to choose on). Each searched row adds where the search moved the head's action
    (:func:`~wmthesis.alphazero.budget.search_changes`)."""
    sizes = curve_sizes(profile)
    search = search_settings(profile) if search is None else dict(search)
    agent = alphazero_agent(profile, seed, variant, progress)
    folder, bouts = work_folder(profile, NAMES.planning_budget, seed), sizes.boxing_bouts
    head = head_games(agent, split, bouts, folder)
    without = np.array(head["returns"])
    tag = search_tag(search)
    rows = [{**_row("mcts", "boxing", NO_SEARCH, seed, without, without, head["ms_per_action"]), "search": tag}]
    for budget in budgets or sizes.mcts_budgets:
        games = searched_games(agent, budget, split, bouts, folder, progress, **search)
        ms = 1000 * sum(g.seconds for g in games) / max(1, sum(len(g.actions) for g in games))
        rows.append({**_row("mcts", "boxing", budget, seed, np.array([g.score for g in games]), without, ms),
                     "search": tag, **search_changes(agent.heads, games)})
    return rows


def cem_curve(profile: str, seed: int, progress: bool, budgets: tuple | None = None) -> list[dict]:
    """CEM with the value on PlaNet's Boxing model: the default value run's planner with its horizon,
    candidates and iterations set by each ``(H, J, I)`` of ``budgets`` (default the profile's
    ``cem_budgets``; budget H x J x I x its particles), and CEM at H = 1 (budget 0: each sampled first
    action scored by the value alone, the best taken, not quite the value agent's argmax), on the first
    ``boxing_bouts`` of the value's evaluation bouts."""
    metrics, work = frozen_agent(NAMES.planet_boxing_value, profile, seed, VALUE_VARIANTS.folder_name(None), progress)
    base = with_added_defaults(ValuePlannerConfig, metrics["value_planner"]["config"])
    budgets = {NO_SEARCH: dict(horizon=1), **{h * j * i * (base["particles"] or 1): dict(horizon=h, candidates=j, iterations=i)
                                              for h, j, i in budgets or curve_sizes(profile).cem_budgets}}
    planners = {f"budget {budget}": ValuePlannerConfig(**{**base, **changes}) for budget, changes in budgets.items()}
    scores = lever_scores(frozen_agent(NAMES.planet_boxing_agent, profile, seed, progress=progress)[1], work,
                          metrics, planners, metrics["bouts"][:curve_sizes(profile).boxing_bouts], progress,
                          folder=NAMES.planning_budget)
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


__all__ = ["planning_budget", "sokoban_curve", "mcts_curve", "mcts_validation", "cem_curve", "curve_sizes"]
