"""A measured force on the body: Record, readers (CSV, MAT, bag), NIFO with force, characterize, predict.

Truth: a single mass driven by a force (and optionally by a moving spindle),
m·ẍ2 + d·ż + k·z + b·z³ = F with z = x2 - x1, integrated here by RK4 at ten
times the sample rate with the inputs linear between fine steps (the
simulator in ``nifo_core`` drives the tire, not the body).
"""

from __future__ import annotations

import json
import warnings

import numba
import numpy as np
import pytest
import scipy.io
from scipy.signal import butter, sosfiltfilt

from nifo.cli import main as nifo_main
from nifo.io.loader import iter_record_chunks, load_record, save_record
from nifo_core.characterize.automatic import characterize
from nifo_core.kinds.describing import make_term
from nifo_core.errors import ConfigError, DataFileError, InputError, RecordTooShortError, TimestampError
from nifo_core.signal.integrate import IntegrationBand
from nifo_core.predict.model import IdentifiedModel, predict_body
from nifo_core.nifo.identify import IllConditionedWarning, identify_nifo
from nifo_core.signal.record import Record, acceleration_from_displacement
from nifo_core.signal.spectral import SpectralSettings

M, K = 2.0, (2 * np.pi * 20) ** 2 * 2.0          # 2 kg on 31.6 kN/m: 20 Hz
D = 2 * 0.05 * np.sqrt(K * M)                      # 5 % damping
B3 = 1e9                                           # N/m³: cubic ≈ 40 % of K2·z at 40 N
FS = 1000.0
SETTINGS = SpectralSettings(block=4096, window="hann", overlap=0.5)
BAND = (2.0, 80.0)


@numba.njit(cache=True)
def _simulate(f, a1, fs, m, d, k, b):  # pragma: no cover - compiled
    """Body acceleration at every sample of m·ẍ2 + d·ż + k·z + b·z³ = f (z = x2 - x1).

    RK4 with f and ẍ1 linear between samples: call it at a rate well above the
    signals' band (the caller samples 10× finer and keeps every 10th sample).
    """
    h = 1.0 / fs
    y = v = x1 = v1 = 0.0
    out = np.empty(f.size)
    out[0] = f[0] / m
    for i in range(f.size - 1):
        f0, f1, a0, a1e = f[i], f[i + 1], a1[i], a1[i + 1]
        fm, am = 0.5 * (f0 + f1), 0.5 * (a0 + a1e)
        xm = x1 + 0.5 * h * v1 + h * h * (a0 / 6 + am / 12)           # spindle at mid-step (linear ẍ1)
        vm = v1 + 0.25 * h * (a0 + am)
        xe = x1 + h * v1 + h * h * (a0 / 3 + a1e / 6)
        ve = v1 + 0.5 * h * (a0 + a1e)
        k1 = (f0 - d * (v - v1) - k * (y - x1) - b * (y - x1) ** 3) / m
        y2, v2 = y + 0.5 * h * v, v + 0.5 * h * k1
        k2 = (fm - d * (v2 - vm) - k * (y2 - xm) - b * (y2 - xm) ** 3) / m
        y3, v3 = y + 0.5 * h * v2, v + 0.5 * h * k2
        k3 = (fm - d * (v3 - vm) - k * (y3 - xm) - b * (y3 - xm) ** 3) / m
        y4, v4 = y + h * v3, v + h * k3
        k4 = (f1 - d * (v4 - ve) - k * (y4 - xe) - b * (y4 - xe) ** 3) / m
        y += h / 6 * (v + 2 * v2 + 2 * v3 + v4)
        v += h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x1, v1 = xe, ve
        out[i + 1] = (f1 - d * (v - v1) - k * (y - x1) - b * (y - x1) ** 3) / m
    return out


