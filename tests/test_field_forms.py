"""The last field forms (issue 18), each read as what it is, with its evidence.

* frcobot_ros sends its whole 4096-byte send buffer after each frame: a ServoJ
  shorter than one before it leaves that frame's tail behind the NUL
  (``…III/b/f\\x00000)III/b/f\\x00…``).  Read as ``buffer_tail``, DIALECT naming
  drivers-034 (was ``garbage``, FAIL, every servo cycle).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conformance.dialects import DialectSet, default_dialects, load_dialects
from conformance.errors import Rule, SpecError
from conformance.frame import Frame, FrameDecoder, Malformed, decode_all
from conformance.judge import Direction, Judge, Reference
from conformance.model import Controller
from conformance.report import Outcome
from conformance.spec import default_specs

SPECS = default_specs()
DIALECTS = default_dialects()
FIELD = Judge(SPECS, DIALECTS)
BARE = Judge(SPECS)  # no dialects: nothing recorded, nothing named

# --------------------------------------------------------------------------- helpers

#: frcobot_ros's send buffer: ``char sendCmdLine[MAXLINE]`` with MAXLINE 4096.
MAXLINE = 4096


def servoj_text(joints: list[float]) -> bytes:
    """The frame frcobot_ros's write() prints: 11 ``%f`` values, CNT 123, ID 376."""
    data = "ServoJ(" + ",".join(f"{x:f}" for x in [*joints, 0, 0, 0.002, 0.002, 0]) + ")"
    return b"/f/bIII123III376III%dIII%sIII/b/f" % (len(data), data.encode())


def sent_buffers(texts: list[bytes]) -> list[bytes]:
    """What the driver sends for each frame: its text and terminating NUL printed into the
    same zeroed buffer, then the whole buffer (``send(confd, buf, sizeof(buf), 0)``)."""
    buf = bytearray(MAXLINE)
    out = []
    for t in texts:
        buf[: len(t) + 1] = t + b"\x00"
        out.append(bytes(buf))
    return out


LONG = servoj_text([-112.5, -95.25, -102.75, -97.5, -90.0, -170.0])
SHORT = servoj_text([2.5, -5.25, 2.75, -7.5, -9.0, 0.0])
MIDDLE = servoj_text([-12.5, -95.25, 102.75, -97.5, -90.0, 0.0])


def byte_at_a_time(raw: bytes) -> list[Frame | Malformed]:
    d = FrameDecoder()
    out: list[Frame | Malformed] = []
    for i in range(len(raw)):
        out += d.feed(raw[i : i + 1])
    return out + d.close()


def replies(ctl: Controller, raw: bytes) -> list[Frame]:
    conn = ctl.connection(transport="tcp")
    acts = conn.receive(raw) + conn.close()
    return [f for a in acts if a.data for f in decode_all(a.data) if isinstance(f, Frame)]


# --------------------------------------------------------------------------- the buffer tail


def test_a_shorter_servoj_leaves_a_buffer_tail_not_garbage() -> None:
    stream = b"".join(sent_buffers([LONG, SHORT]))
    events = decode_all(stream)
    assert [type(e).__name__ for e in events] == ["Frame", "Malformed", "Frame", "Malformed"]
    first, second = events[1], events[3]
    assert isinstance(first, Malformed) and isinstance(second, Malformed)
    # After the first frame the buffer held nothing else: NUL padding, as before.
    assert first.rule is Rule.NUL_PADDING
    # After the shorter one: its NUL, the longer frame's last 11 bytes, NULs to 4096.
    assert second.rule is Rule.BUFFER_TAIL, second
    assert second.raw.startswith(b"\x00000)III/b/f\x00")
    assert len(SHORT) + len(second.raw) == MAXLINE
    assert "11 bytes of earlier frames' text" in second.detail
    # The old reading is gone.
    assert all(not (isinstance(e, Malformed) and e.rule is Rule.GARBAGE) for e in events)
    assert byte_at_a_time(stream) == events


def test_the_buffer_tail_is_the_drivers_dialect() -> None:
    (_, _, _, tail) = decode_all(b"".join(sent_buffers([LONG, SHORT])))
    assert isinstance(tail, Malformed)
    v = FIELD.malformed(tail, Direction.REQUEST)
    assert v.outcome is Outcome.DIALECT and v.rule == "buffer_tail"
    assert v.dialect is not None and v.dialect.id == "drivers-034"
    assert v.source.startswith("drivers-034 (FAIR-INNOVATION/frcobot_ros@04b24d4a17")
    assert "follows field dialect drivers-034" in v.message
    # A recorded habit: no failure under the field reference, strict or not (NON-STRICT at
    # most), a failure under the manual alone.
    assert not v.fails(Reference.FIELD) and not v.fails(Reference.FIELD, strict=True)
    assert v.fails(Reference.MANUAL)
    assert v.to_json()["dialect"] == "drivers-034"
    # With no recorded source it is read as bytes that are not a frame: FAIL.
    assert BARE.malformed(tail, Direction.REQUEST).outcome is Outcome.FAIL


