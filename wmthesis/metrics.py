"""Measures the thesis judged "with the eye of the researcher", and score statistics.

Open-loop prediction error (thesis 5.3): after warming a model up on real steps, it predicts
the future from its own predictions; we compare the predicted frames (and latents) with the
true ones, step by step. The curve of error against horizon, and its value at a game's
cut-off horizon, turn the eye's judgement into a number.
"""
from __future__ import annotations

import numpy as np
from scipy import stats

CONFIDENCE = 0.95  # the intervals of means over seeds


def horizon_errors(truth: np.ndarray, prediction: np.ndarray) -> np.ndarray:
    """Mean squared error per horizon step between two sequences, (T, ...) -> (T,).

    uint8 frames are compared in [0, 1] (divided by 255); floats (latents) as they are.
    """
    truth, prediction = np.asarray(truth), np.asarray(prediction)
    if truth.shape != prediction.shape:
        raise ValueError(f"truth {truth.shape} and prediction {prediction.shape} differ in shape")
    scale = 255.0 if truth.dtype == np.uint8 else 1.0
    diff = truth.astype(np.float64) / scale - prediction.astype(np.float64) / scale
    return (diff ** 2).reshape(len(diff), -1).mean(axis=1)


def error_at(curve: np.ndarray, horizon: int) -> float:
    """The error at ``horizon`` steps ahead (1-based), or the last one if the curve is shorter."""
    curve = np.asarray(curve)
    return float(curve[min(horizon, len(curve)) - 1])


def score_summary(returns) -> dict:
    """Mean, std (population), min, max and count of episode returns."""
    returns = np.asarray(returns, dtype=np.float64)
    if returns.size == 0:
        raise ValueError("no returns to summarise")
    return {"mean": float(returns.mean()), "std": float(returns.std()), "min": float(returns.min()),
            "max": float(returns.max()), "episodes": int(returns.size)}


def score_cell(summary: dict) -> str:
    """A :func:`score_summary` as a table cell: mean ± std (n)."""
    return f"{summary['mean']:.1f} ± {summary['std']:.1f} (n={summary['episodes']})"


def score_difference(returns, baseline) -> dict:
    """How far ``returns`` lie above ``baseline`` (two agents' episode returns): the difference
    of the means and its standard error, ``sqrt(s_a^2 / n_a + s_b^2 / n_b)`` with sample
    variances (Welch); needs two episodes of each."""
    a, b = np.asarray(returns, np.float64), np.asarray(baseline, np.float64)
    if a.size < 2 or b.size < 2:
        raise ValueError(f"need at least two returns of each, got {a.size} and {b.size}")
    return {"difference": float(a.mean() - b.mean()),
            "standard_error": float(np.sqrt(a.var(ddof=1) / a.size + b.var(ddof=1) / b.size))}


def paired_difference(returns, baseline) -> dict:
    """How far ``returns`` lie above ``baseline`` bout for bout (two players on the same (N,)
    bouts): the mean of the differences and its standard error ``s_d / sqrt(N)`` (nan for one bout)."""
    a, b = np.asarray(returns, np.float64), np.asarray(baseline, np.float64)
    if a.shape != b.shape or a.size < 1:
        raise ValueError(f"need the same bouts for both, got {a.size} and {b.size} returns")
    d = a - b
    error = float(d.std(ddof=1) / np.sqrt(d.size)) if d.size > 1 else float("nan")
    return {"difference": float(d.mean()), "standard_error": error}


def correlation(x, y) -> float:
    """Pearson correlation of two (N,) arrays; nan when either is constant or N < 2."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    return float(np.corrcoef(x, y)[0, 1]) if len(x) > 1 and x.std() > 0 and y.std() > 0 else float("nan")


def auc(labels: np.ndarray, scores: np.ndarray) -> float:
    """Area under the ROC curve (ties count half); nan without both classes."""
    labels = np.asarray(labels, bool)
    n1, n0 = int(labels.sum()), int((~labels).sum())
    if n1 == 0 or n0 == 0:
        return float("nan")
    _, inverse, counts = np.unique(scores, return_inverse=True, return_counts=True)
    rank_of = np.cumsum(counts) - (counts - 1) / 2  # the mean rank of each distinct score
    ranks = rank_of[inverse]
    return float((ranks[labels].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))

def aggregate(scores, bounds: tuple[float, float] | None = None) -> dict:
    """Seeds' scores (n,) -> n, mean, sample std and the 95% t interval of the mean (None for one
    seed), clipped to ``bounds`` (low, high) where the score has them: a t interval over 3 seeds
    near 100% of levels would otherwise pass 100."""
    scores = np.asarray(scores, np.float64)
    n, mean = len(scores), float(scores.mean())
    if n < 2:
        return {"n": n, "mean": mean, "std": None, "ci_low": None, "ci_high": None}
    std = float(scores.std(ddof=1))
    half = float(stats.t.ppf(0.5 + CONFIDENCE / 2, n - 1)) * std / np.sqrt(n)
    low, high = bounds if bounds is not None else (-np.inf, np.inf)
    return {"n": n, "mean": mean, "std": std, "ci_low": max(mean - half, low), "ci_high": min(mean + half, high)}
