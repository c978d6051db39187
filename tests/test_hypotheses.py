"""The start-ups' shared ledger (``navkit.hypotheses``): what one look's verdicts do to the hypotheses."""

from __future__ import annotations

from navkit.hypotheses import Tally, settle, weigh


def _looks(verdicts: list[list[bool]], count: int, drop_after: int = 3) -> list[list[Tally]]:
    """``count`` hypotheses weighed by ``verdicts`` (one list a look, by the hypotheses' original
    order; dropped ones not asked); the survivors after each look."""
    hypotheses = [Tally() for _ in range(count)]
    index = {id(h): k for k, h in enumerate(hypotheses)}
    kept, history = list(hypotheses), []
    for look, verdict in enumerate(verdicts):
        kept, _ = weigh(kept, [verdict[index[id(h)]] for h in kept], None, 0.25 * look, drop_after)
        history.append(kept)
    return history


def test_a_look_alike_told_apart_at_one_look_in_three_is_dropped():
    """The right place verified at every look, its look-alike at two of three: the looks that verify
    both are no evidence for either, so the third looks add up and drop it (a look-alike told apart
    only now and then was never dropped when every look for it took one off)."""
    history = _looks([[True, k % 3 != 0] for k in range(9)], 2)
    assert len(history[-1]) == 1 and history[-1][0].support == 10
    assert len(history[5]) == 2 and len(history[6]) == 1  # dropped at its third telling look


def test_looks_that_verify_all_or_none_move_no_count():
    both = [Tally(), Tally()]
    kept, _ = weigh(both, [True, False], None, 0.0, 3)
    for verdicts in ([True, True], [False, False]) * 4:
        kept, _ = weigh(kept, verdicts, None, 0.0, 3, drop_unverified=10)
    assert [h.against for h in kept] == [0, 1]
    kept, looked_for = weigh(kept, [False, True], None, 0.0, 3)
    assert [h.against for h in kept] == [1, 0] and looked_for == [both[1]]


def test_a_place_never_verified_again_falls_by_drop_unverified_alone():
    """Looks that verify nobody drop nobody, until the ``drop_unverified``-th in a row."""
    one = [Tally()]
    for look in range(4):
        one, _ = weigh(one, [False], None, 0.25 * look, 3, drop_unverified=5)
        assert len(one) == 1 and one[0].against == 0
    one, _ = weigh(one, [False], None, 1.0, 3, drop_unverified=5)
    assert one == []


def test_evidence_against_counts_whatever_the_others_did_and_is_no_look_for():
    """Far beams (NavTopo) or a better fit elsewhere (the baseline) count against a hypothesis its
    matcher verified; the look is for the one that stays."""
    a, b = Tally(), Tally()
    kept, looked_for = weigh([a, b], [True, True], [False, True], 0.0, 3)
    assert (a.against, b.against) == (0, 1) and looked_for == [a] and b.unverified == 0


def test_a_verified_place_the_evidence_counts_against_still_tells_against_one_never_verified():
    """NavTopo's far beams contradict a place its matcher verified; a rival the matcher did not verify
    loses ground too (the look verified somewhere else, not it)."""
    contradicted, missed = Tally(), Tally()
    weigh([contradicted, missed], [True, False], [True, False], 0.0, 3)
    assert (contradicted.against, missed.against) == (1, 1)


def test_the_survivor_is_alone_from_the_look_that_left_it_so_and_a_new_rival_ends_it():
    right, alike = Tally(), Tally()
    kept = [right, alike]
    for look in range(3):
        kept, _ = weigh(kept, [True, False], None, 0.25 * look, 3)
    assert kept == [right] and right.alone_since == 0.5 and right.alone_looks == 0
    for look in range(3, 7):
        kept, _ = weigh(kept, [True], None, 0.25 * look, 3)
    assert right.alone_looks == 4 and right.alone_for(1.5) == 1.0
    kept.append(Tally())
    settle(kept, 1.75)
    assert right.alone_since is None and right.alone_looks == 0 and right.alone_for(2.0) == -1.0
