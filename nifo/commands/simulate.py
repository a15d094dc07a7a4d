"""``nifo simulate``: write a simulated quarter-car record and its truth.

The record goes to ``--out`` (format by suffix, :func:`nifo.io.loader.save_record`);
the truth (vehicle, strut forces, road, noise, seed, lift-off) to
``<out>.truth.json`` beside it. Both are written atomically.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from nifo.commands import SUMMARIES
from nifo.io.atomic import check_output, staged_file
from nifo.progress import Progress
from nifo_core.kinds.describing import make_term
from nifo_core.errors import ConfigError
from nifo_core.simulate.quarter_car import (PRESETS, ChirpRoad, RandomRoad, SensorNoise, SimConfig, Simulation, StrutForce,
                                preset, simulate)

HELP = SUMMARIES["simulate"]
#: the argument naming what this command writes: locked for the whole command (nifo.io.lock)
OUTPUT = "out"
DESCRIPTION = f"""{HELP}.

Road: Gaussian random (--road-rms, default 2.5 mm, 0.5-40 Hz) or the paper's
slow chirp (--chirp, 0-15 Hz at 0.025 Hz/s; the duration defaults to the sweep).

Strut nonlinearities: a --preset and/or any number of --nonlinearity
KIND:param=value,...:coef=C  (coef in N per unit of g), e.g.
  --nonlinearity velocity_deadzone:knee=0.03:coef=-700
  --nonlinearity backlash:deadband=0.00043:coef=8000
  --nonlinearity coulomb:coef=100

