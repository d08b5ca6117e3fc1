"""Each notebook's opening box: the thesis's claim for its chapter, what we found over seeds (the
summary's numbers, never typed) with the real environment steps it learned from beside the best
published figure's (:mod:`wmthesis.budget`), and a one-line verdict.

The verdict sets our interval (or our one seed's score) against the number the thesis's figure
stands for (:class:`~wmthesis.headline.Headline`'s ``bar``): *beyond the thesis* where the whole
interval lies above it, *not reproduced at this budget* where it lies below, *reproduced* where it
holds it (the box then says the bar lies within our interval: the seeds cannot tell us apart); a chapter whose thesis gave no number carries the verdict its headline states.
"""
from __future__ import annotations

from wmthesis.headline import CHAPTER_ROWS, HEADLINES, headline_rows, steps_learned


def verdict(headline, row: dict | None) -> str:
    """The verdict of ``headline`` on its summary ``row`` (module docstring)."""
    if row is None:
        return "not run yet"
    if headline.bar is None:
        return headline.judged
    low, high = (row["mean"], row["mean"]) if row["ci_low"] is None else (row["ci_low"], row["ci_high"])
    if low > headline.bar:
        return "beyond the thesis"
    if high < headline.bar:
        return "not reproduced at this budget"
    return "reproduced"


def chapter_box(notebook: str, profile: str = "quick", folder=None) -> str:
    """The opening box (Markdown) of ``notebook`` (its number, ``"02"``): one block per headline it
    holds (the front door's and :data:`~wmthesis.headline.CHAPTER_ROWS`), read from every run's ``metrics.json`` under ``folder`` (default ``data/results``)."""
    from wmthesis.summary import read_runs, summarise

    entries = [e for e in headline_rows(summarise(read_runs(folder)), profile, HEADLINES + CHAPTER_ROWS)
               if e["headline"].notebook == notebook]
    if not entries:
        raise ValueError(f"notebook {notebook!r} holds no headline; those that do: "
                         f"{', '.join(sorted({h.notebook for h in HEADLINES + CHAPTER_ROWS}))}")
    blocks = []
    for entry in entries:
        h, row = entry["headline"], entry["row"]
        if h.thesis is None:
            thesis = "the thesis gives no figure"
        elif h.thesis.quote:  # its words, then the figure we read in them
            thesis = f"\"{h.thesis.quote}\" ({h.thesis.source}); as a figure: {h.thesis.value}"
        else:
            thesis = f"\"{h.thesis.value}\" ({h.thesis.source})"
        if row is None:
            ours = "not run yet"
        else:
            interval = "" if row["ci_low"] is None else f" [{row['ci_low']:.1f}, {row['ci_high']:.1f}]"
            ours = (f"{row['mean']:.1f}{interval} over {row['n']} seed{'s' * (row['n'] > 1)}"
                    + (" (95% interval)" if interval else ""))
        published = "" if h.published is None else f" · best published: {h.published.value} ({h.published.name})"
        steps = steps_learned(row)
        if steps:
            budget = f"; best published: {h.published.budget}" if h.published is not None and h.published.budget else ""
            published += f"  \n> **Learned from:** {steps} agent steps in the real game{budget}"
        said = verdict(h, row)
        if h.bar is not None and row is not None:
            held = said == "reproduced" and row["ci_low"] is not None
            said += f" (the bar: {h.bar:g}{', within our interval' if held else ''})"
        where = f"thesis {h.section}" if h.section[0].isdigit() else h.section.replace("beyond", "beyond the thesis")
        blocks.append(f"> **{h.title}** ({where})  \n"
                      f"> **The thesis:** {thesis}  \n"
                      f"> **Ours** (`{profile}`): {ours}{published}  \n"
                      f"> **Verdict:** {said}{'; ' + h.why if h.why else ''}.")
    return "\n>\n".join(blocks)


__all__ = ["verdict", "chapter_box"]
