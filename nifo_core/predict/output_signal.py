"""The predicted signal as the user measured it: in the output's unit, offset included (docs/method.md §10).

A model's simulation (:class:`~nifo_core.predict.time_prediction.Prediction`) is the deviation of the body
about its operating point, driven by the input's deviation (:func:`~nifo_core.predict.time_prediction.record_inputs`).
:func:`predicted_output` turns it into the signal the record measured — the body displacement when a
displacement was recorded on a single mass driven by a force (the prediction's z is then x2), else the body
acceleration — with the model's static part added (:class:`~nifo_core.predict.scope.Offsets`) and limited to the
model's band when its prediction is (:class:`~nifo_core.predict.scope.PredictionBand`). :func:`measured_output`
is the same signal as measured, to compare with.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..signal.band import band_limit

__all__ = ["MeasuredOutput", "measured_output", "output_name", "predicted_output", "dynamic_output",
           "common_mode"]


@dataclass(frozen=True)
class MeasuredOutput:
    """The output of a record as measured: ``name`` ('body_disp' or 'body_accel'), ``unit`` and ``values``."""

    name: str
    unit: str
    values: np.ndarray


def output_name(record) -> str:
    """'body_disp' when a displacement was recorded on a single mass driven by a force, else 'body_accel'."""
    return "body_disp" if getattr(record, "body_disp", None) is not None and record.spindle_fixed else "body_accel"


def measured_output(record) -> MeasuredOutput:
    """The record's output in the unit it was measured in."""
    if output_name(record) == "body_disp":
        return MeasuredOutput("body_disp", "unit of the measured displacement", np.asarray(record.body_disp, float))
    return MeasuredOutput("body_accel", "m/s²", np.asarray(record.body_accel, float))


def common_mode(record) -> float:
    """The spindle acceleration's mean, which passes to the body acceleration one to one (0 for a fixed spindle)."""
    return 0.0 if record.spindle_fixed else float(np.mean(record.spindle_accel))


def dynamic_output(model, record, prediction) -> np.ndarray:
    """The predicted deviation of the output (no static part), limited to the model's band when its prediction is."""
    y = np.asarray(prediction.z if output_name(record) == "body_disp" else prediction.body_accel, float)
    pb = getattr(model, "prediction_band", None)
    if pb is not None and pb.limited:
        y = band_limit(y, record.fs_hz, pb.band_hz)
    return y


def predicted_output(model, record, prediction) -> np.ndarray:
    """The predicted signal in the output's unit, the model's static part included (module docstring)."""
    y = dynamic_output(model, record, prediction)
    name = output_name(record)
    offsets = getattr(model, "offsets", None)
    # the output offset is in the unit of the output it was taken from: a record measuring the other one gets none
    static = float(offsets.output) if offsets is not None and offsets.output_name == name else 0.0
    if name == "body_accel":
        static += common_mode(record)
    return y + static