def _forced(seed: int, *, force_rms: float, spindle_rms: float = 0.0, seconds: float = 120.0,
            b3: float = B3, over: int = 10) -> Record:
    rng = np.random.default_rng(seed)
    n = int(seconds * FS) * over
    sos = butter(4, [1.0, 100.0], "bandpass", fs=FS * over, output="sos")
    f = sosfiltfilt(sos, rng.standard_normal(n))
    f *= force_rms / f.std()
    a1 = np.zeros(n)
    if spindle_rms:
        a1 = sosfiltfilt(sos, rng.standard_normal(n))
        a1 *= spindle_rms / a1.std()
    a2 = _simulate(f, a1, FS * over, M, D, K, b3)
    keep = slice(0, n, over)   # the signals are band-limited far below FS/2: plain down-sampling
    return Record(FS, a1[keep] if spindle_rms else None, a2[keep], force=f[keep], source=f"forced seed {seed}")


@pytest.fixture(scope="module")
def fixed_rec() -> Record:
    return _forced(1, force_rms=40.0)


# ---------------------------------------------------------------------------------------------
# the estimator
# ---------------------------------------------------------------------------------------------
def test_fixed_spindle_record_has_zero_spindle_and_needs_a_force():
    r = Record(100.0, None, np.ones(8), force=np.zeros(8))
    assert r.spindle_fixed and not r.spindle_accel.any() and r.has_force
    assert r.slice(2, 6).spindle_fixed and r.slice(2, 6).force.size == 4
    with pytest.raises(InputError, match="fixed spindle needs a measured force"):
        Record(100.0, None, np.ones(8))


def test_fixed_spindle_drops_the_spindle_column_and_gives_mass_stiffness_damping(fixed_rec):
    with warnings.catch_warnings():
        warnings.simplefilter("error", IllConditionedWarning)   # the zero spindle column is not inverted
        lin = identify_nifo(fixed_rec, [], settings=SETTINGS, analysis_band_hz=BAND)
    assert lin.spindle_fixed and np.isnan(lin.partial_coherence[0]).all()
    assert np.all(np.isfinite(lin.cond[lin.in_band])) and np.median(lin.cond[lin.in_band]) < 10
    res = identify_nifo(fixed_rec, [make_term("cubic")], settings=SETTINGS, analysis_band_hz=BAND,
                        on_ill_conditioned="ignore")
    m2, k2, c2, misfit = res.static.one_mass
    print(f"M2 {m2:.4g} kg (true {M}), K2 {k2:.4g} N/m (true {K:.4g}), C2 {c2:.4g} (true {D:.4g}), "
          f"c {res.static.c[0]:.4g} N/m³ (true {B3:.3g}); linear-only K2 {lin.static.one_mass[1]:.4g}")
    assert m2 == pytest.approx(M, rel=0.02)
    assert k2 == pytest.approx(K, rel=0.03)
    assert c2 == pytest.approx(D, rel=0.10)
    assert res.static.c[0] == pytest.approx(B3, rel=0.05)
    assert res.static.c_over_m2[0] == pytest.approx(B3 / M, rel=0.06)
    # the linear-only fit is the equivalent linearisation: stiffer than the nominal K2
    assert lin.static.one_mass[1] > 1.05 * K
    # T2F per line is the one-mass body's X2/F near resonance
    w = 2 * np.pi * res.freq_hz
    t2f_true = 1 / (-w**2 * M + K + 1j * w * D)
    sel = (res.freq_hz > 10) & (res.freq_hz < 30)
    assert np.median(np.abs(res.static.t2f[sel] / t2f_true[sel] - 1)) < 0.05


def test_moving_spindle_and_force_both_enter():
    rec = _forced(2, force_rms=30.0, spindle_rms=20.0)
    res = identify_nifo(rec, [make_term("cubic")], settings=SETTINGS, analysis_band_hz=BAND,
                        on_ill_conditioned="ignore")
    assert not res.spindle_fixed and res.t2f is not None
    assert res.static.m2 == pytest.approx(M, rel=0.05)
    assert res.static.c[0] == pytest.approx(B3, rel=0.08)
    # without the force the output-only fit misreads the forced response
    blind = identify_nifo(rec, [make_term("cubic")], settings=SETTINGS, analysis_band_hz=BAND, use_force=False,
                          on_ill_conditioned="ignore")
    err_blind = abs(blind.static.c_over_m2[0] / (B3 / M) - 1)
    err = abs(res.static.c_over_m2[0] / (B3 / M) - 1)
    print(f"c/M2 error with the force {100 * err:.2f} %, without {100 * err_blind:.1f} %")
    assert err_blind > 0.1 and err_blind > 5 * err


