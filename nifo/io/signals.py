"""Predicted signals as tables: one row per sample, Parquet (pyarrow) and CSV, so any metric can be computed.

``nifo predict`` writes, per record, ``<record>_signals.parquet`` and
``<record>_signals.csv`` with the columns of :func:`signal_columns`: time, the
input that drove the model, the measured output in the unit it was measured in
(the body acceleration, or the body displacement when a displacement was
recorded), the model's prediction of it and the linear model's. Units are in
the column names and in the Parquet schema's metadata.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Mapping

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from .atomic import claim

__all__ = ["write_signals", "read_signals"]


def write_signals(out: Path, stem: str, columns: Mapping[str, np.ndarray], *, meta: Mapping | None = None
                  ) -> list[str]:
    """``<stem>_signals.parquet`` and ``<stem>_signals.csv`` in ``out``; their names."""
    table = pa.table({k: pa.array(np.asarray(v, float)) for k, v in columns.items()})
    table = table.replace_schema_metadata({"nifo": json.dumps(dict(meta or {}), default=str)})
    names = [f"{stem}_signals.parquet", f"{stem}_signals.csv"]
    for name in names:
        claim(out / name)
    pq.write_table(table, out / names[0])
    pacsv.write_csv(table, out / names[1])
    return names


def read_signals(path: str | Path, columns: list[str] | None = None) -> dict[str, np.ndarray]:
    """The columns of a ``<record>_signals.parquet`` (all, or ``columns``) as arrays."""
    table = pq.read_table(path, columns=columns)
    return {name: table.column(name).to_numpy() for name in table.column_names}
