"""One results table over every run: ``python -m wmthesis summary``.

Reads each ``metrics.json`` under ``data/results/`` (whatever wrote it: ``reproduce``, a notebook
or a ``sweep``), takes each run's headline score, and for every experiment, variant and profile
reports the number of seeds, their mean and sample standard deviation, and a 95% confidence
interval of the mean over seeds: Student's t interval, ``mean +- t_{0.975, n-1} s / sqrt(n)``
(``scipy.stats.t``), exact for normally distributed seed scores and the honest width for the few
seeds a CPU affords (a bootstrap over 3 seeds would be far too narrow). The headline rows stand
beside the thesis's figure and the best published one (:mod:`wmthesis.headline`). Writes
``data/results/summary.{md,json,csv}`` and ``summary.png`` (every seed as a point, the mean and
its interval).
"""
from __future__ import annotations

import csv
import io
import json
import math
import re
import warnings
from pathlib import Path
from typing import NamedTuple

import numpy as np

from wmthesis.budget import Steps
from wmthesis.budget_curves import budget_markdown, read_budget_rows
from wmthesis.experiments import EXPERIMENTS, VARIANTS
from wmthesis.declarations import NAMES, DECLARED, Of, resolve
from wmthesis.headline import BEGIN, END, ablation_table, headline_rows, headline_table, judge, readme_with_table
from wmthesis.metrics import aggregate
from wmthesis.notebook_index import BEGIN as NOTEBOOKS_BEGIN, END as NOTEBOOKS_END, notebook_rows, notebook_table
from wmthesis.references import published_figures
from wmthesis.schemas import check_metrics
from wmthesis.scores import number
from wmthesis.runs import atomic_path
from wmthesis.utils import data_dir, shipped_dir
from wmthesis.viz import save_figure

INTERVAL = "95% Student-t interval of the mean over seeds (scipy.stats.t)"

# Experiment -> the range its score cannot leave (its interval is clipped to it): its declaration's.
BOUNDS = Of(lambda d: d.bounds, lambda d: d.bounds is not None)


def choice_seeds(experiment: str) -> tuple:
    """The seeds ``experiment``'s recipe was chosen on (its declaration's ``choice_seeds``; none by default)."""
    declared = DECLARED[experiment].choice_seeds
    return () if declared is None else tuple(resolve(declared))


class Run(NamedTuple):
    """One run's headline: which experiment, variant (None: it has none), profile and seed, its
    score, wall time and file, the kind of machine and the torch threads it ran with, its frozen
    model's fingerprint, and the real environment steps it learned from (``agent_steps``, None where
    not known; ``steps_at_most``: an upper bound, :mod:`wmthesis.budget`)."""
    experiment: str
    variant: str | None
    profile: str
    seed: int
    score: float
    wall_seconds: float | None
    path: str
    machine: str | None = None
    threads: int | None = None
    model: str | None = None
    agent_steps: int | None = None
    steps_at_most: bool = False


def model_fingerprint(metrics: dict) -> str | None:
    """The frozen PlaNet model a value run (of an experiment that declares ``frozen_model``: its
    variants all mean to share their seed's model) was fitted on, told by what the thesis's CEM scored on it
    over the same evaluation bouts (``"mean/std/min/max"``: one model plays those bouts alike;
    a model trained again, even from the same seed, does not). None for other experiments, whose
    variants are paired by seed alone, and for a run that did not play the thesis's CEM."""
    key = DECLARED[metrics["experiment"]].frozen_model
    planet = metrics.get(key) if key else None
    if not planet:
        return None
    return f"{planet['mean']:.2f}/{planet['std']:.3f}/{planet['min']:g}/{planet['max']:g}"


