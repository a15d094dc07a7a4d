"""What the fleet's tasks hand on: named, frozen result objects (picklable: they travel between Dask workers and the
client), each with the ``to_dict`` of its part of ``fleet.json``.

A bag's status (:class:`BagStatus`), a group's merged partial (:class:`GroupPartial`), a batch of bags
(:class:`Batch`), a group's solve (:class:`GroupResult`: :class:`Coefficient` per coefficient, :class:`Curves` for
the page), and the optional per-group steps (:class:`LoopOutcome`, :class:`CharacterizeOutcome`). A failure is an
object with ``ok`` False and its one-line ``reason``, never an exception: one bad bag or group never stops the fleet.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Mapping

import numpy as np

from nifo_core.fleet import GroupHealth

__all__ = ["BagStatus", "GroupPartial", "Batch", "Coefficient", "Curves", "LoopOutcome", "CharacterizeOutcome",
           "GroupResult"]

NAN = float("nan")


@dataclass(frozen=True)
class BagStatus:
    """One bag after its accumulation task: ``ok`` with what the client and the group's solve need, else ``reason``.

    ``probe``: the bag's rate, length and channels (:meth:`~nifo_core.nifo.engine.RecordProbe.to_dict`);
    ``setup_hash``: the set-up it was accumulated with; ``coefs``: its own coefficients (for the group's standard
    errors); ``seconds``: this run's time spent on it [s]."""

    ok: bool
    reason: str = ""
    path: str = ""
    n_samples: int = 0
    fs_hz: float = NAN
    hash: str = ""
    key: str = ""
    probe: Mapping[str, Any] = field(default_factory=dict)
    setup_hash: str = ""
    cached: bool = False
    seconds: float = 0.0
    coefs: Mapping[str, float] = field(default_factory=dict)
    cache_note: str = ""

    @classmethod
    def failed(cls, reason: str) -> "BagStatus":
        return cls(ok=False, reason=reason)


@dataclass(frozen=True)
class GroupPartial:
    """The bags of one group accumulated with one set-up and merged (``state``:
    :meth:`~nifo_core.nifo.identify.StreamingNifo.state_dict`), or why there is none (``reasons``: its bags')."""

    ok: bool
    state: Mapping[str, Any] | None = None
    bags: tuple[BagStatus, ...] = ()
    reason: str = ""
    reasons: tuple[str, ...] = ()

    @classmethod
    def none_usable(cls, reasons=()) -> "GroupPartial":
        return cls(ok=False, reason="no usable bag", reasons=tuple(reasons))


@dataclass(frozen=True)
class Batch:
    """What one accumulation task returns: every bag's status for the client, and the partials per (vehicle,
    corner, set-up hash), which stay on the worker until a merge or a solve picks them."""

    status: tuple[tuple[int, BagStatus], ...]
    parts: Mapping[tuple, GroupPartial]


@dataclass(frozen=True)
class Coefficient:
    """One coefficient of a group: its value, standard error and 95 % interval [lo, hi], in ``unit``."""

    value: float
    se: float
    lo: float
    hi: float
    unit: str

    def scaled(self, factor: float, unit: str) -> "Coefficient":
        """The same coefficient times ``factor`` (per body mass → SI: times the sprung mass), in ``unit``."""
        return Coefficient(self.value * factor, self.se * factor, self.lo * factor, self.hi * factor, unit)

    @property
    def halfwidth(self) -> float:
        return (self.hi - self.lo) / 2

    def to_dict(self) -> dict:
        return {"value": self.value, "se": self.se, "lo": self.lo, "hi": self.hi, "unit": self.unit}


@dataclass(frozen=True)
class Curves:
    """A group's pooled T21 with its random error, plain H1 and its coherence, on the lines kept for the page [Hz]."""

    freq_hz: np.ndarray
    t21: np.ndarray
    t21_eps: np.ndarray
    h1: np.ndarray
    coherence: np.ndarray


@dataclass(frozen=True)
class LoopOutcome:
    """``nifo loop``'s verdict on a group; ``scores``: its held-out scores before and after (``LOOP_SCORES``)."""

    ok: bool
    verdict: str
    added: tuple[str, ...] = ()
    nothing_missing: bool | None = None
    scores: Mapping[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        if not self.ok:
            return {"ok": False, "verdict": self.verdict, "added": list(self.added)}
        return {"ok": True, "verdict": self.verdict, "added": list(self.added), "nothing_missing": self.nothing_missing,
                **self.scores}


@dataclass(frozen=True)
class CharacterizeOutcome:
    """``nifo characterize``'s ranking on a group: one line of text and the suggested terms' labels."""

    ok: bool
    text: str
    suggested: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        return {"ok": self.ok, "text": self.text, "suggested": list(self.suggested)}


@dataclass(frozen=True)
class GroupResult:
    """NIFO solved on a group's merged partial, or why not (``ok`` False, ``reason``).

    ``coefficients``: name → :class:`Coefficient` (per body mass, and in SI with the sprung mass ``m2_kg``);
    ``specs``: (name, unit, meaning) of each; ``names``: the per-mass and the SI names; ``t21``: |T21| with bounds and
    phase at the table's frequencies; ``summary``/``warnings``: :func:`nifo_core.nifo.summary.summarize`'s;
    ``health``, ``loop``, ``characterization``: added by the client once every group is in.
    """

    ok: bool
    reason: str = ""
    bags: tuple[BagStatus, ...] = ()
    coefficients: Mapping[str, Coefficient] = field(default_factory=dict)
    specs: tuple[tuple[str, str, str], ...] = ()
    names: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    t21: Mapping[str, float] = field(default_factory=dict)
    summary: Mapping[str, Any] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    n_avg: int = 0
    fs_hz: float = NAN
    duration_s: float = NAN
    curves: Curves | None = None
    analysis_band_hz: tuple[float, float] | None = None
    m2_kg: float | None = None
    health: GroupHealth | None = None
    loop: LoopOutcome | None = None
    characterization: CharacterizeOutcome | None = None

    @classmethod
    def failed(cls, reason: str, bags=()) -> "GroupResult":
        return cls(ok=False, reason=reason, bags=tuple(bags))

    def with_(self, **changes) -> "GroupResult":
        """A copy with ``changes`` (the client adds the health, the loop and the characterization)."""
        return replace(self, **changes)
