"""The loop's settings (:mod:`nifo_core.loop.closing`).

:class:`LoopSettings` says how the loop traces, accepts and reports; beside it the loop's fixed values: the bands
of the per-band residual and the factor within which a declared term may be re-tuned.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ..characterize.automatic import DEFAULT_KINDS, Thresholds
from ..defaults import DEFAULT_ANALYSIS_BAND_HZ
from ..errors import ConfigError
from ..signal.spectral import SpectralSettings

__all__ = ["LoopSettings", "RESIDUAL_BANDS_HZ", "RETUNE_FACTOR"]

#: bands of the per-band residual [Hz]
RESIDUAL_BANDS_HZ = ((2.0, 5.0), (5.0, 10.0), (10.0, 20.0), (20.0, 30.0))
#: a declared term's key parameter (knee, gap, deadband...) may be re-tuned within this factor of its declared
#: value; beyond it, or with its coefficient's sign flipped against the declared model's fit, it is another
#: physics than the one declared, and the loop says so
RETUNE_FACTOR = 2.0

Prediction = Literal["model", "none"]
Structure = Literal["auto", "constant", "paths"]


@dataclass(frozen=True)
class LoopSettings:
    """How the loop traces, accepts and reports (module docstring).

    Parameters
    ----------
    max_rounds : int
        Most effects added (each round adds at most one).
    fit_fraction : float
        Leading fraction of every record used for fitting; the rest is held out.
    kinds : tuple of str
        Library kinds searched.
    thresholds : Thresholds
        Significance, ERR, cross-validation and stability thresholds (shared with characterize).
    grid_points : int
        Grid points per parameter.
    min_heldout_gain : float
        Relative fall of the held-out equation-error NMSE a candidate must bring.
    max_band_rise_db : float
        Most a candidate may raise any band of the held-out residual (prediction error and
        equation error) [dB]; besides, it must lower the held-out prediction NMSE when there is one.
    tire_quantile, tire_guard_s, max_tire_shift : float
        Tire check: samples with |ẍ1| above this quantile, ± guard [s], are left
        out in a refit; the coefficient may move by at most ``max_tire_shift`` (relative).
    top_tried : int
        Candidates tried per round, in rank order, before "nothing significant".
    spectral : SpectralSettings
        For the per-band residual and the transmissibilities (paper Table 2 by default).
    analysis_band_hz : (float, float)
        Band of the transmissibility error and of NIFO.
    prediction : {'model', 'none'}
        ``'model'``: every term set is fitted as ``nifo identify`` fits it (:mod:`nifo_core.predict.model_fit`:
        NIFO on the fit parts, the linear part's form chosen by held-out prediction, constant
        coefficients or feedback paths) and its held-out body acceleration predicted from the
        measured input (spindle acceleration and/or force), simulated from rest
        (:mod:`nifo_core.predict.heldout`): the one metric. ``'none'``: equation error only.
    structure : {'auto', 'constant', 'paths'}
        Feedback structure of the predicting model (:func:`nifo_core.predict.model_fit.fit_model`).
    min_prediction_gain : float
        Relative fall of the held-out prediction NMSE a term must bring (on a rational linear part,
        where it is the only gate).
    max_record_rise : float
        A term may not make any record's held-out prediction worse by more than this (relative).
    path_widths : int
        On a rational linear part (a flexible body): widths tried per kind that can act through a
        feedback path (backlash, clearance, saturation), geometric over the relative motion.
    noise_correction : bool
        Remove the bias that noise on both sensors gives the equation-error fit and the final
        output-error refinement (errors in variables: :mod:`nifo_core.signal.bias_correction`,
        :mod:`nifo_core.predict.refine_bias`, with each record's noise estimated from its spectra,
        :mod:`nifo_core.signal.noise`); its uncertainty joins the coefficients' bounds.
    retune : bool
        Before each round, re-tune the parameter (gap, knee, eps...) of every term of the model
        over its grid (a key parameter within a factor 2 of its value) (declared terms state the form; the data set the parameter). Without it a
        declared term whose parameter does not match the band-limited motion leaves a residual
        that a second term of the same kind "explains".
    refine : bool
        After the rounds, refine the final model by output error (:func:`nifo_core.predict.refine.refine_model`:
        the coefficients, gaps/knees and a one-mass body's k, c that make it predict the fit parts
        best) and keep the refined model when its held-out prediction NMSE is not worse. A final
        step: the acceptance of terms does not use it.
    refine_seconds : float
        Leading seconds of each fit part the refinement simulates [s] (each iteration simulates
        every record once per parameter).
    """

    max_rounds: int = 4
    fit_fraction: float = 2.0 / 3.0
    kinds: tuple[str, ...] = DEFAULT_KINDS
    thresholds: Thresholds = field(default_factory=Thresholds)
    grid_points: int = 24
    min_heldout_gain: float = 0.01
    max_band_rise_db: float = 1.0
    tire_quantile: float = 0.995
    tire_guard_s: float = 0.1
    max_tire_shift: float = 0.5
    top_tried: int = 3
    spectral: SpectralSettings = field(default_factory=SpectralSettings)
    analysis_band_hz: tuple[float, float] = DEFAULT_ANALYSIS_BAND_HZ
    prediction: Prediction = "model"
    retune: bool = True
    refine: bool = True
    refine_seconds: float = 60.0
    structure: Structure = "auto"
    min_prediction_gain: float = 0.02
    max_record_rise: float = 0.05
    path_widths: int = 8
    noise_correction: bool = True

    def __post_init__(self) -> None:
        if isinstance(self.max_rounds, bool) or not isinstance(self.max_rounds, (int, np.integer)) \
                or not 1 <= self.max_rounds <= 10:
            raise ConfigError(f"max_rounds={self.max_rounds!r} must be a whole number in 1..10")
        if not 0.3 <= float(self.fit_fraction) <= 0.9:
            raise ConfigError(f"fit_fraction={self.fit_fraction!r} must be in [0.3, 0.9]",
                              hint="e.g. 2/3: fit on the first two thirds, test on the last third")
        if not 0.5 < float(self.tire_quantile) < 1:
            raise ConfigError(f"tire_quantile={self.tire_quantile!r} must be in (0.5, 1)")
        for name in ("min_heldout_gain", "max_band_rise_db", "tire_guard_s", "max_tire_shift"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v >= 0):
                raise ConfigError(f"{name}={v!r} must be finite and non-negative")
        if self.top_tried < 1:
            raise ConfigError(f"top_tried={self.top_tried!r} must be at least 1")
        lo, hi = (float(v) for v in self.analysis_band_hz)
        if not 0 < lo < hi:
            raise ConfigError(f"analysis_band_hz={self.analysis_band_hz!r} must satisfy 0 < lo < hi")
        if not (np.isfinite(float(self.refine_seconds)) and float(self.refine_seconds) >= 5):
            raise ConfigError(f"refine_seconds={self.refine_seconds!r} must be at least 5 s")
        if self.prediction not in ("model", "none"):
            raise ConfigError(f"prediction={self.prediction!r} must be 'model' or 'none'")
        if self.structure not in ("auto", "constant", "paths"):
            raise ConfigError(f"structure={self.structure!r} must be 'auto', 'constant' or 'paths'")
        for name in ("min_prediction_gain", "max_record_rise"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and 0 <= v < 1):
                raise ConfigError(f"{name}={v!r} must be in [0, 1)")
        if isinstance(self.path_widths, bool) or not 2 <= int(self.path_widths) <= 32:
            raise ConfigError(f"path_widths={self.path_widths!r} must be a whole number in 2..32")
        object.__setattr__(self, "kinds", tuple(self.kinds))
        object.__setattr__(self, "analysis_band_hz", (lo, hi))

    def to_dict(self) -> dict:
        return {"max_rounds": int(self.max_rounds), "fit_fraction": float(self.fit_fraction),
                "kinds": list(self.kinds), "thresholds": self.thresholds.to_dict(),
                "grid_points": self.grid_points, "min_heldout_gain": self.min_heldout_gain,
                "max_band_rise_db": self.max_band_rise_db,
                "tire_quantile": self.tire_quantile, "tire_guard_s": self.tire_guard_s,
                "max_tire_shift": self.max_tire_shift, "top_tried": self.top_tried,
                "spectral": self.spectral.to_dict(), "analysis_band_hz": list(self.analysis_band_hz),
                "prediction": self.prediction, "retune": self.retune, "refine": self.refine,
                "refine_seconds": self.refine_seconds, "structure": self.structure,
                "min_prediction_gain": self.min_prediction_gain, "max_record_rise": self.max_record_rise,
                "path_widths": int(self.path_widths)}
