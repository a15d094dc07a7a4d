"""The shared contracts: Record validation, time bases, atomic outputs, model files, the CLI shell."""

import subprocess
import sys

import numpy as np
import pytest

from nifo.io.atomic import staged_dir, staged_file
from nifo.io.modelfile import load_model_spec, write_model_spec
from nifo_core.kinds.describing import Term
from nifo_core.errors import (ConfigError, DataFileError, InputError, NifoError, NonFiniteError,
                              RecordTooShortError, SampleRateError, TimestampError)
from nifo_core.signal.record import Record
from nifo_core.signal.timebase import check_common_rate, sample_rate_from_stamps
from nifo_core.simulate.vehicle import QuarterCar


def test_error_message_is_one_line_naming_file_channel_and_fix():
    err = NonFiniteError("3 samples are NaN", source="run.mcap", channel="/body/imu", hint="cut them out")
    assert str(err) == "run.mcap: /body/imu: 3 samples are NaN. Fix: cut them out"
    assert isinstance(err, ValueError) and err.exit_code == 5
    assert len({c.exit_code for c in (InputError, DataFileError, NonFiniteError, TimestampError,
                                       SampleRateError, RecordTooShortError, ConfigError)}) == 7


def test_record_is_read_only_and_rejects_nan_with_time_of_first_bad_sample():
    a = np.zeros(600)
    r = Record(600.0, a, a.copy(), source="x.csv")
    with pytest.raises(ValueError):
        r.body_accel[0] = 1.0
    b = a.copy()
    b[300] = np.nan
    with pytest.raises(NonFiniteError, match=r"x.csv: body_accel: 1 samples are NaN.*t=0.500 s"):
        Record(600.0, a, b, source="x.csv")
    with pytest.raises(InputError, match="different lengths"):
        Record(600.0, a, a[:-1])


def test_record_slice_shifts_stamp_and_require_samples_explains():
    r = Record(100.0, np.arange(1000.0), np.arange(1000.0), t0_ns=5)
    s = r.slice(100, 200)
    assert s.n == 100 and s.t0_ns == 5 + 1_000_000_000 and s.spindle_accel[0] == 100
    with pytest.raises(RecordTooShortError, match="too short for one spectral block"):
        s.require_samples(6144, what="one spectral block")


def test_timebase_finds_rate_and_names_gaps_and_reversals():
    t = np.arange(1000, dtype=np.int64) * 1_666_667
    assert sample_rate_from_stamps(t, source="f", channel="c") == pytest.approx(600.0, rel=1e-6)
    with pytest.raises(TimestampError, match="not increasing at sample 11"):
        sample_rate_from_stamps(np.r_[t[:11], t[9:]], source="f", channel="c")
    with pytest.raises(TimestampError, match="not uniform"):
        sample_rate_from_stamps(np.r_[t[:500], t[520:]], source="f", channel="c")
    with pytest.raises(SampleRateError, match="different rates"):
        check_common_rate({"a": 600.0, "b": 500.0}, source="f")


def test_quarter_car_transfer_functions_are_consistent():
    q = QuarterCar()
    f = np.linspace(0.5, 40, 50)
    np.testing.assert_allclose(q.t2b(f), q.t1b(f) * q.t21(f))
    fb, fw = q.natural_frequencies_hz()
    assert 1.0 < fb < 1.8 and 10 < fw < 15
    np.testing.assert_allclose(q.t21([0.0]), 1.0)
    with pytest.raises(ConfigError, match="m2"):
        QuarterCar(m2=-1)


def test_staged_outputs_appear_only_on_success(tmp_path):
    out = tmp_path / "res"
    with pytest.raises(RuntimeError):
        with staged_dir(out) as d:
            (d / "a.json").write_text("{}")
            raise RuntimeError("boom")
    assert not out.exists() and list(tmp_path.iterdir()) == []
    with staged_dir(out) as d:
        (d / "a.json").write_text("{}")
    with staged_dir(out) as d:  # replaces, never merges
        (d / "b.json").write_text("{}")
    assert sorted(p.name for p in out.iterdir()) == [".nifo-output", "b.json"]   # with nifo's marker
    f = tmp_path / "x.txt"
    with pytest.raises(RuntimeError):
        with staged_file(f) as p:
            p.write_text("half")
            raise RuntimeError
    assert not f.exists() and sorted(tmp_path.iterdir()) == [out]


def test_model_file_round_trip_and_errors_name_the_entry(tmp_path):
    terms = [Term("velocity_deadzone", {"knee": 0.03}), Term("backlash", {"deadband": 4.3e-4})]
    p = write_model_spec(tmp_path / "m.yaml", terms, settings={"block": 4096})
    spec = load_model_spec(p)
    assert spec.terms == tuple(terms) and spec.settings == {"block": 4096} and not spec.two_step
    bad = tmp_path / "bad.yaml"
    bad.write_text("nifo_model: 1\nnonlinearities:\n  - kind: velocity_deadzone\n  - kind: clearence\n")
    with pytest.raises(ConfigError, match=r"nonlinearities\[0\]: velocity_deadzone needs parameter 'knee'"):
        load_model_spec(bad)
    bad.write_text("nifo_model: 1\nnonlinearities:\n  - kind: clearence\n")
    with pytest.raises(ConfigError, match="unknown nonlinearity kind 'clearence'"):
        load_model_spec(bad)
    bad.write_text("steps:\n - nonlinearities: [{backlash: {deadband: 0.0004}}]\n   data: low.mcap\n"
                   " - nonlinearities: [{velocity_deadzone: {knee: 0.03}}]\n   data: [high.mcap]\n")
    spec = load_model_spec(bad)
    assert spec.two_step and spec.steps[0].data == (tmp_path / "low.mcap",)
    with pytest.raises(DataFileError, match="model file not found"):
        load_model_spec(tmp_path / "nope.yaml")


def test_nifo_help_lists_commands_with_descriptions():
    out = subprocess.run([sys.executable, "-m", "nifo", "--help"], capture_output=True, text=True, check=True)
    assert "commands:" in out.stdout and "Exit codes" in out.stdout
