"""Silverbox multilevel (Noël & Schoukens, IJC 2018, doi 10.1080/00207179.2017.1308557): a measured input.

The electronic Duffing oscillator m·ÿ + d·ẏ + (a + b·y²)·y = u, input and
displacement output in separate MAT files, five levels. Checked here, with the
loader options a user gives (``tools/silverbox.py`` runs the same through the CLI):

- the linear part at the lowest level is within 1 % of the published 68.58 Hz
  and 4.68 % damping;
- a cubic model identified at the highest level predicts every other level
  with an NMSE at least 10× lower than the linear model identified on the same
  level, in the body (output) acceleration and in the period-averaged
  displacement y.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from nifo.io.loader import load_record
from nifo_core.kinds.describing import make_term
from nifo_core.signal.integrate import IntegrationBand
from nifo_core.predict.model import IdentifiedModel, predict_body
from nifo_core.nifo.identify import identify_nifo
from nifo_core.signal.spectral import SpectralSettings

PERIOD = 8192
COLUMNS = {"body_disp": "ym", "force": "um@{name:_ym_=_um_}", "spindle_accel": "fixed"}
SETTINGS = SpectralSettings(block=PERIOD, overlap=0.0, window="boxcar")
BAND = IntegrationBand(1.0, 900.0)
ANALYSIS = (5.0, 250.0)
LEVELS = (5, 20, 50, 100, 150)


def _load(data, level):
    return load_record(data / "silverbox_multilevel" / f"SNJP_ym_full_FNSI_{level}.mat", columns=COLUMNS,
                       skip_periods=5, period_samples=PERIOD)


def _identify(rec, terms):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # the cubic regressor carries the output: cond(G_UU) is high per line
        return identify_nifo(rec, terms, settings=SETTINGS, band=BAND, analysis_band_hz=ANALYSIS)


def test_loader_combines_the_two_files_and_differentiates_exactly(shared_data):
    rec = _load(shared_data, 5)
    assert rec.spindle_fixed and rec.n == 25 * PERIOD and rec.fs_hz == pytest.approx(2441.40625)
    assert rec.meta["skipped_samples"] == 5 * PERIOD and "exact" in rec.meta["body_from_displacement"]


def test_linear_part_at_the_lowest_level_matches_the_published_one(shared_data):
    res = _identify(_load(shared_data, 5), [])
    m2, k2, c2, misfit = res.static.one_mass
    fn = np.sqrt(k2 / m2) / (2 * np.pi)
    zeta = c2 / (2 * np.sqrt(k2 * m2))
    print(f"5 mV: {fn:.3f} Hz, damping {100 * zeta:.3f} %, one-mass misfit {100 * misfit:.2f} %")
    assert fn == pytest.approx(68.58, rel=0.01)
    assert zeta == pytest.approx(0.0468, rel=0.01)
    assert misfit < 0.03


def _period_average(x):
    p = np.asarray(x)[PERIOD:]
    p = p[:p.size // PERIOD * PERIOD].reshape(-1, PERIOD).mean(axis=0)
    return p - p.mean()


def _displacement(rec):
    w = 2 * np.pi * np.fft.rfftfreq(rec.n, 1 / rec.fs_hz)
    a = np.fft.rfft(rec.body_accel)
    a[1:] /= -(w[1:] ** 2)
    a[0] = 0.0
    return np.fft.irfft(a, rec.n)


def _nmse(y, yhat):
    return float(100 * np.mean((y - yhat) ** 2) / np.var(y))


@pytest.mark.slow
def test_cubic_identified_at_150_mv_predicts_every_other_level_10x_better_than_linear(shared_data):
    recs = {lv: _load(shared_data, lv) for lv in LEVELS}
    models = {name: IdentifiedModel.from_nifo(_identify(recs[150], terms))
              for name, terms in (("cubic", [make_term("cubic_stiffness")]), ("linear", []))}
    assert models["cubic"].force_gain > 0 and models["linear"].force_gain > 0
    for lv in LEVELS[:-1]:
        rec = recs[lv]
        u = rec.force - rec.force.mean()          # DC is neither excited nor identified
        y = _period_average(_displacement(rec))
        acc, disp = {}, {}
        for name, model in models.items():
            p = predict_body(model, None, rec.fs_hz, force=u, label=rec.source)
            v = p.valid
            acc[name] = _nmse(rec.body_accel[v], p.body_accel[v])
            disp[name] = _nmse(y, _period_average(p.z))
        print(f"{lv:>3} mV: acceleration NMSE cubic {acc['cubic']:.3f} % vs linear {acc['linear']:.2f} %; "
              f"displacement {disp['cubic']:.3f} % vs {disp['linear']:.2f} %")
        assert acc["cubic"] * 10 < acc["linear"]
        assert disp["cubic"] * 10 < disp["linear"]


@pytest.mark.slow
def test_nifo_run_hands_off_at_150_mv_loops_to_the_cubic_and_predicts_every_other_level_10x_better(shared_data,
                                                                                                  tmp_path):
    """The main job with only the columns (period, transient, bands read off the data): characterize, identify and
    the loop from the linear model, which adds the cubic (and the circuit's asymmetry); its model predicts every other
    level at least 10× better than the linear model of the same level, in the band NMSE of the output and in the
    displacement as measured (RMS error in volts); its refinement is kept only when it predicts the held-out part no
    worse."""
    import json

    from nifo.cli import main

    cols = ["--columns", "body_disp=ym,force=um@{name:_ym_=_um_},spindle_accel=fixed"]
    files = {lv: shared_data / "silverbox_multilevel" / f"SNJP_ym_full_FNSI_{lv}.mat" for lv in LEVELS}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["-q", "run", str(files[150]), *cols, "--out", str(tmp_path / "run"), "--no-recording"]) == 0
        # the numbers only: the run's own predict step draws the same figures of a Silverbox level
        assert main(["-q", "predict", *[str(files[lv]) for lv in LEVELS if lv != 150], *cols, "--model",
                     str(tmp_path / "run" / "loop"), "--out", str(tmp_path / "pred"), "--no-plots"]) == 0
    loop = json.loads((tmp_path / "run" / "loop" / "loop.json").read_text())
    assert loop["effects_added"] and loop["effects_added"][0]["kind"] == "cubic_stiffness", loop["report"]
    # below the equation error's reach, a term of ż by output error (measured: a damping knee at 44 V/s; a dry
    # friction of negative sign predicts within 0.6 % of it, so the kind is not pinned, its variable is)
    from nifo_core.kinds.describing import KINDS
    beyond = loop["effects_added_by_output_error"]
    assert len(beyond) == 1 and KINDS[beyond[0]["term"]["kind"]].variable == "zdot", loop["report"]
    ref = loop["refinement"]
    if ref and ref["kept"]:
        assert ref["heldout_prediction_nmse_after_pct"] <= ref["heldout_prediction_nmse_before_pct"]
    recs = json.loads((tmp_path / "pred" / "predict.json").read_text())["records"]
    for r in recs:
        m, li = r["model"], r["linear"]
        print(f"{r['name']}: band NMSE {m['band_nmse']['percent']:.3f} % vs linear {li['band_nmse']['percent']:.3f} %; "
              f"RMS error {1e3 * m['whole_signal']['rms_error']:.3f} mV vs {1e3 * li['whole_signal']['rms_error']:.3f} mV")
        assert r["output"]["name"] == "body_disp"
        assert m["band_nmse"]["percent"] * 10 <= li["band_nmse"]["percent"], r["name"]
        assert m["whole_signal"]["rms_error"] * 3 <= li["whole_signal"]["rms_error"], r["name"]
        # the raw signal, offset included (issue 53): the model carries the circuit's operating point (the force's
        # mean it was identified about, the output's offset), and the damping that rises with the velocity which
        # the search by output error adds (nifo_core.loop.beyond); measured 2026-12-06: 0.58, 0.50, 0.29, 0.41 mV
        # at 5/20/50/100 mV (without that search 0.65, 0.98, 0.93, 1.01 mV; before the offsets 0.88-1.48 mV)
        assert m["whole_signal"]["rms_error"] < 0.75e-3, r["name"]
        assert abs(m["whole_signal"]["offset_error"]) < 0.5e-3, r["name"]
