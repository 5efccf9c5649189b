"""The report's words come from the scenario: the quick preview names how the observer study makes its gains
(``Y = v I`` on the paper's arm, ``Y = v M^(q0)`` in rad/s on a URDF arm), and the frequency reading speaks of
the arm's own prismatic joint."""
from __future__ import annotations

import pytest

from analysis.report.settings import QUICK_SETTINGS, observer_study_gains, preview_differences
from blocks.scenarios.scenario import load_scenario


def _observer_phrase(phrases) -> str:
    return next(p for p in phrases if p.startswith("observer gains"))


def test_the_paper_preview_keeps_its_words():
    s = load_scenario("paper")
    assert observer_study_gains(s) == "Y = v I"
    phrase = _observer_phrase(preview_differences(QUICK_SETTINGS, joints=s.robot.joints,
                                                  observer_gains=observer_study_gains(s)))
    assert phrase == "observer gains Y = v I of the observer study: v = 3, 30 (full: v = 1, 3, 10, 30, 100)"


def test_a_urdf_preview_says_v_times_the_inertia():
    pytest.importorskip("pinocchio")
    s = load_scenario("scope4")
    assert observer_study_gains(s) == "Y = v M^(q0)"
    phrase = _observer_phrase(preview_differences(QUICK_SETTINGS, joints=s.robot.joints,
                                                  observer_gains=observer_study_gains(s)))
    assert phrase.startswith("observer gains Y = v M^(q0) of the observer study: v = 3, 30 rad/s (full: ")
    assert "v I" not in phrase


def _metrics(dc_with, dc_without, n):
    from types import SimpleNamespace
    band = SimpleNamespace(kind="band-pass", peak_rad_s=10.0, peak_gain=1e-3, dc_gain=0.0, band_3db_rad_s=(1.0, 50.0))

    def joint(j, dc):
        return SimpleNamespace(**{**vars(band), "dc_gain": dc if j == n["at"] else 0.0})
    return [joint(j, dc_with) for j in range(n["count"])], [joint(j, dc_without) for j in range(n["count"])]


def _reading(joints, at, paper=False):
    from types import SimpleNamespace

    from analysis.report.view.frequency import _frequency_reading
    w, wo = _metrics(0.0, -2e-3, {"at": at, "count": joints.count})
    high = SimpleNamespace(kind="high-pass", peak_rad_s=None, peak_gain=1.0, dc_gain=0.0, band_3db_rad_s=(10.0, None))
    fr = SimpleNamespace(tracking_without_dob=SimpleNamespace(metrics=wo), tracking_with_dob=SimpleNamespace(metrics=w),
                         estimation_with_dob=SimpleNamespace(metrics=[high] * joints.count))
    return _frequency_reading(fr, True, joints, paper)


def test_the_frequency_reading_speaks_of_the_arms_own_prismatic_joint():
    from blocks.model.joints import JointSpace
    from blocks.model.rrpr.joints import RRPR_JOINTS
    # the paper's words, as before: its joint 3 (d3) sets the depth
    assert _reading(RRPR_JOINTS, 2, paper=True).startswith(
        "A constant force of 1 N on the prismatic joint leaves 2 mm of depth error without the observer and none "
        "with it. ")
    # an arm whose prismatic joint is its first: that joint's numbers, under its name
    slider = JointSpace(names=("slide", "yaw", "pitch"), kinds=("prismatic", "revolute", "revolute"))
    assert _reading(slider, 0).startswith("A constant force of 1 N on the prismatic joint Joint 1 (slide) leaves 2 mm "
                                          "of error on it without the observer and none with it. ")
    # no prismatic joint: no such sentence
    arm = JointSpace(names=("a", "b"), kinds=("revolute", "revolute"))
    assert not _reading(arm, 0).startswith("A constant force")


def test_the_report_header_of_a_urdf_quick_preview_says_v_times_the_inertia():
    """The header the report page shows (its quick-preview list), made from the scenario."""
    pytest.importorskip("pinocchio")
    from types import SimpleNamespace

    from analysis.report.view import _header
    for name, words in (("scope4", "Y = v M^(q0)"), ("paper", "Y = v I")):
        s = load_scenario(name)
        header = _header(SimpleNamespace(settings=QUICK_SETTINGS, digital=None), s)
        phrase = _observer_phrase(header.preview)
        assert phrase.startswith(f"observer gains {words} of the observer study")
