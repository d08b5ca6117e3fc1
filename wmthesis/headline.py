"""The front door's table: each thesis experiment, and each agent beyond the thesis, over its seeds
beside the thesis's own figure and the best published figure at the budget it was reached with.

Rows come from the summary's rows (:func:`wmthesis.summary.summarise`): a :class:`Headline`
names the row (experiment, variant) that stands for an experiment; every figure it prints is the
summary's, every published one is :mod:`wmthesis.references`'s. ``python -m wmthesis summary``
writes the table into ``data/results/summary.md`` and between the markers of the README
(:func:`readme_with_table`).
"""
from __future__ import annotations

import re
from typing import NamedTuple

import numpy as np

from wmthesis.alphazero.variants import VARIANTS as ALPHAZERO
from wmthesis.budget import short
from wmthesis.declarations import DECLARED, NAMES
from wmthesis.scores import SOKOBAN_VISION
from wmthesis.world_models.variants import BOXING_WM
from wmthesis.references import (BOXOBAN, RANDOM, THESIS_ALPHAZERO, THESIS_PLANET_BOXING, THESIS_PLANET_BOXING_SCORE,
                                 THESIS_PLANET_FREEWAY, THESIS_PLANET_SEARCH, THESIS_PLANET_SOKOBAN, THESIS_SOKOBAN,
                                 THESIS_SOKOBAN_VISION,
                                 THESIS_WORLD_MODELS, Reference, best_atari_100k)
from wmthesis.verdicts import Claim, Verdict, verdict

BEGIN, END = "<!-- results: written by `python -m wmthesis summary` -->", "<!-- end of results -->"


class Headline(NamedTuple):
    """A row of the front door: the summary row of ``experiment``'s ``variant`` (its key in the
    summary), what it is, the thesis section (or where beyond it), the notebook, the thesis's
    figure and the best published one; ``claim``, what the row claims as a
    :class:`~wmthesis.verdicts.Claim` (its verdict: :func:`judge`; None: the thesis judged it by
    eye, and ``judged``, one of :data:`~wmthesis.verdicts.VERDICTS`, is ours by eye on the figure
    beside it), and ``why``, one line on what explains the verdict."""
    experiment: str
    variant: str | None
    title: str
    section: str
    notebook: str
    thesis: Reference | None
    published: Reference | None
    claim: Claim | None = None
    judged: str = ""
    why: str = ""


HEADLINES = (
    Headline(NAMES.sokoban_wm, None, "World Models on Sokoban: % of levels its controller solves", "5.3", "01",
             THESIS_SOKOBAN, None, Claim("failed", 0.0),
             why="no controller of ours solves a level either (the controllers' table below)"),
    Headline(NAMES.boxing_wm, BOXING_WM.folder_name(None), "World Models on Boxing", "5.4.1", "02", THESIS_WORLD_MODELS,
             best_atari_100k("boxing"), Claim("above", 18.0)),
    Headline(NAMES.boxing_wm_alphazero, ALPHAZERO.default.name, "World Models + AlphaZero on Boxing", "5.4.2", "03",
             THESIS_ALPHAZERO, best_atari_100k("boxing"), Claim("failed", RANDOM["boxing"].value),
             why="the thesis's coupling did not learn to plan, so its failure is random play's score"),
    Headline(NAMES.planet_boxing_agent, None, "PlaNet on Boxing (KL scale 0.03, free nats 12)", "5.6.4", "05",
             THESIS_PLANET_BOXING, best_atari_100k("boxing"), Claim("around", THESIS_PLANET_BOXING_SCORE),
             why="trained at far smaller sizes than the thesis's, as this CPU affords (the table below sets them "
                 "side by side with what an update and a plan cost at each); a learned value on a frozen PlaNet "
                 "model comes nearer (notebooks 09 and 10)"),
    Headline(NAMES.planet_freeway, "freeway-tuned", "PlaNet on Freeway", "5.6.5", "08", THESIS_PLANET_FREEWAY,
             best_atari_100k("freeway"), Claim("failed", 0.0),
             why="the failure is our reading of the thesis's words, no crossing; a player pressing UP at every step "
                 "scores nearly as much as ours (below): what a planner adds over it is cars dodged"),
    Headline(NAMES.planet_boxing_value, "lean-value-rewards-0.7, cem-with-value",
             "Boxing: CEM with a learned value on PlaNet's model", "beyond", "10", THESIS_PLANET_BOXING,
             best_atari_100k("boxing"), Claim("around", THESIS_PLANET_BOXING_SCORE)),
    Headline(NAMES.planet_freeway_value, "cem-with-value", "Freeway: CEM with a learned value on PlaNet's model", "beyond",
             "08", THESIS_PLANET_FREEWAY, best_atari_100k("freeway"), Claim("failed", 0.0)),
    Headline(NAMES.sokoban_search, "boxoban-unfiltered, 1000 report levels",
             "Sokoban by search in a learned model: Boxoban unfiltered, % solved", "beyond (ch. 1)", "07",
             THESIS_SOKOBAN, BOXOBAN["unfiltered"], Claim("failed", 0.0)),
    Headline(NAMES.sokoban_search, "boxoban-medium, 1000 report levels",
             "Sokoban by search in a learned model: Boxoban medium, % solved", "beyond (ch. 1)", "07", THESIS_SOKOBAN,
             BOXOBAN["medium"], Claim("failed", 0.0)),
)

