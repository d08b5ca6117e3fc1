"""Score statistics (wmthesis.metrics)."""
import numpy as np
import pytest

from wmthesis.metrics import score_difference, score_summary


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
