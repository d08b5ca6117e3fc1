"""Score statistics (wmthesis.metrics)."""
import numpy as np
import pytest

from wmthesis.metrics import paired_difference, score_difference, score_summary


def test_score_summary_uses_the_population_std():
    assert score_summary([1, 3]) == {"mean": 2.0, "std": 1.0, "min": 1.0, "max": 3.0, "episodes": 2}
    with pytest.raises(ValueError, match="no returns"):
        score_summary([])


def test_score_difference_is_welchs_standard_error():
    # a: mean 4, sample variance 4, 3 returns; b: mean 1, sample variance 2, 2 returns
    result = score_difference([2, 4, 6], [0, 2])
    assert result["difference"] == 3.0
    assert result["standard_error"] == pytest.approx(np.sqrt(4 / 3 + 2 / 2))
    with pytest.raises(ValueError, match="two returns"):
        score_difference([1], [1, 2])


def test_paired_difference_is_the_mean_of_the_bout_differences_and_its_standard_error():
    # differences 3, 1, 5: mean 3, sample variance 4, standard error 2 / sqrt(3)
    result = paired_difference([4, 2, 9], [1, 1, 4])
    assert result["difference"] == 3.0
    assert result["standard_error"] == pytest.approx(2 / np.sqrt(3))
    assert np.isnan(paired_difference([5], [2])["standard_error"]) and paired_difference([5], [2])["difference"] == 3.0
    with pytest.raises(ValueError, match="same bouts"):
        paired_difference([1, 2], [1, 2, 3])
