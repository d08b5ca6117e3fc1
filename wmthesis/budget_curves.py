"""Score against search budget over seeds: the rows every ``planning-budget`` run writes,
as one CSV (``data/results/planning_budget.csv``), a table over seeds and a figure. One row per
planner, game, budget and seed: the score, the same agent's without search on the same bouts or
levels, and milliseconds per action (:data:`COLUMNS`); budget 0 is the row without search."""
from __future__ import annotations

import csv
import io
import json

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wmthesis.config import DEFAULT_PROFILE, PLANNERS
from wmthesis.metrics import aggregate
from wmthesis.runs import atomic_path
from wmthesis.utils import data_dir

NO_SEARCH = 0
COLUMNS = ("planner", "game", "budget", "seed", "score", "no_search_score", "ms_per_action", "search", "changed",
           "return_changed", "return_kept")
CHANGES = ("changed", "return_changed", "return_kept")  # MCTS: where the search moved its head's action



@dataclass(frozen=True)
class BudgetCurveConfig:
    """The budgets each curve plays (the thesis profile's; ``quick`` and ``smoke`` override them in
    :data:`~wmthesis.config.OVERRIDES`): ``sokoban_budgets``, nodes a search may expand, on the
    first ``sokoban_levels`` Boxoban medium report levels; ``mcts_budgets``, simulations an action;
    ``mcts_search``, the root it searches with (``(name, value)`` pairs of
    :class:`~wmthesis.alphazero.config.AlphaZeroConfig` fields in place of the agent's own: the
    PUCT root acting on the most visited action, equal counts going to the higher prior, chosen on
    validation bouts, ``docs/findings/planning-budget.md``);
    ``cem_budgets``, CEM with the value's (H, J, I), H x J x I imagined steps an action (CEM at
    H = 1, each sampled first action scored by the value alone, is the row without search);
    Boxing's curves on ``boxing_bouts`` evaluation bouts a seed, the same for every budget."""
    sokoban_budgets: tuple = (1_000, 5_000, 20_000, 40_000, 160_000)
    sokoban_levels: int = 1000
    mcts_budgets: tuple = (2, 4, 8, 16, 64, 256)
    mcts_search: tuple = (("tie_break", "prior"),)
    boxing_bouts: int = 10
    cem_budgets: tuple = ((3, 1000, 10), (6, 1000, 10), (12, 1000, 10))


def check_planners(planners) -> None:
    """ValueError (one line, naming the valid ones) for the first of ``planners`` not in :data:`PLANNERS`."""
    unknown = [p for p in planners if p not in PLANNERS]
    if unknown:
        raise ValueError(f"unknown planner {unknown[0]!r} (valid: {', '.join(PLANNERS)})")


def parse_budgets(planner: str, text: str) -> tuple:
    """``planner``'s budgets from ``text``: positive integers ``"16,64,256"`` (simulations for
    ``mcts``, nodes for ``sokoban-search``), or ``"HxJxI"`` triples for ``cem`` (horizon,
    candidates, iterations; ``"6x100x3,12x100x3"``). The row without search (budget 0; CEM's
    horizon 1, the value alone) is measured always, so it is refused here, as are an unknown
    planner, a negative number and one that is not an integer: ValueError in one line."""
    check_planners([planner])
    items = [item.strip() for item in text.split(",") if item.strip()]
    if not items:
        raise ValueError(f"no budget in {text!r}: give {planner}'s budgets, e.g. {_EXAMPLES[planner]}")
    budgets = tuple(_budget(planner, item) for item in items)
    return tuple(dict.fromkeys(budgets))  # each once, in the order given


# per planner (PLANNERS' order): the largest budget a curve takes, 64 times the largest measured
# (160,000 nodes, 256 simulations; CEM: horizon, candidates, iterations), and budgets to give
MOST = dict(zip(PLANNERS, (10_000_000, 16_384, (100, 100_000, 100))))
_EXAMPLES = dict(zip(PLANNERS, ("1000,5000,40000", "16,64,256", "6x100x3,12x100x3")))