# Rows that open a chapter without standing in the front door's table: a figure the thesis judged
# by eye, a search's measure, a step on the way to another chapter's headline.
CHAPTER_ROWS = (
    Headline(NAMES.sokoban_wm, SOKOBAN_VISION, "World Models on Sokoban: the vision, % of reconstructions showing "
             "one player", "5.3.1", "01", THESIS_SOKOBAN_VISION, None, Claim("above", 50.0),
             why="no reconstruction shows the one player, and few keep the four boxes (the open-loop table below, "
                 "its row of reconstructions): the cause the thesis itself suspected, \"VAE is unable to generate "
                 "usable abstract Sokoban representation\" (5.3.1)"),
    Headline(NAMES.planet_sokoban, "unchanged", "PlaNet on Sokoban-small (greedy return)", "5.5.1", "04",
             THESIS_PLANET_SOKOBAN, None, judged="reproduced",
             why="its open-loop predictions blur and show no player from the first imagined steps on (Fig. 58 "
                 "below), where the thesis saw blurred predictions with several players"),
    Headline(NAMES.planet_boxing_search, None, "KL scale x free nats: the best trial's open-loop error x 1000 on held-out "
             "bouts (lower is better)", "5.6.3-5.6.5", "06", THESIS_PLANET_SEARCH, None,
             judged="not settled",
             why="its best and worst settings differ by less than one setting's two seeds do (below), so its trials "
                 "choose no setting"),
    Headline(NAMES.planet_boxing_value, None, "Boxing: a learned value alone on PlaNet's model (the round chosen on "
             "validation bouts)", "beyond", "09", THESIS_PLANET_BOXING, best_atari_100k("boxing"),
             Claim("around", THESIS_PLANET_BOXING_SCORE)),
)


def seed_hours(row: dict | None, rows: list[dict]) -> float | None:
    """What another seed of ``row`` costs, in hours of one core: its seeds' mean wall time (times the
    torch threads each ran on), plus
    that of the default row of each experiment it builds on, of the same profile (a new seed
    trains those too). None where a time is not recorded."""
    def hours(r: dict | None) -> float | None:
        """Its seeds' mean wall time in hours of one core: a run on n torch threads counts n times."""
        r = r or {}
        threads = r.get("threads") or [None] * len(r.get("wall_seconds", []))
        walls = [w * (t or 1) for w, t in zip(r.get("wall_seconds", []), threads) if w is not None]
        return None if not walls else float(np.mean(walls)) / 3600

    own = hours(row)
    if row is None or own is None:
        return None
    by_key = {(r["experiment"], r["variant"], r["profile"]): r for r in rows}
    for experiment in DECLARED[row["experiment"]].builds_on:
        registry = DECLARED[experiment].registry()
        base = hours(by_key.get((experiment, None if registry is None else registry.folder_name(None), row["profile"])))
        if base is None:
            return None
        own += base
    return own


def judge(headline: Headline, row: dict | None, rows: list[dict] = ()) -> str:
    """``headline``'s verdict on its summary ``row`` (:mod:`wmthesis.verdicts`), as the summary, the
    README and every chapter print it; ``rows``, the summary's, price another seed where the
    verdict is not settled. ``"not run yet"`` where no seed ran."""
    if row is None:
        return "not run yet"
    if headline.claim is None:
        return judged_by_eye(headline, row, rows)
    return str(verdict(headline.claim, row["mean"], row["ci_low"], row["ci_high"], row["n"], seed_hours(row, list(rows))))


def judged_by_eye(headline: Headline, row: dict, rows) -> str:
    """The verdict of a row the thesis judged by eye: ours on the figure beside it, ``judged``,
    settled only over 2 seeds or more (one seed gives no interval, whatever the eye says)."""
    if row["n"] >= 2:
        return f"{headline.judged} (by eye, over {row['n']} seeds)"
    eye = "" if headline.judged == "not settled" else f"; by eye on its figure: {headline.judged}"
    return str(Verdict("not settled", row["n"], seed_hours(row, list(rows)), f"one seed gives no interval{eye}"))


