"""The one verdict rule (wmthesis.verdicts), on cases written by hand, today's rows among them, and
over every headline row the summary writes."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from wmthesis.verdicts import Claim, verdict

ROOT = Path(__file__).resolve().parents[1]


def said(claim, mean, low, high, n=3, hours=None):
    return str(verdict(claim, mean, low, high, n, hours))


@pytest.mark.parametrize("claim, mean, low, high, n, expected", [
    # the thesis's "above 18" (5.4.1): World Models on Boxing over 10 seeds, and made-up intervals
    (Claim("above", 18), 34.4, 28.9, 40.0, 10, "reproduced"),
    (Claim("above", 18), 19.0, 10.0, 28.0, 5, "not settled at 5 seeds (the interval holds both the claim and its denial)"),
    (Claim("above", 18), 10.0, 5.0, 15.0, 5, "not reproduced"),
    (Claim("above", 18), 10.0, 5.0, 18.0, 5, "not reproduced"),  # 18 itself is not above 18
    # "around 30" (5.6.4): denied at 15 and at 45
    (Claim("around", 30), 31.5, -21.2, 84.1, 3,  # notebook 10's row: it holds 0, 15, 30 and 45
     "not settled at 3 seeds (the interval holds both the claim and its denial)"),
    (Claim("around", 30), 22.2, 3.1, 41.4, 3,  # notebook 09's row: it holds 15 and 30
     "not settled at 3 seeds (the interval holds both the claim and its denial)"),
    (Claim("around", 30), 3.4, 1.6, 5.1, 3, "not reproduced"),  # PlaNet on Boxing
    (Claim("around", 30), 28.0, 24.0, 33.0, 3, "reproduced"),
    (Claim("around", 30), 60.0, 58.0, 62.0, 5, "beyond"),  # wholly past the band's top
    (Claim("around", 30, tolerance=5), 28.0, 24.0, 33.0, 3, "not settled at 3 seeds (the interval holds both the claim and its denial)"),
    # "failed": the thesis's agent no better than random play (0.1) or 0 levels solved
    (Claim("failed", 0.1), 40.8, 30.0, 51.5, 5, "beyond"),  # the AlphaZero coupling
    (Claim("failed", 0.0), 0.0, 0.0, 0.0, 5, "reproduced"),  # no level solved on any seed
    (Claim("failed", 0.0), 23.7, 22.2, 25.1, 3, "beyond"),  # 3 seeds, but a half-width under a tenth of the mean
    (Claim("failed", 0.0), 94.7, 85.0, 100.0, 3,  # Boxoban medium: its unclipped half-width 9.7 > 9.47
     "not settled at 3 seeds (beyond needs 5 seeds or an interval within a tenth of its mean)"),
    (Claim("failed", 0.0), 2.0, -1.0, 5.0, 5, "not settled at 5 seeds (the interval holds both the claim and its denial)"),
    # beyond claims: better than Y, and a gain above 0
    (Claim("better", 3.4), 31.5, -21.2, 84.1, 3, "not settled at 3 seeds (the interval holds both the claim and its denial)"),
    (Claim("better", 3.4), 30.0, 28.0, 32.0, 5, "beyond"),
    (Claim("better", 3.4), 2.0, 1.0, 3.0, 5, "not reproduced"),
    (Claim("gain"), 11.6, 5.7, 17.5, 3,  # MCTS at 256 simulations: above 0, on 3 seeds with a wide interval
     "not settled at 3 seeds (beyond needs 5 seeds or an interval within a tenth of its mean)"),
    (Claim("gain"), 11.6, 5.7, 17.5, 5, "beyond"),
    (Claim("gain"), 0.0, 0.0, 0.0, 3, "not reproduced"),
    (Claim("gain"), -1.9, -15.2, 11.5, 3, "not settled at 3 seeds (the interval holds both the claim and its denial)"),
    # one seed settles nothing, whatever its score
    (Claim("above", 18), 60.0, None, None, 1, "not settled at 1 seed (one seed gives no interval)"),
])
def test_the_rule_on_cases_written_by_hand(claim, mean, low, high, n, expected):
    assert said(claim, mean, low, high, n) == expected


def test_a_verdict_not_settled_says_what_settling_costs():
    # 3 seeds of 1.2 h each: 2 more to reach 5
    assert said(Claim("around", 30), 31.5, -21.2, 84.1, 3, 1.2).endswith("; 2 more seeds cost about 2.4 h of one core")
    assert said(Claim("above", 18), 19.0, 10.0, 28.0, 7, 0.5).endswith("; 1 more seed cost about 0.5 h of one core")
    assert said(Claim("above", 18), 34.4, 28.9, 40.0, 10, 0.9) == "reproduced"  # settled: no cost


def test_a_claim_is_refused_where_it_cannot_be_judged():
    with pytest.raises(ValueError, match="kind is one of above, around, failed, better, gain"):
        Claim("about", 30)
    with pytest.raises(ValueError, match="positive tolerance"):
        Claim("around", 0)
    with pytest.raises(ValueError, match="finite"):
        Claim("above", float("nan"))
    assert Claim("around", 30).words() == "around 30 (denied at 15 or 45)"


def test_the_summary_never_says_reproduced_or_beyond_where_the_interval_holds_the_denial():
    """Every headline and chapter row over the committed runs: a settled verdict's interval holds
    only one side of its claim; and each row's verdict is the one the README's table prints."""
    from wmthesis.headline import CHAPTER_ROWS, HEADLINES, headline_rows, headline_table, judge
    from wmthesis.summary import read_runs, summarise

    rows = summarise(read_runs(ROOT / "data" / "results"))
    judged = 0
    for entry in headline_rows(rows, "quick", HEADLINES + CHAPTER_ROWS):
        h, row = entry["headline"], entry["row"]
        if h.claim is None or row is None:
            continue
        word = judge(h, row, rows)
        if word in ("reproduced", "beyond"):
            assert row["ci_low"] is not None, h.title
            allows, denies = h.claim.touches(row["ci_low"], row["ci_high"])
            assert allows != denies, f"{h.title}: {word} on [{row['ci_low']}, {row['ci_high']}]"
            if word == "beyond":
                half = max(row["mean"] - row["ci_low"], row["ci_high"] - row["mean"])
                assert row["n"] >= 5 or half <= abs(row["mean"]) / 10, h.title
        judged += 1
    assert judged >= 8
    table = headline_table(rows)
    for entry in headline_rows(rows, "quick"):
        assert f"{judge(entry['headline'], entry['row'], rows)} |" in table
    readme = (ROOT / "README.md").read_text()
    assert "| the claim: verdict |" in readme and "| above 18: reproduced |" in readme


def test_todays_rows_of_09_and_10_are_not_settled_and_say_their_cost():
    from wmthesis.chapters import chapter_box

    for notebook in ("09", "10"):
        box = chapter_box(notebook, folder=ROOT / "data" / "results")
        assert "**Verdict** on the claim \"around 30 (denied at 15 or 45)\": not settled at 3 seeds" in box
        assert "h of one core" in box and "reproduced" not in box.split("*The verdict's rule:*")[0]


def test_the_summarys_json_carries_each_headlines_verdict(tmp_path):
    from wmthesis.summary import headlines

    rows = {(h["experiment"], h["variant"]): h for h in headlines(folder=ROOT / "data" / "results")}
    assert rows["boxing-wm", "separable-64"]["verdict"] == "reproduced"
    assert rows["planet-boxing-agent", None]["verdict"] == "not reproduced"
    assert json.dumps(rows["boxing-wm", "separable-64"])  # plain data


@pytest.mark.parametrize("field, value", [("score", True), ("score", "34.4"), ("score", float("nan")),
                                          ("score", float("inf")), ("seed", -5), ("seed", 5.7), ("seed", True),
                                          ("wall_seconds", True), ("wall_seconds", -3.0), ("threads", 0),
                                          ("profile", "big"), ("schema_version", 99)])
def test_a_metrics_file_with_a_wrong_score_or_seed_is_skipped_and_never_reaches_the_readme(tmp_path, field, value):
    """A score of ``true`` once read as 1.0 and moved the README's main number: such a file is
    refused by name, and the summary's rows stand on the good files alone."""
    import warnings

    from wmthesis.summary import read_runs, summarise

    for seed, score in ((0, 30.0), (1, 40.0)):
        folder = tmp_path / "boxing-wm" / f"quick-seed{seed}" / "separable-64"
        folder.mkdir(parents=True)
        (folder / "metrics.json").write_text(json.dumps({"experiment": "boxing-wm", "profile": "quick", "seed": seed,
                                                         "variant": "separable-64", "score": {"mean": score}}))
    bad = {"experiment": "boxing-wm", "profile": "quick", "seed": 2, "variant": "separable-64", "score": {"mean": 50.0}}
    if field == "score":
        bad["score"]["mean"] = value
    else:
        bad[field] = value
    folder = tmp_path / "boxing-wm" / "quick-seed2" / "separable-64"
    folder.mkdir(parents=True)
    (folder / "metrics.json").write_text(json.dumps(bad))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rows = summarise(read_runs(tmp_path))
    assert [(r["seeds"], r["scores"]) for r in rows] == [([0, 1], [30.0, 40.0])]
    assert any(str(folder / "metrics.json") in str(w.message) and field in str(w.message) for w in caught)


