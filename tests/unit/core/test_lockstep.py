"""The simulator-side lockstep barrier (pure threading)."""

import threading
import time

from scenenav.core.contracts import LockstepRole
from scenenav.core.lockstep import LockstepBarrier

T, C = LockstepRole.TICK, LockstepRole.CAMERA


def test_no_members_no_wait():
    b = LockstepBarrier()
    b.published(T, 0)
    assert b.wait(T, 0, 0.01) == []


def test_waits_for_ack():
    b = LockstepBarrier()
    b.member_changed(T, "ap", True)
    b.published(T, 0)
    threading.Timer(0.05, lambda: b.ack("ap", T, 0)).start()
    assert b.wait(T, 0, 5.0) == []


def test_new_member_only_answers_later_seqs():
    b = LockstepBarrier()
    b.published(C, 7)
    b.member_changed(C, "p2", True)       # joined after frame 7 was out
    assert b.wait(C, 7, 0.01) == []       # not waited for frame 7
    b.published(C, 8)
    assert b.wait(C, 8, 0.01) == ["p2"]   # but for frame 8 (times out here)
    assert b.timeouts == 1


def test_departed_member_releases_wait():
    b = LockstepBarrier()
    b.member_changed(C, "p1", True)
    b.published(C, 0)
    threading.Timer(0.05, lambda: b.member_changed(C, "p1", False)).start()
    t0 = time.monotonic()
    assert b.wait(C, 0, 5.0) == []
    assert time.monotonic() - t0 < 4.0


def test_roles_are_separate_and_wrong_role_ack_ignored():
    b = LockstepBarrier()
    b.member_changed(T, "ap", True)
    b.member_changed(C, "p1", True)
    b.published(T, 0)
    b.published(C, 0)
    b.ack("p1", T, 0)                     # wrong role: ignored
    assert b.wait(T, 0, 0.01) == ["ap"]
    b.ack("p1", C, 0)
    assert b.wait(C, 0, 0.01) == []


def test_wait_members():
    b = LockstepBarrier()
    threading.Timer(0.05, lambda: b.member_changed(T, "ap", True)).start()
    assert b.wait_members({T: 1}, 5.0)
    assert not b.wait_members({C: 1}, 0.05)


def test_answer_times_count_each_members_answers_to_the_current_seq():
    b = LockstepBarrier()
    b.member_changed(T, "ap", True)
    b.member_changed(C, "cam", True)
    for seq in range(3):
        b.published(T, seq)
        b.ack("ap", T, seq)
    b.ack("ap", T, 1)                     # a repeated (stale) ack is not timed again
    b.published(C, 0)
    b.ack("cam", C, 0)
    b.ack("cam", C, 5)                    # an ack for a frame not yet published is not timed
    b.member_changed(T, "gd", True)       # a tick member answering ahead: timed for seq 3 ...
    b.published(T, 3)
    b.ack("gd", T, 9)
    b.published(T, 4)                     # ... not for 4 (answered already), again for 10
    b.published(T, 10)
    b.ack("gd", T, 10)
    assert b.wait(T, 4, 0.01) == ["ap"]   # gd answered 4 ahead, ap did not
    times = b.answer_times()
    assert set(times) == {"ap", "cam", "gd"}
    assert times["ap"][0] == 3 and times["cam"][0] == 1 and times["gd"][0] == 2
    assert all(total >= 0.0 for _, total in times.values())
    b.member_changed(T, "ap", False)      # a member that left keeps its figures
    assert b.answer_times()["ap"][0] == 3


def test_a_member_that_times_out_is_suspended_until_it_answers_again():
    b = LockstepBarrier()
    b.member_changed(T, "ap", True)
    b.member_changed(C, "cam", True)
    b.published(C, 0)
    assert b.wait(C, 0, 0.05) == ["cam"]          # reported once ...
    assert b.suspended() == ["cam"]
    for seq in (1, 2, 3):                          # ... then skipped without waiting
        b.published(C, seq)
        t0 = time.monotonic()
        assert b.wait(C, seq, 5.0) == []
        assert time.monotonic() - t0 < 1.0
    assert b.timeouts == 1 and b.take_rejoined() == []
    b.ack("cam", C, 2)                             # a late answer: it rejoins, named once
    assert b.take_rejoined() == ["cam"] and b.take_rejoined() == []
    assert b.suspended() == []
    b.published(C, 4)
    assert b.wait(C, 4, 0.05) == ["cam"]           # waited for again
    b.ack("cam", C, 5)
    b.published(C, 5)
    assert b.wait(C, 5, 0.05) == []


def test_a_suspended_member_is_behind_only_once_it_holds_the_backlog_unanswered():
    b = LockstepBarrier()
    cam = LockstepRole.CAMERA
    assert not b.all_suspended_and_behind(cam, 4)              # no members: nothing to hold back
    b.member_changed(cam, "p", True)
    b.published(cam, 0)
    assert b.wait(cam, 0, 0.01) == ["p"]                        # timed out on frame 0: suspended
    for seq in (1, 2, 3):
        b.published(cam, seq)
        assert not b.all_suspended_and_behind(cam, 4)           # it may still hold these
    b.published(cam, 4)
    assert b.all_suspended_and_behind(cam, 4)                   # four unanswered since: frozen
    b.ack("p", cam, 2)                                          # it woke and answers its backlog
    assert not b.all_suspended_and_behind(cam, 4) and b.take_rejoined() == ["p"]
    # a slow member that still answers is never held back, however long it stays suspended
    b.published(cam, 5)
    assert b.wait(cam, 5, 0.01) == ["p"]
    for seq in range(6, 20):
        b.published(cam, seq)
        b.ack("p", cam, seq - 2)
        assert not b.all_suspended_and_behind(cam, 4)
    # with a second member that answers, frames always go out
    b.member_changed(cam, "q", True)
    b.published(cam, 30)
    assert not b.all_suspended_and_behind(cam, 4)
