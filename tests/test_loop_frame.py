"""The loop measures every form of z from the static position its model implies (nifo_core/loop/frame.py), and
re-tunes such a form in it; a bump stop's static gap placed beyond the mean's range and re-tuned with the model in
later rounds (nifo_core/loop/stops.py)."""

from nifo_core.kinds.describing import Term
from nifo_core.loop.closing import close_loop
from nifo_core.loop.settings import LoopSettings
from nifo_core.simulate.quarter_car import RandomRoad, SensorNoise, SimConfig, StrutForce, simulate

REBOUND = Term("asymmetric_damping", {"side": "rebound"})


def _loop_beside_a_rebound_damper(strut, levels_mm, seed, max_rounds):
    """The loop (no refinement) on 3 × 90 s of nifo's simulator with ``strut``, the rebound damper declared;
    the result and the sprung mass."""
    m2 = SimConfig().vehicle.m2
    recs = [simulate(SimConfig(strut=strut, road=RandomRoad(rms_m=r * 1e-3), duration_s=90.0,
                               noise=SensorNoise(relative=0.01)), rng=seed + i).record
            for i, r in enumerate(levels_mm)]
    res = close_loop(recs, [REBOUND], m2_kg=m2, settings=LoopSettings(refine=False, max_rounds=max_rounds))
    print(res.verdict, res.notes)
    return res, m2


def test_a_hidden_cubic_beside_a_declared_rebound_damper_is_the_cubic_not_a_stop():
    # issue 54 (the fleet's tune case 19): a damper stiffer in rebound pushes the mean position into compression,
    # the more the harder the road; a cubic spring acts about the static position, so measured from each record's
    # mean it holds an even spring and a stiffness that change with the level, and the loop added compression
    # stops for it. With the forms of z measured from the static position the declared damper implies, the cubic
    # is added, within 10 % of its coefficient, and nothing else
    rebound, cubic = 2000.0, 3e7
    strut = (StrutForce(REBOUND, rebound), StrutForce(Term("cubic_stiffness", {}), cubic))
    res, m2 = _loop_beside_a_rebound_damper(strut, (2.0, 4.0, 7.0), 5400, 3)
    assert [t.kind for t in res.terms] == ["asymmetric_damping", "cubic_stiffness"]
    assert abs(res.final.theta_per_kg[1] * m2 - cubic) < 0.1 * cubic
    frame = next(n for n in res.notes if n.startswith("every form of z measured from the static position"))
    assert "mm" in frame


def test_a_stop_beside_a_declared_rebound_damper_and_a_hidden_knee_is_placed_at_its_static_gap():
    # issue 54 (the fleet's #83 kind): a damper stiffer in rebound pushes the mean position towards a compression
    # stop, so the stop's static gap lies beyond its gap from the mean, where the placement's search (up to 1.05 ×
    # the gap from the mean) did not look: the stop was placed at 6.3 mm for 9 mm and frozen there, and a clearance
    # was added to correct its shape. Now the stop is placed from the static position beyond that range and re-tuned
    # once the knee is in the model: exactly the stop and the knee, the gap within 3 %, the coefficients within 10 %
    (knee_c, knee), (stop_c, gap) = (-700.0, 0.04), (1.5e5, 0.009)
    strut = (StrutForce(REBOUND, 2500.0), StrutForce(Term("velocity_deadzone", {"knee": knee}), knee_c),
             StrutForce(Term("bump_stop", {"gap": gap, "side": "compression"}), stop_c))
    res, m2 = _loop_beside_a_rebound_damper(strut, (1.5, 3.0, 5.0), 5470, 4)
    assert sorted(t.kind for t in res.terms) == ["asymmetric_damping", "bump_stop", "velocity_deadzone"]
    got = {t.kind: (t, th * m2) for t, th in zip(res.terms, res.final.theta_per_kg)}
    stop, c = got["bump_stop"]
    assert abs(stop.params["gap"] - gap) < 0.03 * gap and abs(c - stop_c) < 0.1 * stop_c
    assert abs(got["velocity_deadzone"][1] - knee_c) < 0.1 * abs(knee_c)
    assert any("from the static position" in r.text for r in res.rounds[1:])    # re-tuned in a later round


def test_a_clearance_beside_a_declared_rebound_damper_is_re_tuned_in_the_frame_not_from_the_mean():
    # issue 54: a clearance the loop added is measured from the static position; its gap was re-tuned in later
    # rounds lifted out of the frame, from each record's mean (which a rebound damper pushes into compression, the
    # more the harder the road): an own draw of the fleet generator (seed 54545, case 2, not a fleet case: a
    # rebound damper declared, a clearance beyond 3.09 mm and a knee hidden) had its clearance, added at 3.01 mm,
    # re-tuned to 1.54 mm, and a compression stop added to make up for it. Re-tuned in the frame: exactly the knee
    # and the clearance, its gap and coefficient within 10 %
    import sys
    from dataclasses import replace
    from pathlib import Path

    import numpy as np

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from bench_physics_fleet import _effect, draw_case, simulate_level

    c = draw_case(2, seed=54545)
    rng = np.random.default_rng([54546, 2])
    c2 = c.corner["c2"]
    case = replace(c, declared=_effect("asymmetric_damping", rng, c2), simulator="nifo", duration_s=90.0,
                   hidden=(_effect("clearance", rng, c2), _effect("velocity_deadzone", rng, c2)))
    recs = [simulate_level(case, j) for j in range(len(case.levels_mm))]
    m2 = case.corner["m2"]
    res = close_loop(recs, [REBOUND], m2_kg=m2, settings=LoopSettings(refine=False, max_rounds=4))
    print(res.verdict)
    assert sorted(t.kind for t in res.terms) == ["asymmetric_damping", "clearance", "velocity_deadzone"]
    truth = case.hidden[0]
    got = {t.kind: (t, th * m2) for t, th in zip(res.terms, res.final.theta_per_kg)}
    gap, coef = got["clearance"][0].params["gap"], got["clearance"][1]
    assert abs(gap / truth.params["gap"] - 1) < 0.1 and abs(coef / truth.coefficient - 1) < 0.1
