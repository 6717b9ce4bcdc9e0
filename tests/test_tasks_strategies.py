"""The planners' fallback ladders: named strategies tried in order, the first that succeeds is taken, and
the reason of each that failed is kept."""

import contextlib

import numpy as np
import pytest

from bimanual_app.tasks._grasps import GraspSpec
from bimanual_app.tasks._motion import PlanFailure
from bimanual_app.tasks._planners import (
    PUSH_PRESS_MARGIN,
    StrategiesFailed,
    Strategy,
    _Pair,
    _squeeze_strategies,
    first_success,
)


def _recording(log, name, result=None, fail=None):
    def attempt():
        log.append(name)
        if fail:
            raise PlanFailure("reach", fail)
        return result
    return Strategy(name, attempt)


def test_ladder_tries_in_order_and_stops_at_the_first_success():
    log = []
    name, result = first_success([_recording(log, "high", fail="too high"), _recording(log, "mid", result=7),
                                  _recording(log, "low", result=9)])
    assert (name, result) == ("mid", 7)
    assert log == ["high", "mid"]  # "low" was never tried


def test_ladder_keeps_the_reason_of_every_failed_strategy():
    log = []
    with pytest.raises(StrategiesFailed) as e:
        first_success([_recording(log, "a", fail="blocked"), _recording(log, "b", fail="out of reach")])
    assert log == ["a", "b"]
    assert [(n, f.message) for n, f in e.value.failures] == [("a", "blocked"), ("b", "out of reach")]
    assert e.value.first.message == "blocked" and e.value.last.message == "out of reach"
    combined = e.value.combined()
    assert combined.stage == "reach" and combined.message == "a: blocked; b: out of reach"


def test_ladder_lets_other_errors_through_and_reports_an_empty_ladder():
    def broken():
        raise ZeroDivisionError  # a bug is not a strategy that failed

    with pytest.raises(ZeroDivisionError):
        first_success([Strategy("bug", broken), Strategy("never", lambda: 1)])
    with pytest.raises(StrategiesFailed, match="no strategy"):
        first_success([])


class _Motion:
    """The part of TaskMotion the squeeze ladder uses: the object's points and straight moves, which fail
    beyond ``reach`` m from the start of the squeeze."""

    def __init__(self, object_points, reach):
        self.object_points = object_points
        self.reach = reach

    def context(self, *args, **kwargs):
        return contextlib.nullcontext()

    def cartesian(self, moves, q, min_duration=0.0):
        for a, (T0, T1) in moves.items():
            d = np.linalg.norm(T1[:3, 3] - T0[:3, 3])
            if d > self.reach:
                raise PlanFailure("reach", f"the {a} cannot press {d * 100:.1f} cm")
        return {a: T1 for a, (T0, T1) in moves.items()}


def _push_pair(contact_gap):
    """Two push grasps squeezing a 10 cm box along x from both sides, their fingertips ``contact_gap`` m
    outside its faces (the gap the squeeze is extended by)."""
    box = np.array([[x, y, z] for x in (-0.05, 0.05) for y in np.linspace(-0.01, 0.01, 3) for z in (0.0, 0.01)])
    G = {}
    for arm, side in (("primary", -1.0), ("secondary", 1.0)):
        T = np.eye(4)
        T[:3, 3] = [side * (0.05 + contact_gap), 0.0, 0.005]
        G[arm] = GraspSpec(arm, T, 0.02, kind="push", press=0.004, squeeze=np.array([-side, 0.0, 0.0]))
    return box, G


def test_squeeze_ladder_falls_back_to_half_the_gap_where_the_whole_gap_is_out_of_reach():
    box, G = _push_pair(0.012)
    P = _Pair(_Motion(box, reach=0.012 + PUSH_PRESS_MARGIN), G, True, np.array([0.0, 0.0, 1.0]), PUSH_PRESS_MARGIN)
    touch = {a: G[a].T_b1_g for a in G}
    ladder = _squeeze_strategies(P, touch, {})
    assert [s.name for s in ladder] == ["press and the gap", "press and half the gap", "press alone"]
    whole = 0.004 + PUSH_PRESS_MARGIN + 0.012
    with pytest.raises(PlanFailure, match=f"cannot press {whole * 100:.1f} cm"):  # each strategy on its own
        ladder[0].attempt()
    S, _ = ladder[1].attempt()
    # press (and the margin for the estimate's width error) + half the 1.2 cm gap
    assert S["primary"][0, 3] == pytest.approx(-0.062 + 0.004 + PUSH_PRESS_MARGIN + 0.006)
    name, (S, _) = first_success(ladder)
    assert name == "press and half the gap"


def test_squeeze_ladder_without_a_gap_has_one_strategy_and_keeps_its_reason():
    box, G = _push_pair(0.0)
    P = _Pair(_Motion(box, reach=0.001), G, True, np.array([0.0, 0.0, 1.0]), PUSH_PRESS_MARGIN)
    ladder = _squeeze_strategies(P, {a: G[a].T_b1_g for a in G}, {})
    assert [s.name for s in ladder] == ["press and the gap"]
    with pytest.raises(StrategiesFailed) as e:
        first_success(ladder)
    assert [n for n, _ in e.value.failures] == ["press and the gap"]
    assert f"cannot press {(0.004 + PUSH_PRESS_MARGIN) * 100:.1f} cm" in e.value.first.message


@pytest.mark.parametrize("fails_at, margins_tried, planned", [
    ("squeeze", [PUSH_PRESS_MARGIN, 0.0], True),  # too deep for an arm: planned at the press alone
    ("lift", [PUSH_PRESS_MARGIN, 0.0], True),
    ("reach", [PUSH_PRESS_MARGIN], False),  # before the squeeze: the press changes nothing, no second try
])
def test_a_push_pair_squeezes_deeper_first_then_at_its_press(monkeypatch, fails_at, margins_tried, planned):
    import bimanual_app.tasks._planners as planners
    from bimanual_app.tasks._planners import plan_joint_grasp

    tried = []

    def fake(motion, choice, q_start, width_start, lift, up, at, press_margin=0.0):
        tried.append(press_margin)
        at.extend(["approach", "squeeze", "lift"][: ["reach", "approach", "squeeze", "lift"].index(fails_at)])
        if press_margin > 0 or fails_at == "reach" or choice.kind == "pinch":
            raise PlanFailure("reach", "cannot")
        return "plan"

    monkeypatch.setattr(planners, "_joint_grasp", fake)
    choice = type("Choice", (), {"kind": "push"})()
    if planned:
        assert plan_joint_grasp(None, choice, {}, {}) == "plan"
    else:
        with pytest.raises(PlanFailure) as e:
            plan_joint_grasp(None, choice, {}, {})
        assert e.value.message == "reach: cannot"  # the phase it failed at, then why
    assert tried == margins_tried
    tried.clear()
    choice.kind = "pinch"  # a pinch pair closes its fingers: no press margin, one try
    with pytest.raises(PlanFailure):
        plan_joint_grasp(None, choice, {}, {})
    assert tried == [0.0]