def _budget(planner: str, item: str):
    """One budget of ``planner`` (see :func:`parse_budgets`)."""
    parts = item.lower().split("x") if planner == "cem" else [item]
    if planner == "cem" and len(parts) != 3:
        raise ValueError(f"cem budget {item!r} is not HxJxI (horizon x candidates x iterations, e.g. 6x100x3)")
    try:
        numbers = [int(part) for part in parts]
    except ValueError:
        raise ValueError(f"{planner} budget {item!r} is not {'made of integers' if planner == 'cem' else 'an integer'}"
                         f" (e.g. {_EXAMPLES[planner]})") from None
    if any(n < 0 for n in numbers):
        raise ValueError(f"{planner} budget {item!r} is negative: a budget counts "
                         f"{'imagined steps' if planner == 'cem' else 'simulations' if planner == 'mcts' else 'nodes'}")
    most = MOST[planner]
    if any(n > m for n, m in zip(numbers, most if planner == "cem" else (most,))):
        raise ValueError(f"{planner} budget {item!r} is above the most one run takes "
                         f"({'x'.join(f'{m:,}' for m in most) if planner == 'cem' else f'{most:,}'}): "
                         "a search that large would not end")
    if planner == "cem":
        if 0 in numbers:
            raise ValueError(f"cem budget {item!r} has a 0: horizon, candidates and iterations are 1 or more")
        if numbers[0] == 1:
            raise ValueError(f"cem budget {item!r}: horizon 1 is the value alone (CEM's candidates scored by Q), the row without search, "
                             "measured always")
        return tuple(numbers)
    if numbers[0] == NO_SEARCH:
        raise ValueError(f"{planner} budget 0 is the row without search, measured always: give budgets of 1 or more")
    return numbers[0]


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
                    color=f"C{seed % 10}", label=f"seed {seed}")  # a seed's colour is the same in every panel
        over = [aggregate([r["score"] for r in mine if r["budget"] == b]) for b in x]
        ax.plot(list(x.values()), [a["mean"] for a in over], "k-", lw=2, label="mean")
        if all(a["ci_low"] is not None for a in over):
            ax.fill_between(list(x.values()), [a["ci_low"] for a in over], [a["ci_high"] for a in over], color="k",
                            alpha=0.12, label="95% interval")
        ax.set_xscale("log")
        ax.minorticks_off()  # the budgets alone label the axis
        ax.set_xticks(list(x.values()), ["none", *(f"{b:,}" for b in searched)], rotation=30, fontsize=7)
        ax.set_xlabel("search budget")
        ax.set_ylabel("score")
        ax.set_title(f"{planner} on {game}", fontsize=9)
    shown = {}  # every panel's seeds, the mean and the band, once each, under the panels
    for ax in axes[0]:
        shown.update(zip(*reversed(ax.get_legend_handles_labels())))
    order = sorted(shown, key=lambda label: (not label.startswith("seed"), label))
    fig.legend([shown[label] for label in order], order, fontsize=7, loc="lower center", ncol=len(order),
               bbox_to_anchor=(0.5, -0.06))
    fig.tight_layout()
    return fig


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


def row_line(row: dict) -> str:
    """One row of a curve as the command line prints it: the score, the paired gain over no
    search with its interval, the time an action and, for MCTS, where the search moved its head."""
    interval = "" if row["gain_ci_low"] is None else f" [{row['gain_ci_low']:+.1f}, {row['gain_ci_high']:+.1f}]"
    gain = "" if row["budget"] == NO_SEARCH else f", gain {row['gain']:+.1f}{interval}"
    signed = lambda x: "none" if x is None else f"{x:+.2f}"  # noqa: E731
    changed = "" if row.get("changed") is None else \
        (f", search moved the head's action on {100 * row['changed']:.0f}% of steps (next-10-step return "
         f"{signed(row['return_changed'])} there, {signed(row['return_kept'])} elsewhere)")
    return (f"{row['planner']} on {row['game']}, budget {row['budget']:,}: {row['score']:.1f}{gain}, "
            f"{row['ms_per_action']:.1f} ms an action{changed}")


def budget_box(rows: list[dict], profile: str = DEFAULT_PROFILE) -> str:
    """The chapter's opening box (Markdown): the thesis's promise, and per planner and game the
    verdict (:mod:`wmthesis.verdicts`) on the claim that search pays, a paired gain over no search
    above 0, at each of its budgets: the largest budget's gain with its 95% interval over seeds, then
    the budgets by verdict."""
    from wmthesis.references import THESIS_PLANNING
    from wmthesis.verdicts import RULE, Claim, verdict

    pays = Claim("gain")
    lines = ["> **Score against search budget** (beyond the thesis: its promise, chapter 1)  ",
             f"> **The thesis:** \"{THESIS_PLANNING.value}\" ({THESIS_PLANNING.source})  ",
             "> **Learned from:** no steps of its own: each planner searches the model of an agent that ships "
             "(notebooks 03, 07 and 10 state the agent steps each learned from)  "]
    table = budget_table(rows)
    for planner, game in dict.fromkeys((r["planner"], r["game"]) for r in table):
        searched = [r for r in table if (r["planner"], r["game"]) == (planner, game) and r["budget"] != NO_SEARCH]
        if not searched:
            continue
        said = {r["budget"]: verdict(pays, r["gain"], r["gain_ci_low"], r["gain_ci_high"], r["seeds"]) for r in searched}
        top = max(searched, key=lambda r: r["budget"])
        interval = "" if top["gain_ci_low"] is None else f" [{top['gain_ci_low']:+.1f}, {top['gain_ci_high']:+.1f}]"
        by_word: dict[str, list[str]] = {}
        for budget, v in said.items():
            by_word.setdefault(str(v), []).append(f"{budget:,}")
        verdicts = "; ".join(f"{word} at {', '.join(budgets)}" for word, budgets in by_word.items())
        lines.append(f"> **Ours** (`{profile}`), {planner} on {game}: {top['score']:.1f} at budget {top['budget']:,}, "
                     f"{top['gain']:+.1f}{interval} over no search on the same bouts or levels ({top['seeds']} "
                     f"seed{'s' * (top['seeds'] > 1)}); **Verdict** on the claim \"{pays.words()}\", by budget: "
                     f"{verdicts}  ")
    lines.append(f"> *The verdict's rule:* {RULE}")
    return "\n".join(lines).rstrip()


