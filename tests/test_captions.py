"""The thesis's words beside our figures (wmthesis/captions.py): one entry per figure drawn again,
every quote verbatim in the thesis's text and in the section it names, and each notebook that draws
a figure shows them."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from wmthesis.captions import FIGURES, thesis_says

ROOT = Path(__file__).resolve().parents[1]
THESIS = ROOT.parent / "shared" / "thesis" / "thesis.txt"  # the thesis's text, beside the checkout where it is
DRAWN = {"01_sokoban_world_models": ("5.4", "5.5"), "02_boxing_world_models": ("5.6", "5.7"),
         "04_planet_sokoban": ("5.8",), "05_planet_boxing": ("5.9", "5.10"), "08_planet_freeway": ("5.11",)}
HEADING = re.compile(r"^\*?(\d+\.\d+(?:\.\d+)?)\.", re.M)


def normalised(text: str) -> str:
    return " ".join(text.split())


def test_every_figure_the_notebooks_draw_again_has_the_thesis_s_words():
    assert set(FIGURES) == {f"5.{n}" for n in range(4, 12)}
    for figure, found in FIGURES.items():
        said = thesis_says(figure)
        assert said.startswith(f"> **The thesis on its Fig. {figure.replace('.', '')}** (section {found.section}):")
        assert all(line.startswith(">") for line in said.splitlines()) and found.caption in said
        assert all(passage in said for passage in found.says)
    with pytest.raises(ValueError, match="known: 5.4, 5.5"):
        thesis_says("5.12")


@pytest.mark.skipif(not THESIS.is_file(), reason="the thesis's text is not beside this checkout")
def test_every_quote_is_verbatim_in_the_thesis_and_in_the_section_it_names():
    text = THESIS.read_text()
    headings = [(m.start(), m.group(1)) for m in HEADING.finditer(text)]
    flat = normalised(text)

    def section_of(quote: str) -> str:
        """The heading above the first place ``quote`` (whitespace normalised) stands in the text."""
        at = flat.index(normalised(quote))
        before = [name for start, name in headings if len(normalised(text[:start])) <= at]
        return before[-1]

    for figure, found in FIGURES.items():
        number = figure.replace(".", "")  # the text's "Fig. 54."
        assert normalised(f"Fig. {number}. {found.caption}") in flat, figure
        assert section_of(f"Fig. {number}. {found.caption}") == found.section, figure
        for passage in found.says:
            assert normalised(passage) in flat, (figure, passage)
            assert section_of(passage) == found.section, (figure, passage)
    from wmthesis import references

    quoted = [r for r in vars(references).values() if isinstance(r, references.Reference) and r.quote]
    assert len(quoted) >= 3  # the chapters' boxes quote the thesis's words, then read a figure in them
    for reference in quoted:
        assert normalised(reference.quote) in flat, reference
        assert reference.source.startswith(f"thesis {section_of(reference.quote)}"), reference


@pytest.mark.parametrize("name", sorted(DRAWN))
def test_each_notebook_shows_the_thesis_s_words_under_its_figures(name):
    cells = json.loads((ROOT / "notebooks" / f"{name}.ipynb").read_text())["cells"]
    code = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")
    assert "from wmthesis.captions import thesis_says" in code
    for figure in DRAWN[name]:
        assert f'thesis_says("{figure}")' in code, f"{name}: no thesis_says for Fig. {figure}"