def _ours(row: dict | None) -> str:
    if row is None:
        return "not run yet"
    interval = "" if row["ci_low"] is None else f" [{row['ci_low']:.1f}, {row['ci_high']:.1f}]"
    return f"{row['mean']:.1f}{interval} ({row['n']} seed{'s' if row['n'] > 1 else ''})"


def _minutes(row: dict | None) -> str:
    """A row's minutes a seed, ``"51-97 (x86_64, 2 cores)"``; where its seeds ran with different
    numbers of torch threads, each number's range: ``"51 with 2 threads, 73-97 with 1 (...)"``."""
    if row is None:
        return ""
    machines = sorted(set(row.get("machines", [])) - {None})
    threads = row.get("threads") or [None] * len(row["wall_seconds"])
    runs = [(w, t) for w, t in zip(row["wall_seconds"], threads) if w is not None]
    if not runs:
        return "not recorded"
    counts = {t for _, t in runs}
    if len(counts) == 1 or None in counts:
        time = _range([w for w, _ in runs])
    else:  # the most threads first: "51 with 2 threads, 73-97 with 1"
        time = ", ".join(f"{_range([w for w, t in runs if t == n])} with {n}" + (" threads" if k == 0 else "")
                         for k, n in enumerate(sorted(counts, reverse=True)))
    return f"{time}" + (f" ({'; '.join(machines)})" if machines else "")


def steps_learned(row: dict | None) -> str:
    """A row's real environment steps to learn over its seeds, ``"4.6M"`` or ``"4.6M-4.7M"``
    (``"at most"`` where some stage is counted at full bouts; ``"(2 of 3 seeds)"`` where not every
    seed's budget is known). Empty where none is."""
    seeds = (row or {}).get("agent_steps", [])
    known = [s for s in seeds if s is not None]
    if not known:
        return ""
    low, high = short(min(known)), short(max(known))
    ours = ("at most " if row.get("steps_at_most") else "") + (low if low == high else f"{low}-{high}")
    return ours + (f" ({len(known)} of {len(seeds)} seeds)" if len(known) < len(seeds) else "")


def agent_steps(row: dict | None, published: Reference | None = None) -> str:
    """The table's cell: :func:`steps_learned` and, in brackets, the ``published`` figure's budget:
    ``"4.6M (100k)"``."""
    ours = steps_learned(row)
    return ours + (f" ({published.budget})" if ours and published is not None and published.budget else "")


def _range(walls: list[float]) -> str:
    """Wall times in seconds as minutes: ``"51"`` or ``"73-97"``."""
    low, high = f"{min(walls) / 60:.0f}", f"{max(walls) / 60:.0f}"
    return low if low == high else f"{low}-{high}"


def headline_rows(rows: list[dict], profile: str = "quick", headlines: tuple = HEADLINES) -> list[dict]:
    """The ``headlines`` (the front door's, :data:`HEADLINES`, by default) with their summary rows
    of ``profile`` (None where not run yet)."""
    found = {(r["experiment"], r["variant"]): r for r in rows if r["profile"] == profile}
    return [{"headline": h, "row": found.get((h.experiment, h.variant))} for h in headlines]