def budget_markdown(rows: list[dict]) -> str:
    """:func:`budget_table` of ``rows`` as markdown (an empty string without rows)."""
    if not rows:
        return ""
    lines = ["| planner | game | budget | seeds | score | gain over no search [95% interval] | ms an action |",
             "|---|---|---|---|---|---|---|"]
    for r in budget_table(rows):
        interval = "" if r["gain_ci_low"] is None else f" [{r['gain_ci_low']:+.1f}, {r['gain_ci_high']:+.1f}]"
        lines.append(f"| {r['planner']} | {r['game']} | {r['budget']:,} | {r['seeds']} | {r['score']:.1f} | "
                     f"{r['gain']:+.1f}{interval} | {r['ms_per_action']:.1f} |")
    return "\n".join(lines)


def changes_markdown(rows: list[dict]) -> str:
    """Where MCTS moved its policy head's action, per budget over its seeds (:data:`CHANGES`): the
    share of steps, and the real return over the next steps where it did and where it did not,
    as markdown (an empty string without MCTS rows)."""
    mcts = [r for r in rows if r["planner"] == "mcts" and r["budget"] != NO_SEARCH and r.get("changed") is not None]
    if not mcts:
        return ""
    def mean(key: str, mine: list) -> float | None:
        values = [r[key] for r in mine if r[key] is not None]
        return float(np.mean(values)) if values else None

    signed = lambda x: "none" if x is None else f"{x:+.3f}"  # noqa: E731
    lines = ["| simulations | seeds | steps where the search moved the head's action | next-10-step return there | "
             "elsewhere | score gain |", "|---|---|---|---|---|---|"]
    for budget in sorted({r["budget"] for r in mcts}):
        mine = [r for r in mcts if r["budget"] == budget]
        lines.append(f"| {budget:,} | {len(mine)} | {100 * mean('changed', mine):.1f}% | {signed(mean('return_changed', mine))} | "
                     f"{signed(mean('return_kept', mine))} | {np.mean([r['score'] - r['no_search_score'] for r in mine]):+.1f} |")
    return "\n".join(lines)


def table_name(profile: str) -> str:
    """The CSV of ``profile``'s curves: ``planning_budget.csv`` for the default profile,
    ``planning_budget-PROFILE.csv`` for the others."""
    return "planning_budget.csv" if profile == DEFAULT_PROFILE else f"planning_budget-{profile}.csv"


def read_budget_rows(profile: str, folder: Path | None = None) -> list[dict]:
    """The rows :func:`write_budget_table` wrote for ``profile`` in ``folder`` (default
    ``data/results``), numbers as numbers; none before the first seed is measured."""
    path = (data_dir("results") if folder is None else Path(folder)) / table_name(profile)
    if not path.is_file():  # no seed measured yet in this profile
        return []
    with open(path) as f:
        return [{**r, "budget": int(r["budget"]), "seed": int(r["seed"]),
                 **{k: float(r[k]) for k in ("score", "no_search_score", "ms_per_action")},
                 **{k: float(r[k]) if r.get(k) else None for k in CHANGES}} for r in csv.DictReader(f)]


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
    writer.writerows({**r, **{k: round(r[k], 3) for k in ("score", "no_search_score", "ms_per_action")},
                      **{k: round(r[k], 4) for k in CHANGES if r.get(k) is not None}} for r in rows)
    with atomic_path(results / table_name(profile)) as tmp:
        tmp.write_text(text.getvalue())
    return text.getvalue()


__all__ = ["BudgetCurveConfig", "COLUMNS", "CHANGES", "NO_SEARCH", "PLANNERS", "check_planners", "parse_budgets", "budget_table", "budget_markdown", "changes_markdown", "row_line", "table_name", "read_budget_rows", "write_budget_table", "plot_budget_curves"]