def run_scores(metrics: dict) -> dict[str | None, float]:
    """A run's headline score per variant it ran (``{None: score}`` for experiments without
    variants; AlphaZero's file may hold several), read as its declaration says
    (:mod:`wmthesis.scores`). Empty for runs without a score (the PlaNet model study reports
    errors). Raises KeyError or TypeError on a file of another shape."""
    return resolve(DECLARED[metrics["experiment"]].score)(metrics)


def own_steps(metrics: dict) -> Steps | None:
    """The real environment steps a run learned from, read as its declaration says
    (:mod:`wmthesis.budget`), without the runs it builds on; None where it declares no reader or
    its file predates what the reader needs."""
    reader = DECLARED[metrics["experiment"]].agent_steps
    try:
        return None if reader is None else resolve(reader)(metrics)
    except (KeyError, TypeError, IndexError):
        return None


def with_budgets(runs: list[Run], own: dict[str, Steps | None]) -> list[Run]:
    """``runs`` with their ``agent_steps``: a run's own (``own``, by file; a Sokoban report run
    keeps the one its report states) plus, for each experiment its declaration builds on, the
    default variant's run of the same profile and seed (None where one of them is not known)."""
    by_key = {(r.experiment, r.variant, r.profile, r.seed): r for r in runs}

    def default(experiment: str, profile: str, seed: int) -> Run | None:
        registry = VARIANTS.get(experiment)
        return by_key.get((experiment, None if registry is None else registry.folder_name(None), profile, seed))

    def budget(run: Run) -> Steps | None:
        steps = own.get(run.path)
        if steps is None and run.agent_steps is not None:  # a report's run: its agent's store
            steps = Steps({"store": run.agent_steps})
        for experiment in DECLARED[run.experiment].builds_on:
            base = default(experiment, run.profile, run.seed)
            base_steps = None if base is None else budget(base)
            if steps is None or base_steps is None:
                return None
            steps = base_steps + steps
        return steps

    out = []
    for run in runs:
        steps = budget(run)
        out.append(run if steps is None else run._replace(agent_steps=steps.total, steps_at_most=steps.at_most))
    return out


def result_folders(folder: str | Path | None = None) -> list[Path]:
    """The folders runs are read from: ``folder`` alone where given; else the repository's
    committed ``data/results`` and, where ``$WMTHESIS_DATA`` names another folder, its ``results``
    (those that exist; none is created)."""
    if folder is not None:
        return [Path(folder)]
    shipped, own = shipped_dir(), data_dir() / "results"
    found = [own] if shipped is None or (shipped / "results").resolve() == own.resolve() else [shipped / "results", own]
    return [f for f in found if f.is_dir()]


def read_runs(folder: str | Path | None = None) -> list[Run]:
    """Every run under ``folder`` (default: :func:`result_folders`), one :class:`Run` per variant in a
    ``metrics.json``, and per kind of a Sokoban report evaluation (:func:`report_runs`), each with
    the real environment steps it learned from (:func:`with_budgets`). A file that is not JSON or
    not a run's metrics is skipped with a warning naming it; when two files hold the same run, the
    newer one counts."""
    folders = result_folders(folder)
    runs: dict[tuple, Run] = {}
    own: dict[str, Steps | None] = {}
    for path in sorted((p for f in folders for p in f.rglob("metrics.json")), key=lambda p: p.stat().st_mtime):
        try:
            metrics = check_metrics(json.loads(path.read_text()), path)
            if metrics["experiment"] not in EXPERIMENTS:
                raise ValueError(f"unknown experiment {metrics['experiment']!r}")
            header = (str(metrics["profile"]), run_seed(metrics["seed"]),
                      metrics.get("first_run_wall_seconds", metrics.get("wall_seconds")))
            scores = run_scores(metrics)
        except (ValueError, KeyError, TypeError, AttributeError, IndexError) as error:
            said = str(error).removeprefix(f"{path}: ")
            warnings.warn(f"{path}: skipped, not a run's metrics ({type(error).__name__}: {said})", stacklevel=2)
            continue
        broken = {variant: score for variant, score in scores.items() if not math.isfinite(float(score))}
        if broken:
            warnings.warn(f"{path}: skipped, its score is not a number ({broken})", stacklevel=2)
            continue
        registry = VARIANTS.get(metrics["experiment"])
        gone = [v for v in metrics.get("variants", [metrics.get("variant")]) if v is not None and registry is not None
                and v not in registry]
        if gone:
            warnings.warn(f"{path.parent}: skipped, written by variant {gone[0]!r}, no longer in the code (its numbers: "
                          f"{registry.findings})", stacklevel=2)
            continue
        machine, threads = machine_kind(metrics.get("machine")), metrics.get("threads")
        if header[1] in choice_seeds(metrics["experiment"]):  # the choice's evidence: a row apart
            scores = {f"{variant or 'first recipe'}, validation seeds": score for variant, score in scores.items()}
        own[str(path)] = own_steps(metrics)
        for variant, score in scores.items():
            run = Run(metrics["experiment"], variant, *header[:2], score, header[2], str(path), machine, threads,
                      model_fingerprint(metrics))
            runs[run[:4]] = run
    for run in (run for f in folders for run in report_runs(f)):
        runs[run[:4]] = run
    return with_budgets(sorted(runs.values(), key=lambda r: (r.experiment, str(r.variant), r.profile, r.seed)), own)


