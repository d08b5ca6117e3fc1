"""Each notebook's opening box: the thesis's claim for its chapter, what we found over seeds (the
summary's numbers, never typed) with the real environment steps it learned from beside the best
published figure's (:mod:`wmthesis.budget`), and the summary's verdict on the claim
(:func:`wmthesis.headline.judge`, by the one rule of :mod:`wmthesis.verdicts`), stated in the box.
"""
from __future__ import annotations

from wmthesis.headline import CHAPTER_ROWS, HEADLINES, headline_rows, judge, steps_learned
from wmthesis.verdicts import RULE


def chapter_box(notebook: str, profile: str = "quick", folder=None) -> str:
    """The opening box (Markdown) of ``notebook`` (its number, ``"02"``): one block per headline it
    holds (the front door's and :data:`~wmthesis.headline.CHAPTER_ROWS`), read from every run's ``metrics.json`` under ``folder`` (default ``data/results``)."""
    from wmthesis.summary import read_runs, summarise

    rows = summarise(read_runs(folder))
    entries = [e for e in headline_rows(rows, profile, HEADLINES + CHAPTER_ROWS)
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
        else:  # its figure in our words
            thesis = f"{h.thesis.value} ({h.thesis.source})"
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
        said = judge(h, row, rows)
        claim = f" on the claim \"{h.claim.words()}\"" if h.claim is not None else ""
        where = f"thesis {h.section}" if h.section[0].isdigit() else h.section.replace("beyond", "beyond the thesis")
        blocks.append(f"> **{h.title}** ({where})  \n"
                      f"> **The thesis:** {thesis}  \n"
                      f"> **Ours** (`{profile}`): {ours}{published}  \n"
                      f"> **Verdict**{claim}: {said}{'; ' + h.why if h.why else ''}.")
    return "\n>\n".join(blocks) + f"\n>\n> *The verdict's rule:* {RULE}"


__all__ = ["chapter_box"]
