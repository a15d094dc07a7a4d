"""Each step's typed options (:mod:`nifo.pipeline.options`) are its command line's: the same names, the same
defaults, so ``nifo run`` and the fleet calling a step directly run it as the command would."""

import argparse
from dataclasses import fields

import pytest

from nifo.cli import build_parser
from nifo.pipeline import options as o

STEPS = {"characterize": o.CharacterizeOptions, "identify": o.IdentifyOptions, "loop": o.LoopOptions,
         "predict": o.PredictOptions, "run": o.RunOptions, "export": o.ExportOptions}


def _command_parser(name: str) -> argparse.ArgumentParser:
    sub = next(a for a in build_parser(name)._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[name]


@pytest.mark.parametrize("name", sorted(STEPS))
def test_step_options_have_the_command_lines_names_and_defaults(name):
    parser = _command_parser(name)
    dests = {a.dest: a for a in parser._actions if a.dest not in ("help", "json", "quiet", "verbose")}
    mine = {f.name: f.default for f in fields(STEPS[name]) if f.name not in o.NOT_FLAGS}
    assert set(mine) == set(dests)
    for dest, action in dests.items():
        if not action.required and not (action.nargs in ("*", "+") and action.default is None):
            assert mine[dest] == action.default, dest


def test_run_passes_on_only_the_input_and_settings_options_a_step_has():
    given = o.RunOptions(block=4096, integration_band_hz=[0.5, 60.0], cond_limit=1e3, columns="a=b", no_loop=True)
    pred = o.PredictOptions(out="x").taking(given)
    assert (pred.block, pred.columns, pred.out) == (4096, "a=b", "x") and not hasattr(pred, "integration_band_hz")
    ident = o.IdentifyOptions().taking(given)
    assert (ident.integration_band_hz, ident.cond_limit) == ([0.5, 60.0], 1e3)