def test_stale_text_of_several_earlier_frames() -> None:
    """Long, middle, short: the buffer holds pieces of both earlier frames, each running
    to its frame's end, NULs between."""
    stream = b"".join(sent_buffers([LONG, MIDDLE, SHORT]))
    events = decode_all(stream)
    tail = events[-1]
    assert isinstance(tail, Malformed) and tail.rule is Rule.BUFFER_TAIL
    pieces = [p for p in tail.raw.split(b"\x00") if p]
    assert len(pieces) == 2 and all(p.endswith(b"/b/f") for p in pieces)
    assert [type(e).__name__ for e in events].count("Frame") == 3
    assert byte_at_a_time(stream) == events


@pytest.mark.parametrize(
    ("after", "rule"),
    [
        (b"\x00" * 40, Rule.NUL_PADDING),  # pure NULs stay NUL padding
        (b"\x00f\x00\x00", Rule.BUFFER_TAIL),  # one byte left of an earlier frame
        (b"\x00b/f\x00", Rule.BUFFER_TAIL),
        (b"\x00000)III/b/f", Rule.BUFFER_TAIL),  # up to the end of the buffer
        (b"\x00hello\x00\x00", Rule.GARBAGE),  # text that is no frame's end
        (b"x\x00III/b/f\x00", Rule.GARBAGE),  # no terminating NUL first
        (b"\x00III/b/f\x00junk", Rule.GARBAGE),
    ],
)
def test_what_counts_as_a_buffer_tail(after: bytes, rule: Rule) -> None:
    events = decode_all(SHORT + after + SHORT)
    (m,) = [e for e in events if isinstance(e, Malformed)]
    assert m.rule is rule, m
    assert len([e for e in events if isinstance(e, Frame)]) == 2


def test_only_right_after_a_frame() -> None:
    """The same bytes after garbage, or before any frame, are no buffer's rest."""
    tail = b"\x00000)III/b/f\x00\x00"
    (m,) = [e for e in decode_all(tail + SHORT) if isinstance(e, Malformed)]
    assert m.rule is Rule.GARBAGE
    events = decode_all(SHORT + b"/f/bIIIxx" + tail + SHORT)
    assert Rule.BUFFER_TAIL not in [e.rule for e in events if isinstance(e, Malformed)]


def test_the_emulator_answers_each_servoj_and_not_the_tail() -> None:
    got = replies(Controller(SPECS), b"".join(sent_buffers([LONG, SHORT, MIDDLE])))
    assert [(f.cnt, f.cmd_id, f.data) for f in got] == [(123, 376, "1")] * 3


# --------------------------------------------------------------------------- the data


def test_the_entries_cite_their_evidence() -> None:
    tail = DIALECTS.get("drivers-034")
    assert tail is not None and tail.kind == "framing" and tail.rule == "buffer_tail"
    e = tail.evidence[0]
    assert (e.repo, e.line, e.commit[:10]) == ("FAIR-INNOVATION/frcobot_ros", 91, "04b24d4a17")
    # Its example is a frame and the tail, as the driver sends it (padding cut).
    events = decode_all(tail.example.encode())
    assert [e.rule for e in events if isinstance(e, Malformed)] == [Rule.BUFFER_TAIL]
    assert DIALECTS.by_rule("buffer_tail") == (tail,)


def _write(tmp: Path, entry: dict[str, object]) -> None:
    base: dict[str, object] = {
        "id": "t-001",
        "kind": "framing",
        "cmd_id": 376,
        "name": "ServoJ",
        "form": "bytes",
        "rule": "buffer_tail",
        "transport": ["tcp"],
        "example": "/f/bIII1III376III3IIIx()III/b/f",
        "evidence": [{"repo": "a/b", "path": "x.c", "commit": "0" * 40, "line": 3}],
        "note": "n",
    }
    base.update(entry)
    doc = {
        "kind": "dialects",
        "spec_version": "3.8.2",
        "source": {"name": "t", "summary": "test"},
        "entries": [{k: v for k, v in base.items() if v is not None}],
    }
    (tmp / "t.json").write_text(json.dumps(doc), encoding="utf-8")


@pytest.mark.parametrize(
    ("change", "error"),
    [
        ({"rule": None}, "kind 'framing' goes with form 'bytes' and a 'rule'"),
        ({"form": "text", "pattern": "x"}, "kind 'framing' goes with form 'bytes'"),
        ({"kind": "command", "safety": "query"}, "kind 'framing' goes with form 'bytes'"),
        ({"rule": "no_such_rule"}, "'no_such_rule' is no rule of the decoder"),
    ],
)
def test_framing_entries_are_checked(tmp_path: Path, change: dict[str, object], error: str) -> None:
    _write(tmp_path, change)
    with pytest.raises(SpecError, match=error):
        load_dialects(tmp_path, SPECS)


def test_a_framing_entry_of_ones_own_is_read(tmp_path: Path) -> None:
    _write(tmp_path, {})
    ds = load_dialects(tmp_path, SPECS)
    assert isinstance(ds, DialectSet) and ds.by_rule("buffer_tail")[0].id == "t-001"
    tail = decode_all(SHORT + b"\x00/f\x00" + SHORT)[1]
    assert isinstance(tail, Malformed)
    v = Judge(SPECS, ds).malformed(tail, Direction.REQUEST)
    assert v.outcome is Outcome.DIALECT and "t-001" in v.source
