"""The environments fed bad values (hypothesis): an action that is not an integer in the action
space, or an option that is not a positive integer, is refused in one line naming what is valid,
and a refused action leaves the game as it was."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from wmthesis.envs import make_env

GAMES = {"sokoban-small": 8, "boxing": 18}
bad_actions = st.one_of(
    st.integers(max_value=-1), st.integers(min_value=18), st.floats(allow_nan=True).filter(lambda x: x != int(x)
                                                                                          if np.isfinite(x) else True),
    st.text(max_size=4), st.none(), st.booleans(), st.lists(st.integers(0, 3), max_size=2))
bad_counts = st.one_of(st.integers(max_value=0), st.floats(allow_nan=True), st.text(max_size=3), st.none(),
                       st.booleans())


@pytest.fixture(scope="module", params=sorted(GAMES))
def twins(request):
    """Two copies of one game at the same start: one fed bad actions, one never."""
    envs = [make_env(request.param), make_env(request.param)]
    for env in envs:
        env.reset(seed=3)
    yield request.param, envs
    for env in envs:
        env.close()


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(action=bad_actions)
def test_a_bad_action_is_refused_in_one_line_and_changes_nothing(twins, action):
    name, (fed, kept) = twins
    if isinstance(action, int) and not isinstance(action, bool) and 0 <= action < GAMES[name]:
        return  # a valid action of the smaller game drawn for the larger
    with pytest.raises(ValueError) as refused:
        fed.step(action)
    message = str(refused.value)
    assert "\n" not in message and f"a valid action is an integer in [0, {GAMES[name] - 1}]" in message
    a, b = fed.step(1), kept.step(1)  # the same next step in both: the refusal left no trace
    assert np.array_equal(a[0], b[0]) and a[1:4] == b[1:4]


@settings(max_examples=40, deadline=None)
@given(option=st.sampled_from([("boxing", "action_repeat"), ("boxing", "max_steps"), ("sokoban-small", "max_steps"),
                               ("sokoban-small", "tile_size")]), value=bad_counts)
def test_an_option_that_is_not_a_positive_integer_is_refused_in_one_line(option, value):
    name, field = option
    if value is None and option == ("boxing", "max_steps"):
        return  # no cap on an Atari bout's length: its documented default
    with pytest.raises(ValueError, match=rf"^{field} must be a positive integer, got ") as refused:
        make_env(name, **{field: value})
    assert "\n" not in str(refused.value)
