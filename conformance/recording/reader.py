"""The reader: a recording, finished or not, in file order (:class:`RecordingReader`), or
whole as its records (:func:`read_recording`)."""

from __future__ import annotations

import binascii
import json
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from .layout import (
    C2S,
    CALL_SCHEMA,
    CHANNEL_KINDS,
    CHANNEL_SCHEMAS,
    CNDE_SCHEMA,
    INT_MAX,
    METADATA_NAME,
    OLD_FORMATS,
    REALTIME_STREAM,
    SCHEMAS,
    STATE_KIND,
    TIME_MAX,
    TOPIC_CALLS,
    TOPIC_CNDE,
    TOPIC_CONNECTIONS,
    TOPIC_FRAMES,
    TOPIC_PROBLEMS,
    TOPIC_REALTIME,
    TOPIC_STATE,
)
from .records import (
    CallRecord,
    CndeRecord,
    ConnectionRecord,
    FrameRecord,
    Frames,
    ProblemRecord,
    StateRecord,
)
from .salvage import MAGIC, Damage, Walk
from .traffic_pb import decode_traffic

__all__ = [
    "READ_TOPICS",
    "Damage",
    "Item",
    "Recording",
    "RecordingReader",
    "check_layout",
    "message_damage",
    "read_message",
    "read_recording",
]


@dataclass(frozen=True, kw_only=True)
class Recording:
    """Everything in one recording, in file order."""

    path: str
    metadata: Mapping[str, str]
    frames: tuple[FrameRecord, ...]
    problems: tuple[ProblemRecord, ...]
    connections: tuple[ConnectionRecord, ...]
    #: The file has its summary and footer (False: unfinished, e.g. the proxy was killed).
    complete: bool = True
    #: Why reading stopped early, for an unfinished file.
    truncated: str = ""
    #: The parts that could not be read (a chunk, a message, a region): each says what
    #: it cost.  Every front-end says so, and ``check``/``info`` exit
    #: :data:`~conformance.errors.EXIT_DAMAGED`: a recording that lost data never passes.
    damage: tuple[Damage, ...] = ()
    #: The state port's packets (``/fairino/state``), in file order.
    states: tuple[StateRecord, ...] = ()
    #: The state decoder's problems (``kind`` ``state`` on ``/fairino/problems``): kept
    #: apart from :attr:`problems`, which are the command port's.
    state_problems: tuple[ProblemRecord, ...] = ()
    #: For each of :attr:`problems`, the frames read before it: the file's order of the
    #: two (whose a malformed run is rests on it: conformance/judge/blame.py).
    problems_at: tuple[int, ...] = ()
    #: The SDKs' channels: XML-RPC calls (``/fairino/calls``), CNDE frames
    #: (``/fairino/cnde``), 20004 packets (``/fairino/realtime``), in file order, and their
    #: problems (``kind`` ``xmlrpc``, ``cnde``, ``realtime``), kept apart from the others.
    calls: tuple[CallRecord, ...] = ()
    cnde: tuple[CndeRecord, ...] = ()
    realtime: tuple[StateRecord, ...] = ()
    channel_problems: tuple[ProblemRecord, ...] = ()

    @property
    def start_ns(self) -> int:
        times = [f.first_ns or f.complete_ns for f in self.frames] + [
            c.t_ns for c in self.connections
        ]
        return min(times) if times else 0

    @property
    def end_ns(self) -> int:
        times = [f.complete_ns for f in self.frames] + [c.t_ns for c in self.connections]
        return max(times) if times else 0

    def requests(self) -> list[FrameRecord]:
        return [f for f in self.frames if f.dir == C2S]


#: The ranges of a recording's integers (:data:`~.layout.INT_MAX`, :data:`~.layout.TIME_MAX`).
_INT_MAX = INT_MAX
_TIME_MAX = TIME_MAX


def _kind(v: Any) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "a boolean"
    return {int: "an integer", float: "a number", str: "a string", list: "an array"}.get(
        type(v), "an object"
    )


def _bounds(schema: Mapping[str, Any], top: int) -> tuple[int, int]:
    """An integer's range: the schema's ``minimum`` and ``maximum`` where it states them,
    else 0 and ``top``."""
    return int(schema.get("minimum", 0)), int(schema.get("maximum", top))


