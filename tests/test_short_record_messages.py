"""A record too short to integrate is named in the error (issue 14: "too short to integrate" named no file)."""

from __future__ import annotations

import numpy as np
import pytest

from nifo_core.errors import RecordTooShortError
from nifo_core.signal.record import Record
from nifo_core.characterize.restoring import restoring_force


def test_a_record_too_short_to_integrate_is_named():
    rng = np.random.default_rng(0)
    rec = Record(1000.0, rng.standard_normal(100), rng.standard_normal(100), source="tiny_run.mcap")
    with pytest.raises(RecordTooShortError, match=r"^tiny_run\.mcap: a 0\.10 s record is too short to integrate"):
        restoring_force(rec)
