#!/usr/bin/env python
"""F-16 ground vibration test: does NIFO recover the low-level transmissibility from high-level data?

Data: Noël & Schoukens (2017), F-16 ground vibration test benchmark,
nonlinearbenchmark.org (``../shared/data/f16``). Accelerations on both sides
of the nonlinear wing-payload interface: row 1 (wing) plays the spindle,
row 2 (payload) the body. Full-grid random-phase multisines 2-15 Hz,
9 periods × 8192 samples at 400 Hz; the first period is transient.

What is compared (4-10 Hz, the lines around the bending and torsion modes):
the NIFO estimate of the underlying linear transmissibility from high-level
data against the measured level-1 transmissibility (a practically linear
test), and the raw high-level transmissibility against the same. Level 1 is
never used to choose anything: terms come from the restoring-force
characterization of level 7 (``characterize_level``) or, for the clearance
gap, from the consistency of the NIFO T21 across the high levels
(``choose_gap``); both are reported.

Processing (everything through nifo_core's one spectral engine and NIFO):
- the multisine is periodic, so one block = one period (8192 samples) with a
  boxcar window and no overlap is leakage-free; the transient first period is
  dropped and the steady-state periods are periodically extended by the
  integrator's edge so the relative motion z, ż integrated for the describing
  functions covers exactly periods 2-9 (8 leakage-free blocks per level);
- integration band 1.5-40 Hz: the structure has no mode below 2 Hz (nothing
  like a body bounce to keep), the excitation starts at 2 Hz, and 40 Hz keeps
  the clearance's harmonics of the 2-15 Hz motion;
- metric: median over the 4-10 Hz lines of |T - T_L1|/|T_L1| (complex; this
  reproduces the ≈ 12 % quoted for raw level 7) and, beside it, of
  ||T|/|T_L1| - 1| (magnitude only).

Run: ``.venv/bin/python tools/f16_nifo.py [--data DIR] [--img docs/img] [--json out.json]``
(prints the table of docs/f16_nifo.md and writes the figures).
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nifo.io.loader import load_record  # noqa: E402
from nifo_core.kinds.describing import make_term  # noqa: E402
from nifo_core.signal.integrate import IntegrationBand, integrator_taps  # noqa: E402
from nifo_core.nifo.identify import identify_nifo  # noqa: E402
from nifo_core.signal.record import Record  # noqa: E402
from nifo_core.signal.frf import h1  # noqa: E402
from nifo_core.signal.spectral import SpectralSettings, cross_spectra  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "f16"
PERIOD = 8192
SETTINGS = SpectralSettings(block=PERIOD, overlap=0.0, window="boxcar")
BAND = IntegrationBand(1.5, 40.0)
ANALYSIS = (2.0, 15.0)
METRIC_HZ = (4.0, 10.0)
GAPS = (2e-5, 3e-5, 5e-5, 7e-5, 1e-4, 1.5e-4)
COLUMNS = {"spindle_accel": "Acceleration[1]", "body_accel": "Acceleration[2]", "fs": "Fs"}
#: the independent quick check quoted in the task (FullMSine, first period dropped)
REFERENCE = {"raw_l7": 0.12, "clearance_df": 0.066}


def load(level: int, data: Path = DATA) -> Record:
    return load_record(data / f"F16Data_FullMSine_Level{level}.mat", columns=COLUMNS)


def steady(rec: Record, band: IntegrationBand = BAND) -> Record:
    """Periods 2-9, periodically extended by the integrator's delay at both ends.

    :class:`StreamingNifo` drops the integrator's first ``delay`` outputs and
    never releases the last ``delay``: with the extension the samples that
    enter the spectra are exactly periods 2-9, each block one whole period.
    """
    d = (integrator_taps(rec.fs_hz, band)[0].size - 1) // 2

    def ext(x):
        x = np.asarray(x)[PERIOD:]
        if d > x.size:
            raise ValueError("integration band too low for this record")
        return np.concatenate([x[-d:], x, x[:d]]) if d else x
    return Record(rec.fs_hz, ext(rec.spindle_accel), ext(rec.body_accel), source=rec.source)


def measured_h1(rec: Record) -> tuple[np.ndarray, np.ndarray]:
    """Plain H1 wing→payload over periods 2-9 (leakage-free)."""
    spec = cross_spectra(np.stack([rec.spindle_accel[PERIOD:], rec.body_accel[PERIOD:]]), rec.fs_hz, SETTINGS)
    return spec.freq_hz, h1(spec, 0, 1)


def nifo(recs: list[Record], terms: list[dict], band: IntegrationBand = BAND):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return identify_nifo([steady(r, band) for r in recs], [make_term(t) for t in terms], settings=SETTINGS,
                             band=band, analysis_band_hz=ANALYSIS, on_ill_conditioned="ignore")


def differences(t: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """(complex, magnitude-only) median relative difference over ``mask``."""
    return (float(np.median(np.abs(t[mask] / ref[mask] - 1))),
            float(np.median(np.abs(np.abs(t[mask]) / np.abs(ref[mask]) - 1))))


def clearance(gap: float) -> list[dict]:
    return [{"kind": "clearance", "params": {"gap": gap}}]


def choose_gap(recs: dict[int, Record], mask: np.ndarray, band: IntegrationBand = BAND,
               gaps=GAPS) -> tuple[float, dict]:
    """The clearance gap whose NIFO T21 agrees best between pairs of high levels (3, 5, 7).

    A describing function that captures the interface gives the same nominal
    T21 whichever levels it is identified on; a wrong gap leaves a
    level-dependent part in it. Criterion: median over ``mask`` of the mean
    pairwise |T_a/T_b - 1| of the joint estimates on {3,5}, {3,7}, {5,7}.
    Uses the high levels only.
    """
    scores = {}
    for gap in gaps:
        ts = [nifo([recs[a], recs[b]], clearance(gap), band).t21 for a, b in ((3, 5), (3, 7), (5, 7))]
        pair = [np.abs(ts[i][mask] / ts[j][mask] - 1) for i, j in ((0, 1), (0, 2), (1, 2))]
        scores[gap] = float(np.median(np.mean(pair, axis=0)))
    return min(scores, key=scores.get), scores


def characterize_level(rec: Record, band: IntegrationBand = BAND) -> dict:
    """Restoring-force characterization (docs/method.md §5, :func:`nifo_core.characterize.automatic.characterize`) of one level.

    Returns the suggested terms and the best clearance gap among the candidates.
    """
    from nifo_core.characterize.automatic import characterize

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ch = characterize(Record(rec.fs_hz, rec.spindle_accel[PERIOD:], rec.body_accel[PERIOD:]), band=band)
    gap = next(c.term.params["gap"] for c in ch.candidates if c.term.kind == "clearance")
    return {"terms": [c.term.to_dict() for c in ch.suggested], "clearance_gap": float(gap),
            "ranking": [(c.term.label, c.status, float(c.err)) for c in ch.candidates[:5]]}


@dataclass
class Row:
    variant: str
    data: str
    estimate: str
    complex_diff: float
    magnitude_diff: float
    chosen_by: str = ""


def study(data: Path = DATA) -> dict:
    """All variants; returns the numbers (and the curves for the figures)."""
    recs = {lv: load(lv, data) for lv in (1, 3, 5, 7)}
    f, t1 = measured_h1(recs[1])
    mask = (f >= METRIC_HZ[0]) & (f <= METRIC_HZ[1])
    rows: list[Row] = []
    curves = {"f": f, "L1": t1}
    for lv in (3, 5, 7):
        _, t = measured_h1(recs[lv])
        curves[f"L{lv} raw"] = t
        rows.append(Row(f"raw level {lv} (plain H1)", f"L{lv}", "-", *differences(t, t1, mask)))
    gap, scores = choose_gap(recs, mask)
    # single high level (L7): each gap, pooled (quarter-car static form) and per-line estimates
    for g in GAPS:
        r7 = nifo([recs[7]], clearance(g))
        rows.append(Row(f"clearance gap {g:g} m", "L7", "pooled static", *differences(r7.static.t21, t1, mask)))
        rows.append(Row(f"clearance gap {g:g} m", "L7", "per line (Eq. 9)", *differences(r7.t21, t1, mask)))
    r7 = nifo([recs[7]], clearance(gap) + [{"kind": "coulomb", "params": {"eps": 0.002}}])
    rows.append(Row(f"clearance {gap:g} m + coulomb(eps 0.002)", "L7", "pooled static",
                    *differences(r7.static.t21, t1, mask)))
    rows.append(Row(f"clearance {gap:g} m + coulomb(eps 0.002)", "L7", "per line (Eq. 9)",
                    *differences(r7.t21, t1, mask)))
    asym = [{"kind": "bump_stop", "params": {"gap": gap, "side": "compression"}},
            {"kind": "bump_stop", "params": {"gap": gap, "side": "rebound"}}]
    ra = nifo([recs[7]], asym)
    rows.append(Row(f"asymmetric clearance: two one-sided stops at ±{gap:g} m", "L7", "pooled static",
                    *differences(ra.static.t21, t1, mask)))
    rows.append(Row(f"asymmetric clearance: two one-sided stops at ±{gap:g} m", "L7", "per line (Eq. 9)",
                    *differences(ra.t21, t1, mask)))
    # joint identification on several high levels (merged accumulators)
    for levels in ((5, 7), (3, 5, 7)):
        for g in GAPS:
            rj = nifo([recs[lv] for lv in levels], clearance(g))
            tag = "consistency of T21 across levels" if g == gap else ""
            name = "L" + "+L".join(map(str, levels))
            rows.append(Row(f"clearance gap {g:g} m", name, "per line (Eq. 9)", *differences(rj.t21, t1, mask), tag))
            rows.append(Row(f"clearance gap {g:g} m", name, "pooled static", *differences(rj.static.t21, t1, mask)))
            if levels == (3, 5, 7) and g == gap:
                curves["NIFO L3+L5+L7"] = rj.t21
                best_joint = rj
    # terms chosen by the restoring-force characterization of level 7 alone (nifo_core.characterize.automatic)
    char = characterize_level(recs[7])
    for label, terms in (("characterization: " + ", ".join(t["kind"] for t in char["terms"]), char["terms"]),
                         ("characterization's best clearance", clearance(char["clearance_gap"]))):
        desc = "; ".join(f"{t['kind']}({', '.join(f'{k}={v:.3g}' for k, v in t['params'].items())})" for t in terms)
        for levels in ((7,), (5, 7), (3, 5, 7)):
            rc = nifo([recs[lv] for lv in levels], terms)
            name = "L" + "+L".join(map(str, levels))
            rows.append(Row(f"{label}: {desc}", name, "per line (Eq. 9)", *differences(rc.t21, t1, mask),
                            "restoring force of L7"))
            rows.append(Row(f"{label}: {desc}", name, "pooled static", *differences(rc.static.t21, t1, mask)))
            if label.startswith("characterization:"):
                curves[f"NIFO char {name}"] = rc.t21
    # integration band sensitivity of the chosen variant
    for band in (IntegrationBand(1.0, 100.0), IntegrationBand(2.0, 60.0)):
        rb = nifo([recs[3], recs[5], recs[7]], clearance(gap), band)
        rows.append(Row(f"clearance gap {gap:g} m, integration band {band.f_lo_hz:g}-{band.f_hi_hz:g} Hz",
                        "L3+L5+L7", "per line (Eq. 9)", *differences(rb.t21, t1, mask)))
    r7s = nifo([recs[7]], clearance(gap))
    curves["NIFO L7"] = r7s.static.t21
    raw7 = differences(curves["L7 raw"], t1, mask)
    joint = differences(best_joint.t21, t1, mask)
    single = differences(r7s.static.t21, t1, mask)
    return {"rows": rows, "curves": curves, "mask": mask, "gap": gap, "gap_scores": scores, "characterization": char,
            "headline": {"raw_l7": raw7, "raw_l3": differences(curves["L3 raw"], t1, mask),
                         "nifo_l7_static_consistency_gap": single, "nifo_l357_consistency_gap": joint,
                         "nifo_l7_char": differences(curves["NIFO char L7"], t1, mask),
                         "nifo_l57_char": differences(curves["NIFO char L5+L7"], t1, mask),
                         "nifo_l357_char": differences(curves["NIFO char L3+L5+L7"], t1, mask)},
            "joint_cond_median": float(np.median(best_joint.cond[mask])),
            "l7_cond_median": float(np.median(r7s.cond[mask]))}


def figures(res: dict, img: Path) -> list[Path]:
    from nifo.plots.nifo import plot_transmissibility

    img.mkdir(parents=True, exist_ok=True)
    c, f = res["curves"], res["curves"]["f"]
    h = res["headline"]
    curves = [("level 1 measured (reference)", f, c["L1"], {"color": "k", "lw": 1.6}),
              (f"level 7 raw H1 ({100 * h['raw_l7'][0]:.1f} %)", f, c["L7 raw"], {"color": "C0", "lw": 1.0}),
              (f"NIFO on L7, clearance {res['gap']:g} m, pooled "
               f"({100 * h['nifo_l7_static_consistency_gap'][0]:.1f} %)", f,
               c["NIFO L7"], {"color": "C1", "lw": 1.0, "ls": "--"}),
              (f"NIFO on L7, characterized terms, per line ({100 * h['nifo_l7_char'][0]:.1f} %)", f,
               c["NIFO char L7"], {"color": "C2", "lw": 1.0, "ls": ":"}),
              (f"NIFO on L5+L7 merged, characterized terms ({100 * h['nifo_l57_char'][0]:.1f} %)", f,
               c["NIFO char L5+L7"], {"color": "C4", "lw": 1.0, "ls": "-."}),
              (f"NIFO on L3+L5+L7 merged, characterized terms ({100 * h['nifo_l357_char'][0]:.1f} %)", f,
               c["NIFO char L3+L5+L7"], {"color": "C3", "lw": 1.3, "ls": "--"})]
    p1 = plot_transmissibility(img / "f16_nifo_transmissibility.png", curves, band_hz=METRIC_HZ,
                               ylabel="|T| payload/wing",
                               title="F-16 wing→payload: level 1 vs level 7 raw vs NIFO underlying linear "
                                     "(median |T/T_L1 - 1| in 4-10 Hz)")
    from nifo.plots import pyplot, save_figure
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 3.4))
    m = (f >= 2) & (f <= 15)
    for key, style in (("L7 raw", {"color": "C0"}), ("NIFO L7", {"color": "C1", "ls": "--"}),
                       ("NIFO char L5+L7", {"color": "C4", "ls": "-."}),
                       ("NIFO char L3+L5+L7", {"color": "C3", "ls": "--"})):
        ax.semilogy(f[m], np.abs(c[key][m] / c["L1"][m] - 1), lw=0.9, label=key, **style)
    ax.axvspan(*METRIC_HZ, color="0.93", zorder=0)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("|T/T_L1 - 1|")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("relative difference from the level-1 transmissibility", fontsize=10)
    p2 = save_figure(fig, img / "f16_nifo_error.png")
    return [p1, p2]


def table(res: dict) -> str:
    out = ["| variant | data | estimate | complex diff | magnitude diff | note |", "|---|---|---|---:|---:|---|"]
    for r in res["rows"]:
        out.append(f"| {r.variant} | {r.data} | {r.estimate} | {100 * r.complex_diff:.1f} % | "
                   f"{100 * r.magnitude_diff:.1f} % | {r.chosen_by} |")
    return "\n".join(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", type=Path, default=DATA)
    p.add_argument("--img", type=Path, default=ROOT / "docs" / "img")
    p.add_argument("--json", type=Path)
    a = p.parse_args(argv)
    res = study(a.data)
    print(f"gap chosen by cross-level consistency: {res['gap']:g} m; scores "
          + ", ".join(f"{g:g}: {100 * s:.2f} %" for g, s in res["gap_scores"].items()))
    h = res["headline"]
    for k, (cx, mg) in h.items():
        print(f"{k:<16} complex {100 * cx:5.1f} %   magnitude {100 * mg:5.1f} %")
    print("characterization of L7:", res["characterization"])
    print(f"median scaled cond in 4-10 Hz: L7 alone {res['l7_cond_median']:.3g}, "
          f"L3+L5+L7 {res['joint_cond_median']:.3g}")
    print(table(res))
    for fp in figures(res, a.img):
        print("wrote", fp)
    if a.json:
        a.json.write_text(json.dumps({"gap": res["gap"], "characterization": res["characterization"],
                                      "gap_scores": {str(k): v for k, v in res["gap_scores"].items()},
                                      "headline": h, "rows": [r.__dict__ for r in res["rows"]]}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
