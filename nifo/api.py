"""nifo for scripts: an identified model loaded from a results folder, simulated, and its strut's force law.

::

    import nifo

    model = nifo.Model.load("results")                # a folder nifo run / loop / identify wrote, or a model.json
    rec = nifo.load_record("bags/sample/road_1mm")    # bag, MCAP, CSV or MAT (the CLI's options: columns=..., ...)
    sim = model.predict(rec)                          # as nifo predict drives it: sim.output, body acceleration, z, ż
    sim = model.simulate(rec.spindle_accel, fs_hz=rec.fs_hz)   # any input signal, at any sample rate
    law = model.force_law()                           # force against deflection and velocity, each term, total
    t21 = model.transmissibility([2.0, 5.0, 10.0])    # nominal linear spindle→body transmissibility
    model.validity                                    # band and measured range it was identified on

:meth:`Model.simulate` is the engine ``nifo predict`` runs (:func:`nifo_core.predict.model.predict_body`: the
linear part in continuous time, so any sample rate, with the strut's forces fed back); :meth:`Model.predict` drives it
with a record's inputs as ``nifo predict`` does and gives its predicted signal to the last digit. :meth:`Model.force_law` is what ``nifo export`` writes as
tables and the report draws (:mod:`nifo_core.predict.force_law`); forces are per kg of the body mass M2 unless the
mass is known (a measured force on the body gives it; or ``mass_kg=``).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from nifo.io.loader import load_record
from nifo.io.results import MODEL_JSON, read_json, read_model
from nifo.io.truth import truth_for
from nifo.plots.restoring import term_words
from nifo_core.errors import ConfigError, DataFileError
from nifo_core.predict.force_law import (Characteristic, characteristic, force_law_bounds, strut_law, truth_law)
from nifo_core.predict.model import IdentifiedModel, predict_body, record_inputs
from nifo_core.predict.output_signal import output_name, predicted_output
from nifo_core.predict.periodic import predicts_periodic, record_periodic_response
from nifo_core.signal.record import Record

__all__ = ["Model", "Simulation", "ForceLaw", "Curve", "load_record", "find_model"]

#: the grid spans the measured range and this much beyond it on the wider side (marked as beyond it)
BEYOND = 0.25


def find_model(path: str | os.PathLike) -> Path:
    """The model.json of ``path``: the file itself, a folder holding one, or a ``nifo run`` results folder (its
    final model: ``loop/``, else ``identify/``)."""
    p = Path(path)
    if p.is_file():
        return p
    for cand in (p / MODEL_JSON, p / "loop" / MODEL_JSON, p / "identify" / MODEL_JSON):
        if cand.is_file():
            return cand
    raise DataFileError("no model.json here (nor in loop/ or identify/ below it)", source=str(p),
                        hint="give a folder nifo run, nifo loop or nifo identify wrote, or a model.json")


@dataclass(frozen=True, eq=False)
class Simulation:
    """A model's response to an input signal: body acceleration [m/s²], deflection z [m], velocity ż [m/s] on the
    input's samples (the deviation about the model's operating point); ``valid`` leaves out the start-up edges (the
    record's past is unknown). :meth:`Model.predict` also gives ``output``: the predicted signal as the record
    measured it (``output_name``: 'body_accel', or 'body_disp' for a displacement recorded on a force-driven mass),
    with the model's static part (offsets) and limited to the model's band when its prediction is — what
    ``nifo predict`` writes as ``<output>_model``."""

    fs_hz: float
    body_accel: np.ndarray
    z: np.ndarray
    zdot: np.ndarray
    valid: slice
    output: np.ndarray | None = None
    output_name: str | None = None

    @property
    def time_s(self) -> np.ndarray:
        return np.arange(self.body_accel.size) / self.fs_hz


@dataclass(frozen=True, eq=False)
class Curve:
    """The force against one variable: its grid, its branches (:class:`~nifo_core.predict.force_law.Characteristic`:
    one, or a decreasing and an increasing branch for a play), their 95 % half-widths (None: not refined), the truth's
    (None: no truth file) and the measured range (None: not recorded)."""

    variable: str
    x: np.ndarray
    branches: tuple[Characteristic, ...]
    bounds: tuple[np.ndarray, ...] | None
    truth: tuple[Characteristic, ...] | None
    measured: tuple[float, float] | None

    @property
    def total(self) -> np.ndarray:
        """The total force of the first branch (the only one without a play)."""
        return self.branches[0].total

    @property
    def inside(self) -> np.ndarray:
        """Grid points within the measured range."""
        if self.measured is None:
            return np.zeros(self.x.size, bool)
        return (self.x >= self.measured[0]) & (self.x <= self.measured[1])

    def truth_error(self) -> float | None:
        """Largest difference of the total force from the truth within the measured range, relative to the truth's
        largest force there (every branch); None without truth or range."""
        if self.truth is None or not self.inside.any():
            return None
        m = self.inside
        err = max(float(np.max(np.abs(b.total[m] - t.total[m]))) for b, t in zip(self.branches, self.truth))
        ref = max(float(np.max(np.abs(t.total[m]))) for t in self.truth)
        return err / ref if ref > 0 else None


@dataclass(frozen=True, eq=False)
class ForceLaw:
    """The strut's force law (``Model.force_law``): ``deflection`` and ``velocity`` curves, the terms in words,
    the mass that scales the forces (None: per kg of M2) and the units."""

    deflection: Curve
    velocity: Curve
    term_names: tuple[str, ...]
    mass_kg: float | None
    units: Mapping[str, str]

    def curve(self, variable: str) -> Curve:
        return self.deflection if variable == "z" else self.velocity

    @property
    def scaled_by(self) -> str:
        """Which mass scales the forces, in words."""
        if self.mass_kg is not None:
            return f"forces in {self.units['force']}, for the body mass M2 = {self.mass_kg:.6g} kg"
        return ("forces per kg of the body mass M2: output-only data do not give the mass; multiply by M2 for the "
                "strut's force")

    def table(self, variable: str) -> tuple[list[str], list[list]]:
        """(header with units, rows) of one curve: the grid, whether it lies in the measured range, the branch, the
        linear part, each term, the total and its 95 % half-width — what ``nifo export`` writes as CSV."""
        c = self.curve(variable)
        u = self.units
        xname = f"deflection z [{u['z']}]" if variable == "z" else f"velocity ż [{u['zdot']}]"
        lin = "spring k·z" if variable == "z" else "damper c·ż"
        fu = u["force"]
        header = [xname, "within measured range", "branch"]
        has_lin = c.branches[0].linear is not None
        if has_lin:
            header.append(f"linear {lin} [{fu}]")
        header += [f"{name} [{fu}]" for name in self.term_names] + [f"total [{fu}]"]
        if c.bounds is not None:
            header.append(f"total 95 % half-width [{fu}]")
        rows = []
        inside = c.inside
        for j, b in enumerate(c.branches):
            for i in range(c.x.size):
                row = [float(c.x[i]), "yes" if inside[i] else "no",
                       {"any": "either", "decreasing": f"{variable} decreasing",
                        "increasing": f"{variable} increasing"}[b.branch]]
                if has_lin:
                    row.append(float(b.linear[i]))
                row += [float(v) for v in b.terms[:, i]] + [float(b.total[i])]
                if c.bounds is not None:
                    row.append(float(c.bounds[j][i]))
                rows.append(row)
        return header, rows


class Model:
    """An identified model (``model.json``), ready to simulate and to read its force law from.

    ``Model.load(path)``; ``model.identified`` is the core's
    :class:`~nifo_core.predict.model.IdentifiedModel`, ``model.linear`` the linear model identified beside it
    (None when not stored), ``model.document`` the whole model.json.
    """

    def __init__(self, identified: IdentifiedModel, *, linear: IdentifiedModel | None = None,
                 document: Mapping | None = None, path: Path | None = None) -> None:
        self.identified = identified
        self.linear = linear
        self.document = dict(document or {})
        self.path = path

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Model":
        """From a model.json, a folder holding one, or a ``nifo run`` results folder (its final model)."""
        p = find_model(path)
        identified, linear = read_model(p)
        return cls(identified, linear=linear, document=read_json(p, what="identified model"), path=p)

    def __repr__(self) -> str:
        terms = ", ".join(self.term_names) or "no nonlinear term"
        lo, hi = self.identified.analysis_band_hz
        return (f"<nifo.Model {self.path or ''}: {self.identified.linear.kind} linear part, {terms}; "
                f"identified over {lo:.3g}-{hi:.4g} Hz>")

    # ------------------------------------------------------------------ facts
    @property
    def units(self) -> str:
        """The signals' unit (m/s² for a vehicle; the ``--system`` unit otherwise)."""
        return str((self.identified.provenance.get("system") or {}).get("units", "m/s²"))

    @property
    def term_names(self) -> tuple[str, ...]:
        return tuple(term_words(t, units=self.units) for t in self.identified.terms)

    @property
    def mass_kg(self) -> float | None:
        """M2 [kg] when the data gave it (a measured force on the body), else None (forces per kg)."""
        g = self.identified.force_gain
        return 1.0 / g if g > 0 else None

    @property
    def validity(self) -> dict:
        """Where the model was identified: the analysis band [Hz] and what model.json's ``validity`` holds (the
        strut's measured range ``strut_range``: ``deflection_m``, ``velocity_m_s``, lowest and highest)."""
        return {"analysis_band_hz": list(self.identified.analysis_band_hz), **(self.document.get("validity") or {})}

    def truth(self) -> dict | None:
        """The simulator's truth (``<data>.truth.json`` beside a record the model was identified on), or None."""
        for path in _data_paths(self.identified.provenance):
            tp = truth_for(Path(path))
            if tp is not None:
                try:
                    return json.loads(tp.read_text())
                except (OSError, ValueError):
                    return None
        return None

    # ------------------------------------------------------------------ what it does
    def simulate(self, spindle_accel, fs_hz: float, *, force=None) -> Simulation:
        """The model driven by a spindle acceleration [m/s²] at ``fs_hz`` (any rate: the model is continuous-time),
        and a force on the body [N] for a model identified with one (``spindle_accel=None``: fixed spindle)."""
        pred = predict_body(self.identified, None if spindle_accel is None else np.asarray(spindle_accel, float),
                            float(fs_hz), force=None if force is None else np.asarray(force, float))
        return Simulation(float(fs_hz), pred.body_accel, pred.z, pred.zdot, pred.valid)

    def predict(self, record: Record, *, period_samples: int | None = None) -> Simulation:
        """:meth:`simulate` driven by a record's measured inputs about the model's operating point, and the predicted
        signal as measured (``output``: offsets included, as ``nifo predict`` writes it). A periodic record's
        ``period_samples``: after its first period the prediction is the model's periodic response when model.json
        says it predicts one (``periodic_response``), as ``nifo predict`` gives it."""
        m = self.identified
        a1, force = record_inputs(record, m)
        pred = predict_body(m, a1, record.fs_hz, force=force)
        if predicts_periodic(m, period_samples) and self.linear is not None:
            la1, lforce = record_inputs(record, self.linear)
            lin = predict_body(self.linear, la1, record.fs_hz, force=lforce)
            pred = record_periodic_response(m, record, pred, lin, period_samples=period_samples,
                                            start=period_samples, band_hz=m.analysis_band_hz)
        sim = Simulation(float(record.fs_hz), pred.body_accel, pred.z, pred.zdot, pred.valid)
        return replace(sim, output=predicted_output(m, record, pred), output_name=output_name(record))

    def transmissibility(self, freq_hz) -> np.ndarray:
        """The nominal linear spindle→body transmissibility T21(jω) of the model's linear part (complex)."""
        return self.identified.linear.t21(np.asarray(freq_hz, float))

    def force_law(self, *, deflection_m: Sequence[float] | None = None, velocity_m_s: Sequence[float] | None = None,
                  points: int = 201, mass_kg: float | None = None, bounds: bool = True,
                  truth: bool = True) -> ForceLaw:
        """The strut's force against deflection and against velocity (the other at zero): the linear part, each
        term and the total, on ``points`` values over the measured range and ``BEYOND`` of it past its wider end,
        symmetric about zero (or on the grids given), with 95 % bounds from the refinement's covariance and the
        simulator's truth where a truth file lies beside the data. Forces per kg of M2 unless the mass is known
        (``mass_kg``, or from a measured force)."""
        mass = mass_kg if mass_kg is not None else self.mass_kg
        scale = 1.0 if mass is None else float(mass)
        rng = (self.document.get("validity") or {}).get("strut_range") or {}
        law = strut_law(self.identified)
        tdoc = self.truth() if truth else None
        tlaw = truth_law(tdoc["vehicle"], tdoc.get("strut") or []) if tdoc and "vehicle" in tdoc else None
        curves = []
        for var, given, key in (("z", deflection_m, "deflection_m"), ("zdot", velocity_m_s, "velocity_m_s")):
            measured = tuple(float(v) for v in rng[key]) if key in rng else None
            x = np.asarray(given, float) if given is not None else _grid(measured, points, var)
            curves.append(Curve(var, x, characteristic(law, x, var, scale=scale),
                                force_law_bounds(self.identified, x, var, scale=scale) if bounds else None,
                                None if tlaw is None else characteristic(tlaw, x, var, scale=scale),
                                measured))
        u = self.units
        si = u == "m/s²"
        units = {"z": "m" if si else f"{u}·s²", "zdot": "m/s" if si else f"{u}·s",
                 "force": ("N" if mass is not None else "N per kg of M2") if si else
                 (f"{u} per unit of M2" if mass is None else f"{u}·kg")}
        return ForceLaw(curves[0], curves[1], self.term_names, mass, units)


def _grid(measured: tuple[float, float] | None, points: int, variable: str) -> np.ndarray:
    if measured is None:
        raise ConfigError(f"the model.json records no measured range of {'deflection' if variable == 'z' else 'velocity'}"
                          " (written by an older nifo)", hint="identify it again with this nifo, or give the grid")
    if points < 3:
        raise ConfigError(f"points={points} must be at least 3")
    top = (1 + BEYOND) * max(abs(measured[0]), abs(measured[1]))
    return np.linspace(-top, top, int(points) | 1)    # odd: zero is a grid point


def _data_paths(provenance: Mapping) -> list[str]:
    """The data files recorded in a model's provenance (identify's entries, per step for two-step models)."""
    data = provenance.get("data") or []
    if isinstance(data, Mapping):
        data = [e for s in data.get("steps", []) for e in s.get("data", [])]
    return [str(e["path"]) if isinstance(e, Mapping) else str(e) for e in data
            if isinstance(e, (Mapping, str)) and (not isinstance(e, Mapping) or "path" in e)]