def _misfit(v: Any, schema: Mapping[str, Any], name: str, top: int = _INT_MAX) -> str | None:
    """Why the JSON value ``v`` does not fit ``schema`` (the part of JSON schema the
    recording layout uses: type, items, enum, required, minimum, maximum), or None when it
    fits.  An integer is 0 to ``top`` unless the schema bounds it."""
    types = schema.get("type")
    if types is not None:
        allowed = [types] if isinstance(types, str) else list(types)
        ok = (
            ("integer" in allowed and type(v) is int)
            or ("string" in allowed and isinstance(v, str))
            or ("null" in allowed and v is None)
            or ("array" in allowed and isinstance(v, list))
            or ("object" in allowed and isinstance(v, dict))
        )
        if not ok:
            return f"{name} is {_kind(v)}, not {' or '.join(allowed)}"
        lo, hi = _bounds(schema, top)
        if type(v) is int and not lo <= v <= hi:
            if top == _TIME_MAX:
                return f"{name} is {v}, not a time in ns from 1970 to 2106"
            if (lo, hi) != (0, _INT_MAX):
                return f"{name} is {v}, not within {lo}..{hi}"
            return f"{name} is {v}, not a non-negative 64-bit integer"
    if "enum" in schema and v not in schema["enum"]:
        return f"{name} is {str(v)[:40]!r}, not one of {', '.join(schema['enum'])}"
    if isinstance(v, list) and "items" in schema:
        for k, item in enumerate(v):
            why = _misfit(item, schema["items"], f"{name}[{k}]", top)
            if why is not None:
                return why
    if isinstance(v, dict):
        missing = [k for k in schema.get("required", ()) if k not in v]
        if missing:
            return f"{name} has no {', '.join(repr(k) for k in missing)}"
        props = schema.get("properties", {})
        for k, sub in props.items():
            if k in v:
                why = _misfit(v[k], sub, repr(k), _TIME_MAX if k.endswith("_ns") else _INT_MAX)
                if why is not None:
                    return why
    return None


#: The JSON topics read here and the schema their messages must fit.
_SCHEMA_OF_TOPIC = {
    TOPIC_PROBLEMS: SCHEMAS["fairino.Problem"],
    TOPIC_CONNECTIONS: SCHEMAS["fairino.Connection"],
    TOPIC_CALLS: CHANNEL_SCHEMAS[CALL_SCHEMA],
    TOPIC_CNDE: CHANNEL_SCHEMAS[CNDE_SCHEMA],
}


#: Every topic the reader reads (a message on any other is not the reader's: skipped, unnamed).
READ_TOPICS = frozenset((*_SCHEMA_OF_TOPIC, TOPIC_STATE, TOPIC_REALTIME, TOPIC_FRAMES))

#: A record of one JSON message.
JsonRecord = ProblemRecord | ConnectionRecord | StateRecord | CallRecord | CndeRecord


def _record_of(topic: str, doc: Any) -> JsonRecord:
    """The record of one JSON message on one of the recording's topics, its JSON checked
    against the topic's schema first (:data:`~.layout.SCHEMAS`): a ``ValueError``
    saying what does not fit."""
    if not isinstance(doc, dict):
        raise ValueError(f"the message is {_kind(doc)}, not an object")
    try:
        if topic == TOPIC_STATE:  # its schema comes from the spec set's state layouts
            return StateRecord.from_json(doc)
        if topic == TOPIC_REALTIME:  # and this one from the 20004 layouts
            return StateRecord.from_json(doc, stream=REALTIME_STREAM)
        why = _misfit(doc, _SCHEMA_OF_TOPIC[topic], "the message")
        if why is not None:
            raise ValueError(why)
        if topic == TOPIC_PROBLEMS:
            return ProblemRecord.from_json(doc)
        if topic == TOPIC_CALLS:
            return CallRecord.from_json(doc)
        if topic == TOPIC_CNDE:
            return CndeRecord.from_json(doc)
        return ConnectionRecord.from_json(doc)
    except (binascii.Error, KeyError, TypeError, AttributeError) as e:
        raise ValueError(f"{type(e).__name__}: {e}") from None


