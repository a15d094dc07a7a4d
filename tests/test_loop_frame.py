"""The loop measures every form of z from the static position its model implies (nifo_core/loop/frame.py)."""

from nifo_core.kinds.describing import Term
from nifo_core.loop.closing import LoopSettings, close_loop
from nifo_core.simulate.quarter_car import RandomRoad, SensorNoise, SimConfig, StrutForce, simulate


def test_a_hidden_cubic_beside_a_declared_rebound_damper_is_the_cubic_not_a_stop():
    # issue 54 (the fleet's tune case 19): a damper stiffer in rebound pushes the mean position into compression,
    # the more the harder the road; a cubic spring acts about the static position, so measured from each record's
    # mean it holds an even spring and a stiffness that change with the level, and the loop added compression
    # stops for it. With the forms of z measured from the static position the declared damper implies, the cubic
    # is added, within 10 % of its coefficient, and nothing else
    rebound, cubic = 2000.0, 3e7
    strut = (StrutForce(Term("asymmetric_damping", {"side": "rebound"}), rebound),
             StrutForce(Term("cubic_stiffness", {}), cubic))
    m2 = SimConfig().vehicle.m2
    recs = [simulate(SimConfig(strut=strut, road=RandomRoad(rms_m=r * 1e-3), duration_s=90.0,
                               noise=SensorNoise(relative=0.01)), rng=5400 + i).record
            for i, r in enumerate((2.0, 4.0, 7.0))]
    res = close_loop(recs, [Term("asymmetric_damping", {"side": "rebound"})], m2_kg=m2,
                     settings=LoopSettings(refine=False, max_rounds=3))
    print(res.verdict, res.notes)
    assert [t.kind for t in res.terms] == ["asymmetric_damping", "cubic_stiffness"]
    assert abs(res.final.theta_per_kg[1] * m2 - cubic) < 0.1 * cubic
    frame = next(n for n in res.notes if n.startswith("every form of z measured from the static position"))
    assert "mm" in frame
