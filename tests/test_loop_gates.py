"""The loop names only what is there: a candidate that one term of a kind already present can replace is not added.

Against simulated truth (2 % noise on both sensors); the figures are printed.
"""

from __future__ import annotations

from nifo_core.characterize.restoring import suggest_band
from nifo_core.kinds.describing import Term
from nifo_core.loop import LoopSettings, close_loop
from nifo_core.loop.gates import one_of_kind_alternatives
from nifo_core.simulate import RandomRoad, SensorNoise, SimConfig, StrutForce, simulate

M2 = 300.0


def test_the_alternatives_are_a_second_term_of_a_present_kind_and_the_present_kinds_re_placed():
    knee, stop = Term("velocity_deadzone", {"knee": 0.09}), Term("bump_stop", {"gap": 0.008, "side": "compression"})
    other_knee, friction = Term("velocity_deadzone", {"knee": 0.03}), Term("coulomb", {"eps": 0.01})
    assert one_of_kind_alternatives([knee], other_knee, [other_knee, friction], {}) == [(0, other_knee)]
    assert one_of_kind_alternatives([knee], friction, [friction, other_knee], {}) == [(0, other_knee)]
    assert one_of_kind_alternatives([knee, stop], friction, [friction, knee], {}) == []    # the same knee: no change
    second = Term("bump_stop", {"gap": 0.006, "side": "compression"})
    assert one_of_kind_alternatives([stop], second, [], {stop.label: (0.0,)}) == [(0, second)]  # one stop, not two
    assert one_of_kind_alternatives([stop, knee], friction, [friction, Term("bump_stop", {"gap": 0.005})],
                                    {stop.label: (0.0,)}) == []      # a stop from the static position: its own fit


def test_a_friction_that_only_stands_in_for_a_misplaced_declared_knee_is_not_added():
    # the damper knee is at 0.03 m/s, declared at 0.09 with re-tuning off: a friction's sign(ż) absorbs the
    # difference and passes every other gate (measured before this gate: coulomb(eps=0.031) added at 24.8 N). In the
    # band the first record alone suggests (1.6 Hz); in the band both suggest together (1.24 Hz, the loop's default)
    # the friction does not even pass the significance test (measured: p 0.0087), and the gate is not reached
    truth = (StrutForce(Term("velocity_deadzone", {"knee": 0.03}), -700.0),)
    recs = [simulate(SimConfig(strut=truth, road=RandomRoad(rms_m=rms), duration_s=90.0, fs_hz=600.0,
                               noise=SensorNoise(relative=0.02)), rng=31 + i).record
            for i, rms in enumerate((0.0025, 0.005))]
    res = close_loop(recs, (Term("velocity_deadzone", {"knee": 0.09}),), m2_kg=M2, band=suggest_band(recs[0]).band,
                     settings=LoopSettings(max_rounds=2, refine=False, retune=False))
    tried = [t for r in res.rounds for t in r.trials]
    print(f"\nknee -700 N·s/m at 0.03 m/s declared at 0.09 (re-tuning off), 2 × 90 s at 2.5 and 5 mm, 2 % noise: "
          f"added {[c.term.label for c in res.added]}; " + "; ".join(f for t in tried for f in t.failed
                                                                   if "stands in" in f))
    assert not res.added, res.report()
    assert any("stands in for velocity_deadzone(knee=0.09)" in f for t in tried for f in t.failed), res.report()
    # the friction and the knee re-placed predict the held-out parts alike: an ambiguity, named with both (issue 54)
    doc = res.to_dict()
    assert not res.nothing_missing and "cannot tell them apart" in res.verdict, res.verdict
    amb = doc["ambiguities"]
    assert len(amb) == 1 and set(amb[0]["kinds"]) == {"coulomb", "velocity_deadzone"}
    assert {t["kind"] for o in amb[0]["options"] for t in o["terms"]} == {"coulomb", "velocity_deadzone"}
    assert all(o["heldout_prediction_nmse_pct"] > 0 for o in amb[0]["options"])


def test_a_cubic_inactive_at_the_low_level_and_active_at_the_high_one_is_added():
    # the lead's Silverbox case (5 and 150 mV: "coefficient stability unknown: the term acts in only one data
    # group", the loop ended linear): the low level's z³ carries < 1e-3 of the high one's information, so its
    # group says nothing and the stability was unknown. It is now judged across the quarters of the records where
    # the term acts. Measured without that: nothing added, "The declared model lacks nothing the library can name"
    truth = (StrutForce(Term("cubic_stiffness"), 2e8),)
    recs = [simulate(SimConfig(strut=truth, road=RandomRoad(rms_m=rms), duration_s=90.0, fs_hz=600.0,
                               noise=SensorNoise(relative=0.01)), rng=5 + i).record
            for i, rms in enumerate((0.0002, 0.004))]
    res = close_loop(recs, (), m2_kg=M2, settings=LoopSettings(max_rounds=2, refine=False))
    cubic = res.rounds[0].trials[0].candidate
    print(f"\ncubic 2e8 N/m³ at 0.2 and 4 mm road, 1 % noise: added {[c.term.label for c in res.added]}, spread "
          f"{cubic.spread:.3f}, coefficient {res.final.theta_per_kg[0] * M2:.4g} N/m³")
    assert [c.kind for c in res.added] == ["cubic_stiffness"], res.report()
    assert 0 <= cubic.spread < 0.1
    assert abs(res.final.theta_per_kg[0] * M2 / 2e8 - 1) < 0.10
