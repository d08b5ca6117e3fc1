"""One verdict rule for every result: a claim held against the 95% interval of our seeds.

A :class:`Claim` has a kind. The thesis's own claims:

- ``above X``: the score exceeds X (thesis 5.4.1: "above 18"); a score at or below X denies it.
- ``around X``: the score lies near X (5.6.4: "around 30"); a score as far from X as
  ``tolerance`` (by default half of X) denies it: at most X/2 or at least 3X/2.
- ``failed at F``: the thesis's agent did no better than F (random play's score, or 0 levels
  solved); a score above F denies the failure.

Claims beyond the thesis:

- ``better than Y``: the score exceeds Y; at or below Y denies it.
- ``gain > 0``: a paired gain exceeds 0 (``better than 0``).

The verdict (:func:`verdict`) is one of four:

- **not settled at n seeds** whenever the interval holds both the claim and what would deny it,
  and always on one seed (no interval). It then says what more seeds would cost;
- **reproduced**: the interval holds the thesis's claim and nothing that denies it;
- **beyond**: the interval holds a beyond claim and nothing that denies it, or lies wholly past
  the thesis's claim on the far side of failure (above the failure level of ``failed``, above the
  band of ``around``). A verdict of *beyond* also needs the evidence a claim past the thesis needs:
  at least :data:`BEYOND_SEEDS` seeds, or an interval whose half-width is at most a tenth of its
  mean (:data:`BEYOND_PRECISION`); otherwise it is not settled;
- **not reproduced**: the interval holds only what denies the claim.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

KINDS = ("above", "around", "failed", "better", "gain")
BEYOND_SEEDS = 5
BEYOND_PRECISION = 0.1  # the largest half-width of a beyond interval with fewer seeds, as a share of its mean
VERDICTS = ("reproduced", "beyond", "not reproduced", "not settled")
RULE = ("A claim holds where our seeds' 95% interval holds it and nothing that would deny it; where the interval "
        "holds both, the verdict is \"not settled at n seeds\" (one seed settles nothing). \"Around X\" is denied "
        "by a score as far from X as half of it; \"failed at F\" by a score above F; a gain by 0. A verdict of "
        "\"beyond\" also needs 5 seeds or an interval within a tenth of its mean. A figure the thesis judged by eye is "
        "judged by eye here too, and settled only over 2 seeds or more.")


@dataclass(frozen=True)
class Claim:
    """A claim of ``kind`` (:data:`KINDS`) about a score: its number ``value`` (X, F or Y; 0 for
    a gain), and for ``around`` the distance from X that denies it (None: half of X)."""
    kind: str
    value: float = 0.0
    tolerance: float | None = None

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"a claim's kind is one of {', '.join(KINDS)}, not {self.kind!r}")
        if not math.isfinite(self.value):
            raise ValueError(f"a claim's value must be a finite number, not {self.value!r}")
        if self.kind == "around" and self.band_width <= 0:
            raise ValueError("an 'around' claim needs a positive tolerance (half of X by default, so X must not be 0)")

    @property
    def beyond(self) -> bool:
        """Whether the claim is one of ours beyond the thesis (``better``, ``gain``)."""
        return self.kind in ("better", "gain")

    @property
    def band_width(self) -> float:
        return abs(self.value) / 2 if self.tolerance is None else self.tolerance

    def words(self) -> str:
        """The claim as a reader reads it: ``"above 18"``, ``"around 30 (denied at 15 or 45)"``."""
        if self.kind == "around":
            return (f"around {self.value:g} (denied at {self.value - self.band_width:g} or "
                    f"{self.value + self.band_width:g})")
        return {"above": f"above {self.value:g}", "failed": f"failed (no better than {self.value:g})",
                "better": f"better than {self.value:g}", "gain": "a gain above 0"}[self.kind]

    def touches(self, low: float, high: float) -> tuple[bool, bool]:
        """Whether the interval [low, high] holds (some score the claim allows, some score that denies it)."""
        if self.kind == "around":
            lo, hi = self.value - self.band_width, self.value + self.band_width
            return high > lo and low < hi, low <= lo or high >= hi
        bar = 0.0 if self.kind == "gain" else self.value
        if self.kind == "failed":
            return low <= bar, high > bar
        return high > bar, low <= bar


@dataclass(frozen=True)
class Verdict:
    """A claim's verdict on ``n`` seeds: ``word`` (:data:`VERDICTS`), and where not settled, why
    (``reason``) and the hours of one core another seed costs (``seed_hours``, None where not known)."""
    word: str
    n: int
    seed_hours: float | None = None
    reason: str = ""

    @property
    def settled(self) -> bool:
        return self.word != "not settled"

    def __str__(self) -> str:
        if self.settled:
            return self.word
        said = f"not settled at {self.n} seed{'s' * (self.n != 1)}" + (f" ({self.reason})" if self.reason else "")
        more = max(BEYOND_SEEDS - self.n, 1)
        if self.seed_hours is not None:
            said += f"; {more} more seed{'s' * (more != 1)} cost about {more * self.seed_hours:.1f} h of one core"
        return said


def verdict(claim: Claim, mean: float, low: float | None, high: float | None, n: int,
            seed_hours: float | None = None) -> Verdict:
    """The verdict of ``claim`` on ``n`` seeds with ``mean`` and 95% interval [``low``, ``high``]
    (None on one seed); ``seed_hours``: what another seed costs, stated where not settled."""
    if low is None or high is None or n < 2:
        return Verdict("not settled", n, seed_hours, "one seed gives no interval")
    allows, denies = claim.touches(low, high)
    if allows and denies:
        return Verdict("not settled", n, seed_hours, "the interval holds both the claim and its denial")
    if allows:
        word = "beyond" if claim.beyond else "reproduced"
    elif claim.kind == "failed" or (claim.kind == "around" and low >= claim.value):
        word = "beyond"
    else:
        word = "not reproduced"
    half_width = max(mean - low, high - mean)  # a score's range clips one side at most
    if word == "beyond" and n < BEYOND_SEEDS and half_width > BEYOND_PRECISION * abs(mean):
        return Verdict("not settled", n, seed_hours, f"beyond needs {BEYOND_SEEDS} seeds or an interval within a "
                                                     "tenth of its mean")
    return Verdict(word, n, seed_hours)


__all__ = ["Claim", "Verdict", "verdict", "KINDS", "VERDICTS", "RULE", "BEYOND_SEEDS", "BEYOND_PRECISION"]
