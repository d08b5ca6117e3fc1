"""The reader's path (``test_reader_path.py``) for the notebooks that play shipped agents for
minutes (PlaNet's bouts plan with CEM): a file of their own, so that the two test workers share the
notebooks."""
from __future__ import annotations

import pytest

from test_reader_path import opens_as_a_reader_opens_it, shipped  # noqa: F401 (the fixture)

SLOW = ("05_planet_boxing", "08_planet_freeway", "10_planet_value_planner")


@pytest.mark.parametrize("name", SLOW)
def test_a_slow_notebook_opens_from_what_ships_as_a_reader_opens_it(name, shipped, monkeypatch):  # noqa: F811
    opens_as_a_reader_opens_it(name, shipped, monkeypatch)


def test_every_notebook_is_on_the_readers_path():
    from test_reader_path import FAST, ROOT

    assert sorted(FAST + SLOW) == sorted(p.stem for p in (ROOT / "notebooks").glob("*.ipynb"))
