"""The command line's parsers and the episode store fed random bad values (hypothesis): each
either answers as documented or raises a ValueError in one line; nothing else escapes."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from wmthesis.budget_curves import PLANNERS, parse_budgets
from wmthesis.utils import MAX_SEED, MAX_SEEDS, parse_seeds

TEXT = st.text(alphabet="0123456789-,x X.e+ab", max_size=24)


@settings(max_examples=400, deadline=None)
@given(TEXT)
def test_a_seed_list_is_parsed_or_refused_in_one_line(text):
    try:
        seeds = parse_seeds(text)
    except ValueError as error:
        assert "\n" not in str(error) and "--seeds" in str(error)
        return
    assert seeds == sorted(set(seeds)) and 0 < len(seeds) <= MAX_SEEDS and all(0 <= s <= MAX_SEED for s in seeds)


@settings(max_examples=400, deadline=None)
@given(st.sampled_from(PLANNERS), TEXT)
def test_a_budget_list_is_parsed_or_refused_in_one_line(planner, text):
    try:
        budgets = parse_budgets(planner, text)
    except ValueError as error:
        assert "\n" not in str(error)
        return
    assert budgets and len(set(budgets)) == len(budgets)
    for budget in budgets:
        numbers = budget if planner == "cem" else (budget,)
        assert all(isinstance(n, int) and n >= 1 for n in numbers)


@settings(max_examples=200, deadline=None)
@given(st.text(alphabet="=,rootgumbelpuctie_brakpsvcnsd0123456789.-", max_size=40))
def test_a_search_setting_is_parsed_or_refused_in_one_line(text):
    from wmthesis.alphazero.config import SEARCH_FIELDS, search_settings

    try:
        settings_ = search_settings("quick", text)
    except ValueError as error:
        assert "\n" not in str(error)
        return
    assert set(settings_) <= set(SEARCH_FIELDS)


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    from wmthesis.data import EpisodeStore

    return EpisodeStore(tmp_path_factory.mktemp("fuzz") / "s.h5", "a", env="test", obs_shape=(2, 2, 3))


@settings(max_examples=150, deadline=None)
@given(steps=st.integers(0, 4), shape=st.sampled_from([(2, 2, 3), (2, 3, 3), (2, 2)]),
       reward=st.sampled_from([0.0, 1.5, np.nan, np.inf, -np.inf]), action=st.sampled_from([0, 3, 1.5]),
       terminal_first=st.booleans())
def test_the_store_takes_a_whole_good_episode_or_refuses_it_in_one_line(store, steps, shape, reward, action, terminal_first):
    before = len(store)
    observations = np.zeros((steps, *shape), np.uint8)
    actions = np.full(steps, action)
    rewards = np.full(steps, reward, np.float32)
    terminals = np.zeros(steps, bool)
    if steps and terminal_first:
        terminals[0] = True
    try:
        index = store.append_episode(observations, actions, rewards, terminals)
    except ValueError as error:
        assert "\n" not in str(error) and len(store) == before
        return
    good = steps >= 1 and shape == (2, 2, 3) and np.isfinite(reward) and action != 1.5 and not (terminal_first and steps > 1)
    assert good and index == before and len(store.episode(index)["actions"]) == steps
