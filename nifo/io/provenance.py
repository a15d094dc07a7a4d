"""What a result needs to read its data again, and what system the data come from.

Commands store, in their JSON document,

- ``"input"``: the values of the input options (:func:`nifo.io.loader.add_input_arguments`:
  ``--columns``, ``--topics``, ``--fs``, ...) they read the data with, so ``nifo report`` and
  ``nifo view`` re-read the same channels (:func:`reader_options`);
- ``"system"``: ``--system "DESCRIPTION [UNIT]"``, what was measured and the unit of the two
  acceleration channels (default: a vehicle suspension in m/s²), so figures and the report
  use the record's units and no quarter-car words on other structures (:func:`system_of`).

:func:`true_t21` and :func:`true_strut_model` read the simulator's truth beside a data file, for the
true curves in figures.
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Mapping

from nifo_core.errors import ConfigError, NifoError

__all__ = ["input_provenance", "reader_options", "add_system_argument", "system_of", "System", "QUARTER_CAR",
           "true_t21", "true_strut_model"]

#: the default system: what nifo is made for
QUARTER_CAR = {"description": "", "units": "m/s²", "vehicle": True}


def _input_defaults() -> argparse.Namespace:
    from .loader import add_input_arguments

    p = argparse.ArgumentParser(add_help=False)
    add_input_arguments(p)
    return p.parse_args([])


def input_provenance(args: argparse.Namespace) -> dict:
    """The input options of ``args`` as given (JSON-able), for the result's document."""
    return {k: getattr(args, k, v) for k, v in vars(_input_defaults()).items()}


def reader_options(doc: Mapping) -> dict:
    """Keyword arguments for :func:`nifo.io.loader.load_record` from a result document's ``"input"``
    (the defaults when the document has none: results written before it was stored)."""
    from .loader import input_options

    ns = _input_defaults()
    for k, v in (doc.get("input") or {}).items():
        if hasattr(ns, k):
            setattr(ns, k, v)
    return input_options(ns)


System = Mapping[str, object]


def add_system_argument(parser: argparse.ArgumentParser) -> None:
    """``--system "DESCRIPTION [UNIT]"``: what was measured, and the channels' unit."""
    parser.add_argument("--system", metavar='"TEXT [UNIT]"',
                        help="what the data are from, with the unit of the two signals in brackets, e.g. "
                             "--system 'Silverbox Duffing circuit [V]' (default: a vehicle suspension, m/s²); "
                             "used in figures and the report instead of quarter-car words")


def system_of(args_or_doc) -> dict:
    """``{"description", "units", "vehicle"}`` from parsed arguments or a result document's ``"system"``."""
    if isinstance(args_or_doc, Mapping):
        got = args_or_doc.get("system")
        return {**QUARTER_CAR, **got} if isinstance(got, Mapping) else dict(QUARTER_CAR)
    text = getattr(args_or_doc, "system", None)
    if not text:
        return dict(QUARTER_CAR)
    m = re.fullmatch(r"\s*(.*?)\s*(?:\[([^\[\]]+)\])?\s*", text)
    desc, unit = (m.group(1), m.group(2)) if m else (text, None)
    if not desc and not unit:
        raise ConfigError(f"--system {text!r} says nothing", channel="--system",
                          hint="e.g. --system 'F-16 wing-payload interface [m/s²]'")
    return {"description": desc, "units": (unit or "m/s²").strip(), "vehicle": False}


def true_t21(path, freq_hz):
    """The true nominal linear T21 at ``freq_hz`` [Hz] from the simulator's truth file beside data ``path``
    (``<name>.truth.json``, see ``nifo simulate``); None when there is none or it cannot be read."""
    import json
    from pathlib import Path

    from .truth import truth_for
    from nifo_core.simulate.vehicle import QuarterCar

    tp = truth_for(Path(path))
    if tp is None:
        return None
    try:
        return QuarterCar(**json.loads(tp.read_text())["vehicle"]).t21(freq_hz)
    except (OSError, ValueError, KeyError, TypeError):
        return None


def true_strut_model(path):
    """The simulator's true strut (linear K2, C2 and its nonlinear terms), per unit sprung mass, as a
    :class:`nifo_core.characterize.automatic.FittedModel`, from the truth file beside data ``path``; None without one."""
    import json
    from pathlib import Path

    from .truth import truth_for
    from nifo_core.characterize.automatic import FittedModel
    from nifo_core.kinds.describing import make_term

    tp = truth_for(Path(path))
    if tp is None:
        return None
    try:
        doc = json.loads(tp.read_text())
        m2 = float(doc["vehicle"]["m2"])
        terms = tuple((make_term({"kind": s["kind"], "params": s.get("params") or {}}), float(s["coefficient"]) / m2)
                      for s in doc.get("strut") or [])
        return FittedModel(float(doc["vehicle"]["k2"]) / m2, float(doc["vehicle"]["c2"]) / m2, terms, float("nan"))
    except (OSError, ValueError, KeyError, TypeError, NifoError):
        return None