def test_force_result_round_trips_through_json(fixed_rec):
    from nifo_core.nifo.identify import NifoResult
    res = identify_nifo(fixed_rec, [make_term("cubic")], settings=SETTINGS, analysis_band_hz=BAND,
                        on_ill_conditioned="ignore")
    back = NifoResult.from_dict(json.loads(json.dumps(res.to_dict())))
    assert back.spindle_fixed and np.allclose(back.t2f, res.t2f, equal_nan=True)
    assert np.allclose(back.static.one_mass, res.static.one_mass) and np.allclose(back.static.c, res.static.c)


def test_mixed_records_and_missing_force_are_refused(fixed_rec):
    moving = _forced(3, force_rms=30.0, spindle_rms=20.0, seconds=30.0)
    with pytest.raises(InputError, match="fixed spindle and some a measured one"):
        identify_nifo([fixed_rec, moving], [], settings=SETTINGS)
    plain = Record(FS, moving.spindle_accel, moving.body_accel)
    with pytest.raises(InputError, match="force in every record"):
        identify_nifo([moving, plain], [], settings=SETTINGS, use_force=True)


# ---------------------------------------------------------------------------------------------
# prediction and characterization with the force
# ---------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_identified_forced_model_predicts_a_held_out_level(fixed_rec):
    res = identify_nifo(fixed_rec, [make_term("cubic")], settings=SETTINGS, analysis_band_hz=BAND,
                        on_ill_conditioned="ignore")
    lin = identify_nifo(fixed_rec, [], settings=SETTINGS, analysis_band_hz=BAND)
    for level in (20.0, 60.0):                                # other seeds, half and 1.5 times the level
        held = _forced(7, force_rms=level, seconds=40.0)
        out = {}
        for name, r in (("cubic", res), ("linear", lin)):
            model = IdentifiedModel.from_nifo(r)
            if name == "cubic":
                assert model.force_gain == pytest.approx(1 / M, rel=0.01)
            p = predict_body(model, None, FS, force=held.force)
            v = p.valid
            y = held.body_accel[v]
            out[name] = 100 * np.mean((y - p.body_accel[v]) ** 2) / np.var(y)
        print(f"{level:g} N held-out NMSE: cubic {out['cubic']:.3f} %, linear {out['linear']:.2f} %")
        assert out["cubic"] < 1.0 and out["cubic"] < out["linear"] / 20


def test_loop_coefficients_are_named_after_their_columns_with_a_measured_force(fixed_rec):
    """The force is a column of the equation-error fit between c and the terms: each reported coefficient is the
    one its name says (the cubic per kg is B3/M; the force column's coefficient is -1/M)."""
    from nifo_core.loop import LoopSettings, close_loop

    res = close_loop([fixed_rec], ["cubic_stiffness"], band=IntegrationBand(0.5, 150.0),
                     settings=LoopSettings(max_rounds=1, refine=False, prediction="none"))
    got = {d["name"]: d for d in res.coefficients()}
    assert got["k = K2/M2"]["value"] == pytest.approx(K / M, rel=0.05)
    assert got["c = C2/M2"]["value"] == pytest.approx(D / M, rel=0.1)
    assert got["-1/M2 (force column)"]["value"] == pytest.approx(-1 / M, rel=0.05)
    cubic = next(d for n, d in got.items() if n.startswith("cubic"))
    assert cubic["value"] == pytest.approx(B3 / M, rel=0.05)
    assert got["-1/M2 (force column)"]["value_times_m2"] is None


def test_a_model_predicts_a_record_at_a_quarter_of_its_identification_rate(fixed_rec):
    """The model is continuous-time: a record at another rate (a benchmark's test record often is) is predicted on
    the fine step the model was identified with, as well as at the identification rate."""
    from nifo_core.predict.model import fine_factor

    model = IdentifiedModel.from_nifo(identify_nifo(fixed_rec, [make_term("cubic")], settings=SETTINGS,
                                                    analysis_band_hz=BAND, on_ill_conditioned="ignore"))
    held = _forced(7, force_rms=40.0, seconds=40.0)       # band-limited to 100 Hz: every 4th sample is exact
    got = {}
    for q in (1, 4):
        p = predict_body(model, None, FS / q, force=held.force[::q])
        y = held.body_accel[::q][p.valid]
        got[q] = 100 * np.mean((y - p.body_accel[p.valid]) ** 2) / np.var(y)
    print(f"held-out NMSE at {FS:g} Hz {got[1]:.4f} %, at {FS / 4:g} Hz {got[4]:.4f} %")
    assert fine_factor(FS / 4, FS) == 4 * fine_factor(FS, FS)
    assert got[4] < 1.0 and got[4] < 1.5 * got[1] + 0.02