#: The records of one message (:func:`read_message`).
Read = list[FrameRecord] | JsonRecord


def read_message(topic: str, data: bytes, *, protobuf: bool) -> tuple[Read | None, str]:
    """One message on one of :data:`READ_TOPICS` as :func:`read_recording` reads it
    (``protobuf``: its channel's message encoding is protobuf, as the frames' is): its
    records and "", or None and why it is skipped (the reason :func:`message_damage`
    names)."""
    if topic == TOPIC_FRAMES:
        if not protobuf:
            return None, f"a {topic} message not in protobuf (the layout writes fairino.Traffic)"
        try:
            return decode_traffic(data, as_arrays=False).records(), ""
        except ValueError as e:
            return None, f"not a fairino.Traffic message that can be read ({e})"
    try:
        doc = json.loads(data)
    except RecursionError:
        return None, "not JSON that can be read (nested too deep)"
    except ValueError as e:  # JSONDecodeError, UnicodeDecodeError
        return None, f"not JSON ({type(e).__name__}: {e})"
    try:
        return _record_of(topic, doc), ""
    except ValueError as e:
        return None, str(e)


def check_layout(path: str, metadata: Mapping[str, str]) -> None:
    """A recording in an earlier layout (:data:`~.layout.OLD_FORMATS`) is refused in one
    line naming it: this kit reads layout 4 only."""
    from ..errors import RecordingError

    fmt = metadata.get("format", "")
    if fmt in OLD_FORMATS:
        raise RecordingError(
            f"{path} is a recording in layout {OLD_FORMATS[fmt]} ({fmt}), which this kit no "
            "longer reads: record the traffic again (layout 4)",
            path=path,
        )


def message_damage(count: int, topic: str, sequence: int, offset: int, why: str) -> Damage:
    """A message :func:`read_message` skips, as :attr:`Recording.damage` names it: the
    ``count``-th message of the file (of any topic), its sequence, where it was read."""
    return Damage(
        where=f"message {count} on {topic} (sequence {sequence})",
        offset=offset,
        reason=why,
        lost=1,
        message=True,
    )


def _channel(c: Any, topics: dict[int, str], protobuf: set[int]) -> None:
    """Note a channel: its topic, and whether its messages are protobuf."""
    topics[c.id] = c.topic
    protobuf.discard(c.id)
    if c.message_encoding == "protobuf":
        protobuf.add(c.id)


#: What :meth:`RecordingReader.items` gives: a batch of frames, or another record.
Item = Frames | JsonRecord