def run_seed(seed) -> int:
    """A run's seed: a whole number from 0 (JSON's ``5``, never ``5.7``, ``-5`` or ``true``);
    ValueError otherwise."""
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"its seed is {seed!r}, not a whole number from 0")
    return seed


def report_runs(folder: Path) -> list[Run]:
    """The Sokoban agent's closing evaluations on Boxoban's report files (``evaluate-sokoban``
    writes ``sokoban-search/PROFILE-seedS/boxoban-report-N.json``): one :class:`Run` per kind,
    variant ``boxoban-KIND, N report levels``, its score the percentage solved. A file of another
    shape is skipped with a warning naming it."""
    runs = []
    for path in sorted(folder.glob("sokoban-search/*/boxoban-report-*.json")):
        try:
            report = json.loads(path.read_text())
            runs += [Run(NAMES.sokoban_search, f"boxoban-{kind}, {int(report['levels'])} report levels",
                         str(report["profile"]), run_seed(report["seed"]), 100.0 * number(row["solve_rate"]),
                         report_seconds(report, row), str(path), machine_kind(report.get("machine")),
                         agent_steps=report.get("env_steps"))
                     for kind, row in report["rows"].items()]
        except (ValueError, KeyError, TypeError, AttributeError) as error:
            warnings.warn(f"{path}: skipped, not a Boxoban report ({type(error).__name__}: {error})", stacklevel=2)
    return runs



def report_seconds(report: dict, row: dict) -> float | None:
    """A Boxoban report run's time: its agent's training (``training_wall_seconds``, absent from
    reports written before 2026-11-28) and the search on that kind's levels, one level after
    another (``seconds_per_level`` x ``levels``); None where the training time is not recorded."""
    training = report.get("training_wall_seconds")
    return None if training is None else round(float(training) + float(row["seconds_per_level"]) * int(row["levels"]), 1)


def machine_kind(machine: str | None) -> str | None:
    """``"host (x86_64, 2 cores)"`` -> ``"x86_64, 2 cores"``: the kind of machine, not its name."""
    return machine[machine.find("(") + 1:-1] if isinstance(machine, str) and "(" in machine else machine