def test_a_metrics_file_is_checked_against_its_versioned_schema_naming_the_file_and_the_field():
    from wmthesis.runs import run_header
    from wmthesis.schemas import METRICS_VERSION, check_metrics

    header = run_header("boxing-wm", "quick", 3, 12.34, variant="separable-64")
    assert header["schema_version"] == METRICS_VERSION and check_metrics(header, "m.json") is header
    for field, value, says in [("seed", 2**31, "seed: 2147483648 is greater than the maximum"),
                               ("threads", True, "threads: True is not of type 'integer', 'null'"),
                               ("date", "yesterday", "date: 'yesterday' does not match"),
                               ("wall_seconds", float("nan"), "wall_seconds: nan is not of type 'number'")]:
        with pytest.raises(ValueError, match=re.escape(f"runs/m.json: {says}")):
            check_metrics({**header, field: value}, "runs/m.json")
    with pytest.raises(ValueError, match="m.json: \\(the file\\): 'seed' is a required property"):
        check_metrics({k: v for k, v in header.items() if k != "seed"}, "m.json")


def test_another_seed_costs_its_wall_time_times_its_threads_in_hours_of_one_core():
    from wmthesis.headline import seed_hours

    row = {"experiment": "planet-boxing-search", "variant": None, "profile": "quick", "wall_seconds": [3600.0, 1800.0],
           "threads": [2, None]}
    assert seed_hours(row, [row]) == pytest.approx((7200 + 1800) / 2 / 3600)  # a 2-thread hour is 2 hours of one core
