"""Where a robot without a given pose may be, weighed look by look: one ledger for both systems.

NavTopo's start-up (``navtopo.startup``) and the metric baseline's kidnapped start
(``baselines.metric_grid.tracking``) follow every place the robot's scan may be at as a hypothesis.
Each verifies its hypotheses its own way (scan matching in a location; a fit to the occupancy grid)
and may count other evidence against one (NavTopo's far beams; the grid's best fit elsewhere). What
one look's verdicts do to the hypotheses is this module's rule, the same for both:

- A look *for* a hypothesis verified it and no evidence of that look counts against it.
- A look *tells the hypotheses apart* when it verified at least one of them and is not for all of
  them. Only such a look moves a count by the verdicts: one more against each it is not for, one
  less (never below zero) for each it is for. Evidence counted against a hypothesis adds one
  whatever the others did. So a look that verifies every hypothesis, or none, is no evidence for one
  place over another: it moves no count but by such evidence. (With one taken off at every look
  that verified it, a look-alike told apart at one look in three was never dropped at
  ``drop_after`` 3: three looks for it undid each against.)
- A hypothesis is dropped when its count against reaches ``drop_after``, or after
  ``drop_unverified`` looks in a row that did not verify it.
- One hypothesis left is *alone* from the odometer reading at which it was left so, and counts the
  looks for it since (not the look that left it alone); a rival found later ends that.

Each system adds its own commitment rule on top (``navtopo.startup.Startup._committed``,
``PoseTracker._confirmed``), and its own bookkeeping of the looks for a hypothesis (the locations it
was verified in, the drifted ``map -> odom`` refitted).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypeVar

__all__ = ["Tally", "settle", "weigh"]


@dataclass(kw_only=True, eq=False)
class Tally:
    """A hypothesis's ledger: the looks for and against it, and since when it has been alone."""

    support: int = 1  # looks for it (the one that found it included)
    against: int = 0  # looks against it, less the telling looks for it, never below zero
    unverified: int = 0  # looks in a row that did not verify it
    alone_since: float | None = None  # the odometer when its last rival fell or it was found alone (None: rivals live)
    alone_looks: int = 0  # looks for it since then

    def alone_for(self, odometer: float) -> float:
        """m driven since it was left alone at ``odometer`` now (-1: rivals live)."""
        return -1.0 if self.alone_since is None else odometer - self.alone_since


T = TypeVar("T", bound=Tally)


def weigh(
    hypotheses: Sequence[T],
    verified: Sequence[bool],
    against: Sequence[bool] | None,
    odometer: float,
    drop_after: int,
    drop_unverified: int | None = None,
) -> tuple[list[T], list[T]]:
    """One look's verdicts on ``hypotheses`` (``verified[k]``: the look verified the k-th one;
    ``against[k]``: other evidence of the look counts against it) by the module's rule, at the
    odometer reading ``odometer`` (m): (the hypotheses kept, in order; those the look was for)."""
    against = against if against is not None else [False] * len(hypotheses)
    looks_for = [ok and not bad for ok, bad in zip(verified, against, strict=True)]
    # a hypothesis verified but counted against still tells: the others it did not verify lose ground
    telling = any(verified) and not all(looks_for)
    for h, ok, found, bad in zip(hypotheses, verified, looks_for, against, strict=True):
        if found:
            h.support += 1
            h.against = max(h.against - int(telling), 0)
            h.unverified = 0
            h.alone_looks += int(h.alone_since is not None)
        else:
            h.against += int(telling or bad)
            h.unverified += int(not ok)
    kept = [
        h
        for h in hypotheses
        if h.against < drop_after and (drop_unverified is None or h.unverified < drop_unverified)
    ]
    settle(kept, odometer)
    live = {id(h) for h in kept}
    return kept, [h for h, found in zip(hypotheses, looks_for, strict=True) if found and id(h) in live]


def settle(hypotheses: Sequence[Tally], odometer: float) -> None:
    """The alone marks after hypotheses were dropped or added (at ``odometer``, m): one left is alone
    from now unless it already was; among several, none is."""
    if len(hypotheses) == 1:
        h = hypotheses[0]
        if h.alone_since is None:
            h.alone_since, h.alone_looks = odometer, 0
    elif len(hypotheses) > 1:
        for h in hypotheses:
            h.alone_since, h.alone_looks = None, 0