def summarise(runs: list[Run]) -> list[dict]:
    """One row per experiment, variant and profile: the aggregate over its seeds, the seeds'
    scores, wall times and machines, and what the score measures (the published figures beside
    them: :mod:`wmthesis.headline`)."""
    groups: dict[tuple, list[Run]] = {}
    for run in runs:
        groups.setdefault((run.experiment, run.variant, run.profile), []).append(run)
    return [{"experiment": experiment, "variant": variant, "profile": profile,
             "measure": DECLARED[experiment].measure,
             **aggregate([r.score for r in group], BOUNDS.get(experiment)),
             "seeds": [r.seed for r in group], "scores": [r.score for r in group],
             "wall_seconds": [r.wall_seconds for r in group], "machines": [r.machine for r in group],
             "threads": [r.threads for r in group], "models": [r.model for r in group],
             "agent_steps": [r.agent_steps for r in group], "steps_at_most": any(r.steps_at_most for r in group)}
            for (experiment, variant, profile), group in groups.items()]


def _number(value, digits: int = 1) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def markdown_table(rows: list[dict]) -> str:
    """Every row of the summary (each experiment's variants and ablations) as a markdown table, the
    interval named under it."""
    lines = ["| experiment | variant | profile | n | mean | std | 95% CI | seeds: scores | wall min per seed |",
             "|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        interval = "one seed" if row["ci_low"] is None else f"[{row['ci_low']:.1f}, {row['ci_high']:.1f}]"
        seeds = ", ".join(f"{s}: {v:.1f}" for s, v in zip(row["seeds"], row["scores"]))
        walls = ", ".join("?" if w is None else f"{w / 60:.0f}" for w in row["wall_seconds"])
        lines.append(f"| {row['experiment']} | {row['variant'] or ''} | {row['profile']} | {row['n']} | "
                     f"{row['mean']:.1f} | {_number(row['std'])} | {interval} | {seeds} | {walls} |")
    clipped = "; ".join(f"{name} to [{low:g}, {high:g}]" for name, (low, high) in BOUNDS.items())
    return "\n".join(lines + ["", f"Interval: {INTERVAL}, clipped to the score's range ({clipped}). A row with "
                                  "n = 1 stands on one seed. Wall time: the run that computed it, in minutes."])


def _csv(rows: list[dict]) -> str:
    fields = ["experiment", "variant", "profile", "n", "mean", "std", "ci_low", "ci_high", "measure", "seeds", "scores"]
    out = io.StringIO()
    writer = csv.DictWriter(out, fields, extrasaction="ignore")
    writer.writeheader()
    for row in rows:
        writer.writerow({**row, "variant": row["variant"] or "", "seeds": " ".join(map(str, row["seeds"])),
                         "scores": " ".join(f"{v:g}" for v in row["scores"])})
    return out.getvalue()


def summary_figure(rows: list[dict]):
    """Each row's seeds as points, with its mean and 95% interval (one panel per experiment,
    since their scores are on different scales)."""
    import matplotlib.pyplot as plt

    experiments = list(dict.fromkeys(row["experiment"] for row in rows))
    heights = [max(2.0, 0.5 + 0.5 * sum(row["experiment"] == e for row in rows)) for e in experiments]
    fig, axes = plt.subplots(len(experiments), 1, figsize=(7, sum(heights)), squeeze=False,
                             gridspec_kw={"height_ratios": heights})
    for ax, experiment in zip(axes[:, 0], experiments):
        mine = [row for row in rows if row["experiment"] == experiment]
        for y, row in enumerate(mine):
            ax.scatter(row["scores"], np.full(row["n"], y), color="tab:blue", alpha=0.6, zorder=3)
            if row["ci_low"] is not None:
                ax.plot([row["ci_low"], row["ci_high"]], [y, y], color="black", lw=2)
            ax.scatter([row["mean"]], [y], marker="|", s=300, color="black", zorder=4)
        at: dict[float, list[str]] = {}  # published numbers, those at one value named together
        for name, value, *_ in published_figures(experiment):
            if isinstance(value, (int, float)):
                at.setdefault(float(value), []).append(name.split(" (")[0].split(",")[0])
        for value, names in at.items():
            ax.axvline(value, ls=":", lw=1, color="gray")
            ax.annotate(" / ".join(names), (value, len(mine) - 0.5), fontsize=6, rotation=90, va="top", color="gray")
        ax.set_yticks(range(len(mine)), [f"{r['variant'] or 'default'} ({r['profile']}, n={r['n']})" for r in mine])
        ax.set_ylim(-0.5, len(mine) - 0.5)
        ax.set_title(f"{experiment}: {DECLARED[experiment].measure}", fontsize=9)
    fig.tight_layout()
    return fig


HEADLINE_LINE = re.compile(r"headline · (?P<experiment>[\w-]+) · (?P<variant>.+?) · (?P<profile>\w+): "
                           r"(?P<mean>-?[\d.]+) .*?over (?P<n>\d+) seeds? \((?P<seeds>[\d ]+)\)")


def variant_label(experiment: str, variant: str | None) -> str:
    """A row's variant as a headline line names it: its own name; for the runs in the experiment's
    own folders (``None``), the variant they are (its registry's root), else ``default``."""
    if variant is not None:
        return variant
    registry = VARIANTS.get(experiment)
    return registry.root if registry is not None and registry.root else "default"


def headline_line(experiment: str, variant: str | None = None, profile: str = "quick",
                  folder: str | Path | None = None) -> str:
    """The line a notebook prints for a headline number: the summary's row of ``experiment``'s
    ``variant`` (None: its own folders' runs) over every seed under ``folder`` (default
    ``data/results``), read the way ``summary`` reads it, so the two agree (tested)."""
    rows = [r for r in summarise(read_runs(folder))
            if (r["experiment"], r["variant"], r["profile"]) == (experiment, variant, profile)]
    if not rows:
        raise ValueError(f"no {profile} run of {experiment} ({variant or 'its own folders'}) under "
                         f"{folder or data_dir('results')}: run `python -m wmthesis reproduce {experiment}` first")
    row = rows[0]
    interval = "" if row["ci_low"] is None else f" [{row['ci_low']:.1f}, {row['ci_high']:.1f}]"
    return (f"headline · {experiment} · {variant_label(experiment, variant)} · {profile}: {row['mean']:.1f}{interval} "
            f"over {row['n']} seed{'s' if row['n'] > 1 else ''} ({' '.join(map(str, row['seeds']))})")


def headlines(profile: str = "quick", folder=None) -> list[dict]:
    """Every headline as plain data (floats, lists, strings): ``experiment``, ``variant``,
    ``title``, ``section``, ``notebook``, the ``thesis``'s figure and the best ``published`` one
    (each ``{"name", "value", "source"}`` or None), and ``ours`` over seeds (``mean``, ``ci_low``,
    ``ci_high``, ``n``, ``seeds``, ``scores``; None where not run yet) with its ``verdict``
    (:func:`wmthesis.headline.judge`), read from every run's
    ``metrics.json`` under ``folder`` (default: the committed results and the data folder's,
    :func:`result_folders`) as ``summary`` reads them; a warning in one line where there are none."""
    def plain(value):
        return None if value is None else float(value)

    def reference(ref):
        return None if ref is None else {"name": ref.name, "value": ref.value, "source": ref.source}

    out = []
    rows = summarise(read_runs(folder))
    if not rows:
        where = ", ".join(map(str, result_folders(folder))) or f"{data_dir() / 'results'} (no such folder)"
        warnings.warn(f"no results under {where}: every headline reads 'not run yet'", stacklevel=2)
    for entry in headline_rows(rows, profile):
        h, row = entry["headline"], entry["row"]
        ours = None if row is None else {"mean": plain(row["mean"]), "ci_low": plain(row["ci_low"]),
                                         "ci_high": plain(row["ci_high"]), "n": int(row["n"]),
                                         "seeds": [int(s) for s in row["seeds"]],
                                         "scores": [plain(s) for s in row["scores"]]}
        out.append({"experiment": h.experiment, "variant": h.variant, "title": h.title, "section": h.section,
                    "notebook": h.notebook, "thesis": reference(h.thesis), "published": reference(h.published),
                    "ours": ours, "verdict": judge(h, row, rows)})
    return out


def write_summary(folder: str | Path | None = None, readme: str | Path | None = None, force: bool = False) -> list[dict]:
    """Read every run under ``folder`` (default ``data/results``), write ``summary.md`` (the
    headline table, :mod:`wmthesis.headline`, then every row), ``summary.json``, ``summary.csv``
    and ``summary.png`` there, and into ``readme`` where given the headline table and the notebook
    index (:mod:`wmthesis.notebook_index`) between their markers; return the rows. A table built
    from fewer runs than ``readme``'s (more headline rows "not run yet") is refused before anything
    is written, naming the rows it would drop, unless ``force``."""
    folder = Path(folder) if folder is not None else data_dir("results")
    rows = summarise(read_runs(folder))
    headline = headline_table(rows)
    if readme is not None and not force:
        check_not_fewer(Path(readme).read_text(), headline, folder)
    ablations = ablation_table(rows, roots={name: v.root for name, v in VARIANTS.items() if v.root})
    budget = budget_markdown(read_budget_rows("quick", folder)) or "no seed measured yet (`python -m wmthesis reproduce planning-budget`)"
    outputs = {"md": f"## Headline\n\n{headline}\n\n## Ablations: each variant against its headline row, paired by seed on the same frozen model"
                     f"\n\n{ablations}\n\n## Score against search budget, quick (planning_budget.csv)\n\n"
                     f"{budget}\n\n## Every variant\n\n{markdown_table(rows)}\n",
               "json": json.dumps({"interval": INTERVAL, "rows": rows}, indent=1),
               "csv": _csv(rows)}
    for suffix, text in outputs.items():
        with atomic_path(folder / f"summary.{suffix}") as tmp:
            tmp.write_text(text)
    if rows:
        save_figure(summary_figure(rows), folder / "summary.png")
    if readme is not None:  # the front door's two generated blocks: the results and the notebook index
        readme = Path(readme)
        text = readme_with_table(readme.read_text(), headline)
        text = readme_with_table(text, notebook_table(notebook_rows(data=folder.parent)), NOTEBOOKS_BEGIN, NOTEBOOKS_END)
        with atomic_path(readme) as tmp:
            tmp.write_text(text)
    return rows


def check_not_fewer(readme: str, table: str, folder: Path) -> None:
    """ValueError where ``table`` shows a headline row that ``readme``'s table shows over fewer
    seeds, or leaves it "not run yet"."""
    start = readme.find(BEGIN)
    held = _seeds_shown(readme[start:readme.find(END, start)] if start >= 0 else "")
    shown = _seeds_shown(table)
    dropped = [f"{title} ({n} -> {shown.get(title, 0)} seeds)" for title, n in held.items() if shown.get(title, 0) < n]
    if dropped:
        raise ValueError(f"{folder} holds fewer runs than the README's table: it would drop {'; '.join(dropped)} "
                         "(is WMTHESIS_DATA the folder you meant? `summary --force` writes it anyway)")


def _seeds_shown(table: str) -> dict[str, int]:
    """A headline table's rows: title -> the seeds it is shown over (0: not run yet)."""
    seeds = {}
    for line in table.splitlines():
        title = line.split(" | ")[0].lstrip("| ")
        if "| not run yet |" in line:
            seeds[title] = 0
        elif (found := re.search(r"\((\d+) seeds?\) \|", line)) is not None:
            seeds[title] = int(found[1])
    return seeds


__all__ = ["check_not_fewer", "headlines", "Run", "run_scores", "read_runs", "report_runs", "aggregate", "summarise", "markdown_table", "summary_figure",
           "write_summary", "headline_line", "variant_label", "model_fingerprint", "HEADLINE_LINE", "INTERVAL"]
