"""Bag topics and their roles (spindle, body, tire patch): :class:`BagTopics` and :func:`resolve_topics`."""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

from nifo_core.errors import ConfigError, MissingChannelError

from .cdr import IMU, POINT_STAMPED, WRENCH_STAMPED

if TYPE_CHECKING:
    from rosbags.interfaces import Connection

__all__ = ["BagTopics", "resolve_topics"]

_SPINDLE_WORDS = ("spindle", "wheel", "unsprung")
_BODY_WORDS = ("body", "sprung", "chassis")
_TIRE_WORDS = ("tire", "tyre", "patch", "road")
_FORCE_WORDS = ("force", "load", "wrench")
_FORCE_TOPIC = "/nifo/force"

_ROLE_ALIASES = {"spindle": "spindle", "spindle_accel": "spindle", "body": "body", "body_accel": "body",
                 "tire_patch": "tire_patch", "tire_patch_disp": "tire_patch", "force": "force"}


@dataclass(frozen=True)
class BagTopics:
    """Which topic plays which role.

    Reading with topics other than the defaults requires them to exist (the
    default tire-patch topic may be absent: no tire patch then);
    ``tire_patch=None`` ignores any tire-patch topic. Writing a record with a
    tire patch needs a ``tire_patch`` topic.
    """

    spindle: str = "/nifo/spindle/imu"
    body: str = "/nifo/body/imu"
    tire_patch: str | None = "/nifo/tire_patch/displacement"
    #: None: ``/nifo/force`` when the bag has it (a force is optional)
    force: str | None = None

    @classmethod
    def parse(cls, text: str) -> "BagTopics":
        """``"spindle=/a,body=/b[,tire_patch=/c]"`` (the ``--topics`` option) to :class:`BagTopics`."""
        given: dict[str, str] = {}
        for item in filter(None, (s.strip() for s in text.split(","))):
            key, sep, topic = item.partition("=")
            role = _ROLE_ALIASES.get(key.strip())
            if not sep or role is None or not topic.strip():
                raise ConfigError(f"cannot read --topics item {item!r}", channel="--topics",
                                  hint="write --topics spindle=/a,body=/b[,tire_patch=/c]")
            given[role] = topic.strip()
        return cls(**given)

    def as_dict(self) -> dict[str, str | None]:
        """Topic per role (``force`` only when set)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "force" or self.force}


_DEFAULT_TOPICS = BagTopics()


def _topic_table(conns: Sequence["Connection"]) -> dict[str, str]:
    return {c.topic: c.msgtype for c in conns}


def _matching(names: Sequence[str], words: Sequence[str], exclude: Sequence[str] = ()) -> list[str]:
    def has(name: str, ws: Sequence[str]) -> bool:
        parts = re.split(r"[^a-z0-9]+", name.lower())
        return any(w in p for p in parts for w in ws)
    return [n for n in names if has(n, words) and not (exclude and has(n, exclude))]


def resolve_topics(available: Mapping[str, str], topics: BagTopics | None, *,
                   source: str) -> dict[str, str | None]:
    """Topic for each role (``spindle``, ``body``, ``tire_patch``) among ``available`` {topic: msgtype}.

    Explicit ``topics`` must exist. Without them the defaults are used when
    present; otherwise Imu topics are matched by name: spindle
    ("spindle", "wheel", "unsprung") and body ("body", "sprung", "chassis",
    but not a spindle word); a PointStamped with "tire", "tyre", "patch" or
    "road" in its name is the tire patch, a WrenchStamped ``/nifo/force`` or
    the one with "force", "load" or "wrench" in its name the measured force
    (the ``force`` role is listed only when found). Raises :class:`MissingChannelError`
    listing the Imu topics when a role is absent or ambiguous.
    """
    imus = sorted(t for t, ty in available.items() if ty == IMU)
    points = sorted(t for t, ty in available.items() if ty == POINT_STAMPED)
    listing = ", ".join(imus) or "none"
    fix = "name the topics, e.g. --topics spindle=/a,body=/b"

    def missing(role: str, what: str) -> MissingChannelError:
        return MissingChannelError(f"{what}; Imu topics in the bag: {listing}", source=source,
                                   channel=role, hint=fix)

    if topics is not None and topics != _DEFAULT_TOPICS:
        out: dict[str, str | None] = {}
        for role, want, types in (("spindle", topics.spindle, (IMU,)), ("body", topics.body, (IMU,)),
                                  ("tire_patch", topics.tire_patch, (POINT_STAMPED,)),
                                  ("force", topics.force or _FORCE_TOPIC, (WRENCH_STAMPED,))):
            if want is None:
                out[role] = None
            elif want not in available:
                if (role, want) in (("tire_patch", _DEFAULT_TOPICS.tire_patch), ("force", _FORCE_TOPIC)):
                    out[role] = None  # the optional default
                    continue
                raise missing(role, f"topic {want} is not in the bag")
            elif available[want] not in types:
                raise MissingChannelError(f"topic {want} is {available[want]}, expected {' or '.join(types)}",
                                          source=source, channel=role, hint=fix)
            else:
                out[role] = want
        if out.get("force", 0) is None:
            del out["force"]
        if out["spindle"] == out["body"]:
            raise MissingChannelError(f"spindle and body are both {out['spindle']}", source=source,
                                      channel="--topics", hint="give the spindle and the body their own topics")
        return out

    d = _DEFAULT_TOPICS
    out = {}
    for role, default, words, exclude in (("spindle", d.spindle, _SPINDLE_WORDS, ()),
                                          ("body", d.body, _BODY_WORDS, _SPINDLE_WORDS)):
        if available.get(default) == IMU:
            out[role] = default
            continue
        found = _matching(imus, words, exclude)
        if len(found) != 1:
            raise missing(role, f"no Imu topic for the {role}" if not found
                          else f"several Imu topics could be the {role} ({', '.join(found)})")
        out[role] = found[0]
    if available.get(d.tire_patch) == POINT_STAMPED:
        out["tire_patch"] = d.tire_patch
    else:
        found = _matching(points, _TIRE_WORDS)
        out["tire_patch"] = found[0] if len(found) == 1 else None
    wrenches = sorted(t for t, ty in available.items() if ty == WRENCH_STAMPED)
    found = [_FORCE_TOPIC] if available.get(_FORCE_TOPIC) == WRENCH_STAMPED else _matching(wrenches, _FORCE_WORDS)
    if len(found) == 1:   # the force role is listed only when present
        out["force"] = found[0]
    if out["spindle"] == out["body"]:
        raise missing("body", f"spindle and body resolve to the same topic {out['spindle']}")
    return out