class RecordingReader:
    """A recording read in file order, finished or not (an unfinished one reads up to its
    last whole chunk), damaged or not: a chunk that cannot be read is skipped and the
    reading goes on (:class:`~.salvage.Walk`), and a message on the recording's topics
    whose JSON does not fit its schema, or whose frame batch does not read or fit
    (:mod:`.traffic_pb`), is skipped; each is in :attr:`damage` once read.

    Opening it checks the file (a :class:`~conformance.errors.RecordingError` for one
    missing, unreadable or not MCAP); :meth:`items` reads it, a message at a time, and
    raises the same error for a file with no recording's metadata or of an earlier layout
    (:func:`check_layout`).  Every reading of a recording goes through here: the whole
    of it (:func:`read_recording`) and a window at a time (``check``, ``info``,
    ``export-parquet``: :mod:`conformance.offline.engine`)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        from ..errors import RecordingError

        self.path = os.fspath(path)
        try:
            self._file = open(self.path, "rb")  # noqa: SIM115 (closed when items() ends)
        except FileNotFoundError:
            raise RecordingError(f"no such recording: {self.path}", path=self.path) from None
        except OSError as e:
            raise RecordingError(
                f"cannot read {self.path}: {e.strerror or e}", path=self.path
            ) from None
        if self._file.read(8) != MAGIC:
            self._file.close()
            raise RecordingError(f"{self.path} is not an MCAP file", path=self.path)
        self.metadata: dict[str, str] = {}
        #: The file has its summary and footer (False: unfinished); known once read.
        self.complete = True
        #: Why reading stopped early, for an unfinished file.
        self.truncated = ""
        #: What could not be read, in the order met (growing as the file is read).
        self.damage: list[Damage] = []

    def items(self, *, arrays: bool = False) -> Iterator[Item]:
        """The recording's frame batches and records in file order (``arrays``: a batch's
        number columns as numpy arrays, else lists)."""
        from mcap.records import Channel, Message, Metadata

        from ..errors import RecordingError

        topics: dict[int, str] = {}
        protobuf: set[int] = set()  # channels whose messages are protobuf
        with self._file as f:
            walk = Walk(f, self.path)
            self.damage = walk.damage
            for r in walk.summary_records():
                if isinstance(r, Channel):
                    _channel(r, topics, protobuf)
            count = 0
            for rec, where in walk.records():
                if isinstance(rec, Channel):
                    _channel(rec, topics, protobuf)
                elif isinstance(rec, Message):
                    count += 1
                    topic = topics.get(rec.channel_id)
                    if topic not in READ_TOPICS:
                        continue  # a foreign topic: not ours to read
                    got, why = _read(topic, rec.data, rec.channel_id in protobuf, arrays)
                    if got is None:
                        walk.damage.append(message_damage(count, topic, rec.sequence, where, why))
                        continue
                    yield got
                elif isinstance(rec, Metadata) and rec.name == METADATA_NAME and not self.metadata:
                    self.metadata = dict(rec.metadata)
                    check_layout(self.path, self.metadata)
            self.complete = walk.complete
            self.truncated = walk.stopped if not walk.complete else ""
        if not self.metadata:
            lost = f" ({walk.damage[0]})" if walk.damage else ""
            raise RecordingError(
                f"{self.path} is an MCAP file but not a fairino-conformance recording{lost}",
                path=self.path,
            )


def _read(topic: str, data: bytes, protobuf: bool, arrays: bool) -> tuple[Item | None, str]:
    """One message as :meth:`RecordingReader.items` reads it (see :func:`read_message`)."""
    if topic == TOPIC_FRAMES and protobuf:
        try:
            return decode_traffic(data, as_arrays=arrays), ""
        except ValueError as e:
            return None, f"not a fairino.Traffic message that can be read ({e})"
    got, why = read_message(topic, data, protobuf=protobuf)
    return (None, why) if isinstance(got, list) else (got, why)


def read_recording(path: str | os.PathLike[str]) -> Recording:
    """A recording read whole (:class:`RecordingReader`) as its records."""
    reader = RecordingReader(path)
    frames: list[FrameRecord] = []
    problems: list[ProblemRecord] = []
    problems_at: list[int] = []
    conns: list[ConnectionRecord] = []
    states: list[StateRecord] = []
    state_problems: list[ProblemRecord] = []
    calls: list[CallRecord] = []
    cnde: list[CndeRecord] = []
    realtime: list[StateRecord] = []
    channel_problems: list[ProblemRecord] = []
    for got in reader.items():
        if isinstance(got, Frames):
            frames += got.records()
        elif isinstance(got, ProblemRecord):
            # The state decoder's and the SDK channels' problems apart from the command port's.
            if got.kind == STATE_KIND:
                state_problems.append(got)
            elif got.kind in CHANNEL_KINDS:
                channel_problems.append(got)
            else:
                problems.append(got)
                problems_at.append(len(frames))
        elif isinstance(got, StateRecord):
            (realtime if got.realtime else states).append(got)
        elif isinstance(got, CallRecord):
            calls.append(got)
        elif isinstance(got, CndeRecord):
            cnde.append(got)
        else:
            conns.append(got)
    return Recording(
        path=reader.path,
        metadata=reader.metadata,
        frames=tuple(frames),
        problems=tuple(problems),
        connections=tuple(conns),
        complete=reader.complete,
        truncated=reader.truncated,
        damage=tuple(reader.damage),
        states=tuple(states),
        state_problems=tuple(state_problems),
        problems_at=tuple(problems_at),
        calls=tuple(calls),
        cnde=tuple(cnde),
        realtime=tuple(realtime),
        channel_problems=tuple(channel_problems),
    )