def test_characterize_takes_the_force_as_a_linear_column(fixed_rec):
    ch = characterize(fixed_rec, band=IntegrationBand(1.0, 200.0), kinds=("cubic_stiffness", "coulomb",
                                                                          "quadratic_damping"))
    assert ch.linear["m2_from_force_kg"] == pytest.approx(M, rel=0.05)
    assert ch.candidates[0].term.kind == "cubic_stiffness"


# ---------------------------------------------------------------------------------------------
# readers and data options
# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def short_rec() -> Record:
    return _forced(5, force_rms=20.0, spindle_rms=5.0, seconds=6.0)


@pytest.mark.parametrize("name", ["r.csv", "r.mat", "r.mcap", "bagdir"])
def test_force_round_trips_through_every_format(tmp_path, short_rec, name):
    back = load_record(save_record(tmp_path / name, short_rec))
    assert np.array_equal(back.force, short_rec.force) and np.array_equal(back.body_accel, short_rec.body_accel)
    if name in ("r.mcap", "bagdir"):
        assert back.meta["topics"]["force"] == "/nifo/force"


def test_bag_chunks_skip_the_start(tmp_path, short_rec):
    path = save_record(tmp_path / "r.mcap", short_rec)
    chunks = list(iter_record_chunks(path, chunk_samples=1000, skip_seconds=1.5))
    f = np.concatenate([c.force for c in chunks])
    assert np.array_equal(f, short_rec.force[1500:])
    assert chunks[0].meta["chunk"]["total_samples"] == short_rec.n - 1500


def test_csv_fixed_spindle_and_skip_seconds(tmp_path, short_rec):
    p = tmp_path / "shaker.csv"
    t = np.arange(short_rec.n) / FS
    np.savetxt(p, np.column_stack([t, short_rec.body_accel, short_rec.force]), delimiter=",",
               header="t,acc,load_cell", comments="")
    r = load_record(p, columns={"time": "t", "body_accel": "acc", "force": "load_cell", "spindle_accel": "fixed"},
                    skip_seconds=2.0)
    assert r.spindle_fixed and r.n == short_rec.n - 2000 and r.meta["skipped_samples"] == 2000
    assert np.array_equal(r.force, short_rec.force[2000:])
    with pytest.raises(ConfigError, match="fixed spindle needs a measured force"):
        load_record(p, columns={"time": "t", "body_accel": "acc", "spindle_accel": "fixed"})


