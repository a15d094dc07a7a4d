"""The export step (``nifo export MODEL --out DIR``): the identified strut in the forms other tools read.

MODEL is a model.json, a folder holding one, or a ``nifo run`` results folder (its final model). Writes, atomically
(the folder carries nifo's ownership marker), to DIR:

- ``force_deflection.csv``  the stiffness characteristic: strut force against deflection z (ż = 0) — the linear
  spring, each term, the total and its 95 % half-width — on a grid over the measured range and a quarter beyond it,
  each row marked within the measured range or not; a play's two branches of travel (z decreasing, z increasing)
  as rows of their own;
- ``force_velocity.csv``    the damping characteristic: strut force against velocity ż (z = 0), the same columns;
- ``linear_part.json``      the linear part as a state-space model and as transfer functions, with units: inputs
  the spindle acceleration and the strut's nonlinear force per kg of M2 (and a measured force on the body),
  outputs deflection, velocity and body acceleration;
- ``force_law.png``/``.svg`` the two characteristics drawn (bounds shaded, linear part dashed, truth dotted);
- ``export.json``           what was written, which mass scales the forces, the measured range, and where a
  simulator truth file lies beside the model's data, the total force's largest difference from it there.

The CSV files have one header row, with units, and plain numbers: they open in a spreadsheet. Forces are per kg of
the body mass M2 (output-only data do not give the mass) unless it is known: ``--m2 KG``, or a force measured on
the body. The measured range is model.json's ``validity.strut_range`` (written by ``nifo identify`` and
``nifo loop``); a model.json from before it is refused with what to do.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import scipy.signal

from nifo.api import ForceLaw, Model
from nifo.io.atomic import check_output, staged_dir
from nifo.io.results import write_json
from nifo.pipeline.options import ExportOptions
from nifo.plots.force_law import plot_force_law
from nifo.plots.writer import figure_batch
from nifo_core import __version__

__all__ = ["run_export", "linear_part_document", "FILES"]

#: the files ``nifo export`` writes, in the order it lists them
FILES = ("force_deflection.csv", "force_velocity.csv", "linear_part.json", "force_law.png", "force_law.svg",
         "export.json")


def _write_csv(path: Path, header: list[str], rows: list[list]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows([[format(v, ".10g") if isinstance(v, float) else v for v in row] for row in rows])


def _poly(p) -> np.ndarray:
    """Polynomial coefficients with the conversion's rounding (below 1e-12 of the largest) cleared, leading
    zeros dropped."""
    p = np.real_if_close(np.atleast_1d(np.asarray(p)), tol=1e6).astype(float)
    p = np.where(np.abs(p) < 1e-12 * np.max(np.abs(p), initial=0.0), 0.0, p)
    return np.trim_zeros(p, "f") if np.any(p) else np.zeros(1)


def linear_part_document(model: Model) -> dict:
    """The model's linear part (nominal: the terms carry their whole force) as real state-space matrices and as
    transfer functions in s, with the names and units of every input, state and output."""
    m = model.identified
    lin = m.linear
    a, b, c = (np.asarray(v, float) for v in lin.state_space())
    ka, kb = lin.absorbed          # the realised part holds the terms' linear part: take it out again
    if ka or kb:
        a = a - np.outer(b, ka * c + kb * (c @ a))
    n = a.shape[0]
    fg = float(m.force_gain)
    gains = [1.0, 1.0] + ([-fg] if fg > 0 else [])
    bmat = np.outer(b, gains)
    ca, cab = c @ a, float(c @ a @ b)
    cmat = np.vstack([c, ca, ca @ a])
    dmat = np.zeros((3, len(gains)))
    dmat[2] = np.array(gains) * cab
    dmat[2, 0] += 1.0                                 # ẍ2 = ẍ1 + z̈
    num, den = scipy.signal.ss2tf(a, b[:, None], c[None, :], np.zeros((1, 1)))
    num, den = _poly(num[0]), _poly(den)
    t21_num = _poly(np.polyadd(den, np.polymul(num, [1.0, 0.0, 0.0])))
    units = model.units
    si = units == "m/s²"
    zu, vu = ("m", "m/s") if si else (f"{units}·s²", f"{units}·s")
    per_kg = "N/kg" if si else f"{units} (force per unit M2)"
    inputs = [{"name": "spindle acceleration ẍ1", "unit": units},
              {"name": "the strut's nonlinear force per kg of M2, Σ γ_i·g_i(z, ż) (the terms of model.json; "
                       "force_deflection.csv and force_velocity.csv tabulate them)", "unit": per_kg}]
    if fg > 0:
        inputs.append({"name": f"force measured on the body (enters as -F/M2, M2 = {1 / fg:.6g} kg)", "unit": "N"})
    doc = {"nifo_export_linear_part": 1, "nifo_version": __version__, "kind": lin.kind,
           "reason": lin.reason,
           "equations": "dx/dt = A·x + B·u, y = C·x + D·u; z = x2 - x1 (body minus spindle); the nonlinear force "
                        "u[1] is fed back from y (z, ż) by the terms",
           "inputs": inputs,
           "states": ([{"name": "deflection z", "unit": zu}, {"name": "velocity ż", "unit": vu}]
                      if lin.kind == "body" else
                      [{"name": f"modal state {i + 1} (real modal form)", "unit": "-"} for i in range(n)]),
           "outputs": [{"name": "deflection z", "unit": zu}, {"name": "velocity ż", "unit": vu},
                       {"name": "body acceleration ẍ2", "unit": units}],
           "A": a.tolist(), "B": bmat.tolist(), "C": cmat.tolist(), "D": dmat.tolist(),
           "transfer_functions": {
               "Hz(s) = Z/U, U = ẍ1 + Σ γ_i·g_i": {"numerator": num.tolist(), "denominator": den.tolist(),
                                                   "unit": f"{zu} per {units}"},
               "T21(s) = X2/X1, the nominal linear spindle→body transmissibility": {
                   "numerator": t21_num.tolist(), "denominator": den.tolist(),
                   "unit": "-"}},
           "polynomials": "coefficients in descending powers of s [s in 1/s]",
           "poles_hz": sorted({round(float(abs(p) / (2 * np.pi)), 6) for p in lin.all_poles()})}
    if lin.kind == "body":
        bm = m.body
        doc["body"] = {"k = K2/M2": {"value": bm.k, "unit": "1/s² (N/m per kg)"},
                       "c = C2/M2": {"value": bm.c, "unit": "1/s (N·s/m per kg)"},
                       "k3 = K3/M2": {"value": bm.k3, "unit": "1/s²"}}
        if model.mass_kg is not None:
            doc["body"]["K2"] = {"value": bm.k * model.mass_kg, "unit": "N/m"}
            doc["body"]["C2"] = {"value": bm.c * model.mass_kg, "unit": "N·s/m"}
    if lin.paths is not None:
        doc["feedback_paths"] = ("this model sends each play/clearance/saturation term's force through its own linear "
                                 "path on these poles (model.json linear_part.paths); the matrices above are the "
                                 "path of the spindle input, which the terms share only approximately")
    return doc


def _summary_doc(model: Model, law: ForceLaw, args: ExportOptions) -> dict:
    curves = {"deflection": law.deflection, "velocity": law.velocity}
    return {"nifo_export": 1, "nifo_version": __version__, "model": str(model.path), "files": list(FILES),
            "terms": list(law.term_names), "forces": law.scaled_by, "mass_kg": law.mass_kg,
            "units": dict(law.units),
            "measured_range": {k: None if c.measured is None else list(c.measured) for k, c in curves.items()},
            "grid_points": int(args.points),
            "bounds": "95 % half-width of the total from the refinement's parameter covariance (first-order)"
                      if law.deflection.bounds is not None else "none: the model was not refined",
            "truth": {k: c.truth_error() for k, c in curves.items()} if law.deflection.truth is not None else None,
            "truth_note": "largest |total - truth| within the measured range over the truth's largest |force| there"}


def run_export(args: ExportOptions) -> dict:
    """``nifo export`` (module docstring): the files in ``args.out``; the command's summary."""
    check_output(args.out, reads=[args.model])   # refuse a file, a foreign folder or one holding the model first
    model = Model.load(args.model)
    law = model.force_law(points=args.points, mass_kg=args.m2)
    doc = _summary_doc(model, law, args)
    with staged_dir(args.out) as tmp, figure_batch():
        for name, var in (("force_deflection.csv", "z"), ("force_velocity.csv", "zdot")):
            _write_csv(tmp / name, *law.table(var))
        write_json(tmp / "linear_part.json", linear_part_document(model), atomic=False, indent=2)
        plot_force_law(tmp / "force_law.png", law, terms=True,
                       title=f"strut force law ({law.scaled_by.split(':')[0]})")
        write_json(tmp / "export.json", doc, atomic=False, indent=2)
    if not args.quiet:
        print(f"strut: linear {model.identified.linear.kind} part"
              + "".join(f" + {n}" for n in law.term_names) + f"; {law.scaled_by}")
        for key, c in (("deflection", law.deflection), ("velocity", law.velocity)):
            unit = law.units["z" if key == "deflection" else "zdot"]
            rng = "not recorded" if c.measured is None else f"{c.measured[0]:.4g} to {c.measured[1]:.4g} {unit}"
            err = c.truth_error()
            print(f"  {key}: measured {rng}" + ("" if err is None else f"; total within {100 * err:.2f} % of "
                                                                          "the simulator's truth there"))
        print(f"wrote {args.out}/ ({', '.join(FILES)})")
    return {"out": str(args.out), **{k: doc[k] for k in ("model", "files", "terms", "forces", "mass_kg",
                                                         "measured_range", "truth")}}
