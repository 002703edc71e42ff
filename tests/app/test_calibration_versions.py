"""Versions of the calibration in use: policy, approvals, supersession, the approvals file, the file round trip."""

import json

import numpy as np
import pytest

from handeye.app.calibration_versions import Approvals, History, write_approval
from handeye.app.errors import SessionError

I = np.eye(4)


def _moved(mm: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = mm * 1e-3
    return T


def test_auto_puts_a_settled_version_in_use_and_approve_waits_for_a_person():
    for policy in ("auto", "approve"):
        h = History(policy)
        assert h.first(I, 0.4, 0.0, "armed").number == 1 and h.in_use.number == 1
        v2 = h.propose(_moved(10), 0.5, 10.0, "re-learnt", {"moved_mm": 10.0})
        assert h.pending is v2 and v2.state == "settling" and h.in_use.number == 1
        h.follow(_moved(9.5), 0.45)             # it follows the estimate while it settles
        applied = h.settle(_moved(9.6), 0.42, 20.0)
        assert v2.camera_transform[0][3] == pytest.approx(9.6e-3) and v2.error_mm == pytest.approx(0.42)
        if policy == "auto":
            assert applied is v2 and h.in_use is v2 and h.pending is None and v2.applied_by.startswith("auto")
            assert h.version(1).state == "replaced"
        else:
            assert applied is None and h.in_use.number == 1 and h.waiting_for_approval is v2
            assert h.approve(2, "ann@cell7", 30.0) is v2
            assert h.in_use is v2 and v2.approved_by == "ann@cell7" and v2.applied_by == "approved by ann@cell7"


def test_an_approval_given_while_settling_applies_at_the_settle_and_a_stale_one_changes_nothing():
    h = History("approve")
    h.first(I, 0.4, 0.0, "armed")
    h.propose(_moved(10), 0.5, 10.0, "re-learnt", {})
    assert h.approve(2, "ann", 11.0) is None          # still settling: not in use yet
    assert h.settle(_moved(10), 0.4, 20.0).number == 2 and h.in_use.number == 2
    assert h.approve(2, "bob", 21.0) is None and h.version(2).approved_by == "ann"   # in use already
    assert h.approve(7, "bob", 21.0) is None                                         # unknown


def test_a_knock_during_settling_supersedes_the_pending_version_and_numbers_stay_consecutive():
    h = History("approve")
    h.first(I, 0.4, 0.0, "armed")
    h.propose(_moved(10), 0.5, 10.0, "re-learnt after the move at sample 16", {})
    v3 = h.propose(_moved(25), 0.5, 15.0, "re-learnt after the move at sample 22", {})
    assert [v.number for v in h.versions] == [1, 2, 3] and h.version(2).state == "superseded"
    assert h.pending is v3 and h.approve(2, "ann", 16.0) is None     # the superseded one cannot be approved
    h.settle(_moved(25), 0.4, 20.0)
    assert h.approve(3, "ann", 21.0) is v3


def test_the_history_round_trips_through_plain_data_and_the_config_sets_the_policy():
    h = History("approve")
    h.first(I, 0.4, 0.0, "armed")
    h.propose(_moved(10), 0.5, 10.0, "re-learnt", {"moved_mm": 10.0})
    h.settle(_moved(10), 0.4, 20.0)
    data = json.loads(json.dumps(h.to_dict()))
    assert data["in_use"] == 1 and data["pending"] == 2
    back = History.from_dict(data, "auto")
    assert back.policy == "auto" and back.to_dict()["versions"] == data["versions"]
    assert back.waiting_for_approval is None and back.pending.number == 2
    with pytest.raises(SessionError, match="calibration_history"):
        History.from_dict({"versions": [{"number": 1}]})


def test_approvals_are_read_once_each_and_a_torn_or_bad_line_is_not_lost_or_fatal(tmp_path):
    reader = Approvals([tmp_path])
    assert reader.new() == []
    write_approval(tmp_path, 2, "ann", 5.0)
    assert reader.new() == [{"version": 2, "by": "ann", "t": 5.0}] and reader.new() == []
    with open(tmp_path / "approvals.jsonl", "a") as fh:
        fh.write('not json\n{"version": 3, "by": "bob", "t": 6.0}')      # the last line not finished yet
    assert reader.new() == []
    with open(tmp_path / "approvals.jsonl", "a") as fh:
        fh.write("\n")
    assert reader.new() == [{"version": 3, "by": "bob", "t": 6.0}]
