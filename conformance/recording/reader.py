"""The reader: a recording, finished or not, as records (:func:`read_recording`), and its
requests paired with their replies (:class:`RecordedExchange`)."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import IO, Any

from .layout import C2S, METADATA_NAME, TOPIC_C2S, TOPIC_CONNECTIONS, TOPIC_PROBLEMS, TOPIC_S2C
from .records import ConnectionRecord, FrameBatch, FrameRecord, ProblemRecord

__all__ = ["RecordedExchange", "Recording", "read_recording"]


@dataclass(frozen=True, kw_only=True)
class RecordedExchange:
    """A request and the reply paired with it (either may be missing)."""

    conn: int
    request: FrameRecord | None
    reply: FrameRecord | None

    @property
    def cmd_id(self) -> int:
        f = self.request or self.reply
        assert f is not None
        return f.cmd_id

    @property
    def name(self) -> str | None:
        f = self.request or self.reply
        assert f is not None
        return f.name if f.name is not None else (self.reply.name if self.reply else None)

    @property
    def latency_ns(self) -> int | None:
        if self.request is None or self.reply is None:
            return None
        return self.reply.complete_ns - self.request.complete_ns


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

    def _malformed_runs(self) -> tuple[dict[int, FrameRecord], list[ProblemRecord]]:
        """Each malformed run (by ``id()``) with the frame its sender sent next on that
        connection and direction; and the runs no frame follows."""
        before: dict[int, FrameRecord] = {}
        trailing: list[ProblemRecord] = []
        streams: dict[tuple[int, str], list[tuple[int, int, Any]]] = {}
        for f in self.frames:
            streams.setdefault((f.conn, f.dir), []).append((f.offset, 1, f))
        for p in self.problems:
            if p.kind == "malformed":
                streams.setdefault((p.conn, p.dir), []).append((p.offset, 0, p))
        for items in streams.values():
            items.sort(key=lambda x: (x[0], x[1]))
            run: list[ProblemRecord] = []
            for _, is_frame, x in items:
                if is_frame:
                    for p in run:
                        before[id(p)] = x
                    run = []
                else:
                    run.append(x)
            trailing.extend(run)
        return before, trailing

    def noise_before(self) -> dict[int, int]:
        """For each frame (by ``id()``), the malformed bytes its sender sent just before it
        (since the previous frame in that direction): garbage ahead of a reply."""
        out: dict[int, int] = {}
        before, _ = self._malformed_runs()
        by_id = {id(p): p for p in self.problems}
        for pid, f in before.items():
            out[id(f)] = out.get(id(f), 0) + by_id[pid].size
        return out

    def answered_by(self) -> dict[int, FrameRecord]:
        """The one rule for whose a controller's malformed run is: for each run of the
        controller's (by ``id()``), the request it answered.

        That is the request of the reply it came just before (the garbage ahead of a
        reply: :meth:`noise_before` gives its bytes to that reply, ``diff`` and ``replay``
        compare them per request), or the reply itself when no request is paired with it;
        a run no reply follows answered the last request its client sent before the run
        ended.  A run before any request answered none (absent)."""
        before, trailing = self._malformed_runs()
        request_of = {id(e.reply): e.request for e in self.exchanges() if e.reply is not None}
        out: dict[int, FrameRecord] = {}
        for p in self.problems:
            if p.dir == C2S or id(p) not in before:
                continue
            reply = before[id(p)]
            out[id(p)] = request_of.get(id(reply)) or reply
        sent: dict[int, list[FrameRecord]] = {}
        for f in self.frames:
            if f.dir == C2S:
                sent.setdefault(f.conn, []).append(f)
        for p in trailing:
            if p.dir == C2S:
                continue
            earlier = [
                f for f in sent.get(p.conn, ()) if (f.first_ns or f.complete_ns) <= p.complete_ns
            ]
            if earlier:
                out[id(p)] = max(earlier, key=lambda f: f.first_ns or f.complete_ns)
        return out

    def requests(self) -> list[FrameRecord]:
        return [f for f in self.frames if f.dir == C2S]

    def exchanges(self) -> list[RecordedExchange]:
        """Pair each reply with the oldest unanswered request of its connection with the same
        CNT and CMD_ID (else the same CMD_ID); unpaired frames stand alone.

        Frames are taken in the order their first byte arrived, not file order: a frame
        the recorder could decide only once its sender went quiet (a LEN that does not
        fit, odd separators) is written after the reply that already answered it.
        """
        out: list[RecordedExchange | None] = []
        pending: dict[int, list[tuple[int, FrameRecord]]] = {}
        for f in sorted(self.frames, key=lambda f: f.first_ns or f.complete_ns):
            if f.dir == C2S:
                pending.setdefault(f.conn, []).append((len(out), f))
                out.append(RecordedExchange(conn=f.conn, request=f, reply=None))
                continue
            waiting = pending.get(f.conn, [])
            pick = next(
                (k for k, (_, r) in enumerate(waiting) if r.cnt == f.cnt and r.cmd_id == f.cmd_id),
                None,
            )
            if pick is None:
                pick = next((k for k, (_, r) in enumerate(waiting) if r.cmd_id == f.cmd_id), None)
            if pick is None:
                out.append(RecordedExchange(conn=f.conn, request=None, reply=f))
                continue
            idx, req = waiting.pop(pick)
            out[idx] = RecordedExchange(conn=f.conn, request=req, reply=f)
        return [e for e in out if e is not None]


def _iter_tolerant(stream: IO[bytes]) -> Iterator[tuple[Any, str]]:
    """MCAP records in file order; stops (with a reason) where an unfinished file breaks off."""
    from mcap.stream_reader import StreamReader

    reader = StreamReader(stream, record_size_limit=1 << 30)
    it = reader.records
    while True:
        try:
            rec = next(it)
        except StopIteration:
            return
        except Exception as e:  # truncated record, bad chunk, missing magic: the file ends here
            yield None, f"{type(e).__name__}: {e}" if str(e) else type(e).__name__
            return
        yield rec, ""


def read_recording(path: str | os.PathLike[str]) -> Recording:
    """Read a recording, finished or not (an unfinished one reads up to its last whole chunk)."""
    from mcap.records import Channel, Footer, Message, Metadata, Schema

    from ..errors import RecordingError

    p = os.fspath(path)
    frames: list[FrameRecord] = []
    problems: list[ProblemRecord] = []
    conns: list[ConnectionRecord] = []
    metadata: dict[str, str] = {}
    topics: dict[int, str] = {}
    complete = False
    truncated = ""
    try:
        f = open(p, "rb")  # noqa: SIM115
    except FileNotFoundError:
        raise RecordingError(f"no such recording: {p}", path=str(p)) from None
    with f:
        head = f.read(8)
        if head != b"\x89MCAP0\r\n":
            raise RecordingError(f"{p} is not an MCAP file", path=str(p))
        f.seek(0)
        for rec, why in _iter_tolerant(f):
            if rec is None:
                truncated = why
                break
            if isinstance(rec, Schema):
                continue
            if isinstance(rec, Channel):
                topics[rec.id] = rec.topic
            elif isinstance(rec, Message):
                topic = topics.get(rec.channel_id)
                if topic is None:
                    continue
                try:
                    doc = json.loads(rec.data)
                    if topic in (TOPIC_C2S, TOPIC_S2C):
                        if isinstance(doc.get("cnt"), list):
                            frames += FrameBatch.from_json(doc).records()
                        else:  # layout 1: one frame a message
                            frames.append(FrameRecord.from_json(doc))
                    elif topic == TOPIC_PROBLEMS:
                        problems.append(ProblemRecord.from_json(doc))
                    elif topic == TOPIC_CONNECTIONS:
                        conns.append(ConnectionRecord.from_json(doc))
                except (ValueError, KeyError, TypeError):
                    continue  # a foreign message on our topic: not ours to judge
            elif isinstance(rec, Metadata) and rec.name == METADATA_NAME and not metadata:
                metadata = dict(rec.metadata)
            elif isinstance(rec, Footer):
                complete = True
    if not metadata:
        raise RecordingError(
            f"{p} is an MCAP file but not a fairino-conformance recording", path=str(p)
        )
    return Recording(
        path=p,
        metadata=metadata,
        frames=tuple(frames),
        problems=tuple(problems),
        connections=tuple(conns),
        complete=complete,
        truncated=truncated,
    )