Presets:
""" + "\n".join(f"  {name:<18} {desc}" for name, (_, desc) in PRESETS.items())

_COEF_KEYS = ("coef", "coefficient", "c")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, type=Path, metavar="PATH",
                   help="record to write (.mcap or bag directory, .csv, .mat); truth goes to PATH.truth.json")
    p.add_argument("--preset", choices=list(PRESETS), help="named set of strut nonlinearities")
    p.add_argument("--nonlinearity", action="append", default=[], metavar="KIND:param=value,...:coef=C",
                   help="a strut force c·g (repeatable; added to --preset)")
    road = p.add_mutually_exclusive_group()
    road.add_argument("--road-rms", type=float, metavar="MM", help="random road RMS displacement [mm] (default 2.5)")
    road.add_argument("--chirp", type=float, metavar="AMPLITUDE_MM", help="slow chirp road amplitude [mm]")
    p.add_argument("--road-spectrum", choices=("flat", "iso8608"), default="flat",
                   help="random road displacement spectrum: flat 0.5-40 Hz (default) or falling as 1/f above 1 Hz "
                        "like a real road (ISO 8608)")
    p.add_argument("--duration", type=float, metavar="S", help="record length [s] (default 300, or the chirp sweep)")
    p.add_argument("--fs", type=float, default=600.0, metavar="HZ", help="sample rate [Hz] (default 600)")
    p.add_argument("--oversample", type=int, default=10, metavar="N", help="integration rate = fs·N (default 10)")
    p.add_argument("--noise", type=float, default=0.0, metavar="REL",
                   help="sensor noise, fraction of each channel's RMS (default 0)")
    p.add_argument("--seed", type=int, metavar="N", help="random seed (default: fresh, recorded in the truth)")
    p.add_argument("--tire-lift-off", action="store_true", help="let the wheel leave the road")


def parse_nonlinearity(text: str) -> StrutForce:
    """``KIND:param=value,...:coef=C`` → :class:`StrutForce` (groups of key=value may also be split by ':')."""
    kind, *groups = text.split(":")
    params: dict[str, object] = {}
    for item in (i for g in groups for i in g.split(",") if i.strip()):
        key, sep, value = item.partition("=")
        if not sep:
            raise ConfigError(f"--nonlinearity {text!r}: {item!r} is not key=value",
                              hint="write KIND:param=value,...:coef=C, e.g. coulomb:eps=0.005:coef=100")
        params[key.strip()] = _number_or_text(value.strip())
    coef = [params.pop(k) for k in _COEF_KEYS if k in params]
    if len(coef) != 1 or not isinstance(coef[0], float):
        raise ConfigError(f"--nonlinearity {text!r} needs one numeric coef=C [N per unit of g]",
                          hint="e.g. velocity_deadzone:knee=0.03:coef=-700")
    try:
        return StrutForce(make_term({"kind": kind.strip(), "params": params}), coef[0])
    except ConfigError as err:
        raise ConfigError(f"--nonlinearity {text!r}: {err.message}", hint=err.hint) from None


def _number_or_text(value: str) -> object:
    try:
        return float(value)
    except ValueError:
        return value


def config_from_args(args: argparse.Namespace) -> SimConfig:
    """The :class:`SimConfig` the options describe."""
    strut = (preset(args.preset) if args.preset else ()) + tuple(parse_nonlinearity(s) for s in args.nonlinearity)
    if args.chirp is not None:
        road = ChirpRoad(args.chirp * 1e-3)
    else:
        road = RandomRoad((2.5 if args.road_rms is None else args.road_rms) * 1e-3, spectrum=args.road_spectrum)
    return SimConfig(strut=strut, tire_lift_off=args.tire_lift_off, road=road, duration_s=args.duration,
                     fs_hz=args.fs, oversample=args.oversample, noise=SensorNoise(relative=args.noise))


def truth_path(out: Path) -> Path:
    """Where the truth of record ``out`` is written: ``<out>.truth.json``."""
    return out.with_name(out.name + ".truth.json")


def _write_truth(sim: Simulation, path: Path, record_path: Path) -> None:
    doc = {"nifo_truth": 1, "record": record_path.name, **sim.truth.to_dict(), "config": sim.config.to_dict()}
    with staged_file(path) as tmp:
        tmp.write_text(json.dumps(doc, indent=2) + "\n")


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def _summary(sim: Simulation, out: Path) -> str:
    r, t = sim.record, sim.truth
    f_body, f_hop = t.vehicle.natural_frequencies_hz()
    strut = ", ".join(s.label for s in t.strut) or "linear"
    return "\n".join([
        f"wrote {out} and {truth_path(out).name}",
        f"  {r.duration_s:g} s at {r.fs_hz:g} Hz ({r.n} samples), seed {t.seed}",
        f"  road: {t.road.to_dict()}",
        f"  strut: {strut}",
        f"  RMS: spindle {_rms(r.spindle_accel):.3g} m/s², body {_rms(r.body_accel):.3g} m/s², "
        f"tire patch {1e3 * _rms(r.tire_patch_disp):.3g} mm, z {1e3 * _rms(t.z):.3g} mm, "
        f"ż {_rms(t.zdot):.3g} m/s",
        f"  modes: body bounce {f_body:.2f} Hz, wheel hop {f_hop:.2f} Hz",
        f"  lift-off: {100 * t.lift_off_fraction:.2f} % of the time" + ("" if t.tire_lift_off else " (not modelled)"),
    ])


def run(args: argparse.Namespace) -> dict:
    config = config_from_args(args)
    from nifo.io.loader import check_record_output, save_record  # imported late: the I/O stack is heavy

    check_record_output(args.out)   # refuse a file or folder nifo did not write before any work
    check_output(truth_path(args.out), kind="file")

    with Progress(1.0, "simulate", enabled=config.duration >= 60) as bar:
        sim = simulate(config, rng=args.seed, progress=lambda frac: bar.advance(frac - bar.done))
    save_record(args.out, sim.record)
    _write_truth(sim, truth_path(args.out), args.out)
    print(_summary(sim, args.out))
    return {"out": str(args.out), "truth": str(truth_path(args.out)), "fs_hz": sim.record.fs_hz,
            "duration_s": sim.record.duration_s, "seed": sim.truth.seed}