def headline_table(rows: list[dict], profile: str = "quick") -> str:
    """The front door's table (markdown) from the summary's ``rows``, the published figures'
    sources as footnotes under it."""
    notes: list[str] = []

    def cite(ref: Reference | None) -> str:
        if ref is None:
            return ""
        if ref.source not in notes:
            notes.append(ref.source)
        return f"{ref.value} ({ref.name})[^{notes.index(ref.source) + 1}]"

    lines = [f"| experiment | thesis | the thesis's figure | ours, `{profile}`: mean [95% interval] (seeds) "
             "| the claim: verdict | best published | agent steps to learn: ours (best published's) | notebook "
             "| minutes a seed (machine) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for entry in headline_rows(rows, profile):
        h, row = entry["headline"], entry["row"]
        thesis = "" if h.thesis is None else str(h.thesis.value)
        said = (f"{h.claim.words()}: " if h.claim is not None else "") + judge(h, row, rows)
        lines.append(f"| {h.title} | {h.section} | {thesis} | {_ours(row)} | {said} | {cite(h.published)} "
                     f"| {agent_steps(row, h.published)} | {h.notebook} | {_minutes(row)} |")
    lines += ["", *(f"[^{i + 1}]: {source}" for i, source in enumerate(notes))]
    return "\n".join(lines)


def _measure(variant: str | None) -> tuple[str | None, str | None]:
    """A summary key's variant and what of it was measured: ``"rounds-10, cem-with-value"`` ->
    ``("rounds-10", "cem-with-value")``; ``"cem-with-value"`` -> ``(None, "cem-with-value")``."""
    if variant is None:
        return None, None
    name, _, part = variant.partition(", ")
    if not part and name in ("cem-with-value",):
        return None, name
    return name, part or None


def ablation_rows(rows: list[dict], profile: str = "quick") -> list[dict]:
    """Each variant of a headline's experiment, measured the same way, against the headline's row,
    paired by seed (a seed plays the same evaluation bouts or levels under every variant): the
    seeds both ran on the same frozen model (a row's ``models``, where it has them: a seed whose
    two runs froze different models is not paired, and is listed in ``other_model``), both means
    over them, and the mean difference with its 95% t interval (None for one seed). A variant
    whose every shared seed froze another model gets both means over those seeds unpaired and a
    difference of None."""
    from wmthesis.metrics import aggregate  # scipy: loaded when a table is written

    by_key = {(r["experiment"], r["variant"]): r for r in rows if r["profile"] == profile}
    headline_keys = {(h.experiment, h.variant) for h in HEADLINES}
    out = []
    for h in HEADLINES:
        default = by_key.get((h.experiment, h.variant))
        if default is None:
            continue
        for (experiment, variant), row in by_key.items():
            if (experiment != h.experiment or (experiment, variant) in headline_keys
                    or _measure(variant)[1] != _measure(h.variant)[1]):
                continue
            ours, theirs = dict(zip(row["seeds"], row["scores"])), dict(zip(default["seeds"], default["scores"]))
            shared = sorted(set(ours) & set(theirs))
            if not shared:
                continue
            models = _seed_models(row), _seed_models(default)
            seeds = [s for s in shared if models[0].get(s) == models[1].get(s)]
            other = [s for s in shared if s not in seeds]
            means = seeds or other
            difference = aggregate([ours[s] - theirs[s] for s in seeds]) if seeds else \
                {"mean": None, "ci_low": None, "ci_high": None}
            out.append({"experiment": experiment, "variant": _measure(variant)[0], "against": _measure(h.variant)[0],
                        "measured": _measure(variant)[1], "seeds": seeds, "other_model": other,
                        "mean": float(np.mean([ours[s] for s in means])),
                        "default_mean": float(np.mean([theirs[s] for s in means])),
                        "difference": difference["mean"], "ci_low": difference["ci_low"],
                        "ci_high": difference["ci_high"]})
    return out


def _seed_models(row: dict) -> dict:
    """seed -> the frozen model its run was on (None where the row does not tell)."""
    return dict(zip(row["seeds"], row.get("models") or [None] * len(row["seeds"])))


def ablation_table(rows: list[dict], profile: str = "quick", roots: dict | None = None) -> str:
    """The ablations as markdown: each variant against its experiment's headline row, paired by
    seed on the same frozen model (:func:`ablation_rows`; seeds on another model are named, not
    paired). The runs in the experiment's own folders (variant None) are its first recipe, named
    by ``roots`` (experiment -> the root variant's name, :attr:`~wmthesis.variants.Variants.root`)."""
    def label(experiment: str, variant: str | None) -> str:
        root = (roots or {}).get(experiment)
        return variant or (f"{root} (first recipe)" if root else "first recipe")

    def seeds(a: dict) -> str:
        paired = " ".join(map(str, a["seeds"])) or "none"
        return paired + (f" ({' '.join(map(str, a['other_model']))}: another model, not paired)" if a["other_model"] else "")

    def difference(a: dict) -> str:
        if a["difference"] is None:
            return "not paired"
        interval = "" if a["ci_low"] is None else f" [{a['ci_low']:+.1f}, {a['ci_high']:+.1f}]"
        return f"{a['difference']:+.1f}{interval}"

    lines = ["| experiment | variant | against (headline) | measured | paired seeds | variant | headline "
             "| difference [95% interval] |", "|---|---|---|---|---|---|---|---|"]
    for a in ablation_rows(rows, profile):
        lines.append(f"| {a['experiment']} | {label(a['experiment'], a['variant'])} | {label(a['experiment'], a['against'])} "
                     f"| {a['measured'] or 'score'} | {seeds(a)} | {a['mean']:.1f} "
                     f"| {a['default_mean']:.1f} | {difference(a)} |")
    return "\n".join(lines)


def readme_with_table(readme: str, table: str, begin: str = BEGIN, end: str = END) -> str:
    """``readme`` with the text between ``begin`` and ``end`` (by default the results block's
    markers) replaced by ``table``; a README without both markers raises ValueError naming them."""
    pattern = re.compile(re.escape(begin) + r".*?" + re.escape(end), re.S)
    if not pattern.search(readme):
        raise ValueError(f"the README has no {'results' if begin == BEGIN else 'such'} block: put {begin} and {end} "
                         "where the table goes")
    return pattern.sub(lambda _: f"{begin}\n{table}\n{end}", readme, count=1)


__all__ = ["Headline", "HEADLINES", "CHAPTER_ROWS", "judge", "seed_hours", "BEGIN", "END", "headline_rows", "headline_table", "ablation_rows",
           "ablation_table", "readme_with_table"]