def _periodic(tmp_path):
    """Two MAT files like the Silverbox's: input and displacement output, 6 periods of 512 samples."""
    fs, per, nper = 1000.0, 512, 6
    rng = np.random.default_rng(4)
    spec = np.zeros(per // 2 + 1, complex)
    spec[1:60] = np.exp(2j * np.pi * rng.random(59))
    u1 = np.fft.irfft(spec, per)
    w = 2 * np.pi * np.fft.rfftfreq(per, 1 / fs)
    y1 = np.fft.irfft(spec / (K - w**2 * M + 1j * w * D), per)
    scipy.io.savemat(tmp_path / "x_um_7.mat", {"um": np.tile(u1, nper)[:, None], "fs": np.float64(fs)})
    scipy.io.savemat(tmp_path / "x_ym_7.mat", {"ym": np.tile(y1, nper)[:, None]})
    return fs, per, u1, y1


def test_channels_from_two_mat_files_displacement_and_skipped_periods(tmp_path):
    fs, per, u1, y1 = _periodic(tmp_path)
    cols = {"force": "um@{name:_ym_=_um_}", "body_disp": "ym", "spindle_accel": "fixed"}
    r = load_record(tmp_path / "x_ym_7.mat", columns=cols, skip_periods=2, period_samples=per)
    assert r.fs_hz == fs and r.n == 4 * per and r.spindle_fixed
    assert np.allclose(r.force, np.tile(u1, 4))
    w = 2 * np.pi * np.fft.rfftfreq(per, 1 / fs)
    a1 = np.fft.irfft(-(w**2) * np.fft.rfft(y1), per)
    assert np.max(np.abs(r.body_accel - np.tile(a1, 4))) < 1e-9 * np.max(np.abs(a1))   # exact for whole periods
    assert "exact" in r.meta["body_from_displacement"]
    # the same through the explicit file name
    r2 = load_record(tmp_path / "x_ym_7.mat", columns={**cols, "force": "um@x_um_7.mat"}, skip_periods=2,
                     period_samples=per)
    assert np.array_equal(r2.force, r.force)


def test_finite_differences_without_whole_periods():
    fs = 1000.0
    t = np.arange(3000) / fs
    x = np.sin(2 * np.pi * 37 * t)
    a, how = acceleration_from_displacement(x, fs)
    assert "differences" in how
    assert np.max(np.abs(a[2:-2] + (2 * np.pi * 37) ** 2 * x[2:-2])) < 1e-3 * (2 * np.pi * 37) ** 2


def test_data_option_errors_are_one_line_naming_file_and_fix(tmp_path):
    fs, per, *_ = _periodic(tmp_path)
    ym = tmp_path / "x_ym_7.mat"
    with pytest.raises(DataFileError) as e:
        load_record(ym, columns={"force": "um@nope.mat", "body_disp": "ym", "spindle_accel": "fixed"})
    assert "x_ym_7.mat" in str(e.value) and "nope.mat" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(ConfigError, match="--period-samples"):
        load_record(ym, columns={"force": "um@x_um_7.mat", "body_disp": "ym", "spindle_accel": "fixed"},
                    skip_periods=1)
    with pytest.raises(RecordTooShortError, match="leaves nothing"):
        load_record(ym, columns={"force": "um@x_um_7.mat", "body_disp": "ym", "spindle_accel": "fixed"},
                    skip_periods=6, period_samples=per)
    scipy.io.savemat(tmp_path / "short_um.mat", {"um": np.linspace(-1.0, 1.0, 100)[:, None], "fs": np.float64(fs)})
    with pytest.raises(TimestampError, match="100 samples but the record has"):
        load_record(ym, columns={"force": "um@short_um.mat", "body_disp": "ym", "spindle_accel": "fixed"})
    with pytest.raises(ConfigError, match="does not occur"):
        load_record(ym, columns={"force": "um@{name:_zz_=_um_}", "body_disp": "ym", "spindle_accel": "fixed"})


@pytest.mark.slow
def test_cli_identify_and_predict_a_forced_record(tmp_path, fixed_rec):
    save_record(tmp_path / "id.csv", fixed_rec.slice(0, 60000))
    held = _forced(8, force_rms=60.0, seconds=30.0)
    save_record(tmp_path / "held.csv", held)
    (tmp_path / "m.yaml").write_text("nifo_model: 1\nnonlinearities:\n  - {kind: cubic_stiffness}\n"
                                     "settings: {block: 4096, overlap: 0.5, window: hann, freq_range_hz: [2, 80]}\n")
    cols = "time=time,body_accel=body_accel,force=force,spindle_accel=fixed"
    assert nifo_main(["identify", str(tmp_path / "id.csv"), "--model", str(tmp_path / "m.yaml"), "--out",
                      str(tmp_path / "id"), "--columns", cols, "--no-plots", "--quiet"]) == 0
    doc = json.loads((tmp_path / "id" / "identify.json").read_text())
    assert doc["summary"]["force"]["m2_kg"] == pytest.approx(M, rel=0.03)
    assert (tmp_path / "id" / "model.json").is_file()
    assert nifo_main(["predict", str(tmp_path / "held.csv"), "--model", str(tmp_path / "id" / "model.json"),
                      "--out", str(tmp_path / "pr"), "--columns", cols, "--no-plots"]) == 0
    pred = json.loads(next((tmp_path / "pr").glob("*.json")).read_text())
    text = json.dumps(pred)
    assert "nmse_percent" in text
