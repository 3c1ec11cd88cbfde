"""The last field forms (issue 18), each read as what it is, with its evidence.

* frcobot_ros sends its whole 4096-byte send buffer after each frame: a ServoJ
  shorter than one before it leaves that frame's tail behind the NUL
  (``…III/b/f\\x00000)III/b/f\\x00…``).  Read as ``buffer_tail``, DIALECT naming
  drivers-034 (was ``garbage``, FAIL, every servo cycle).
* frcobot_ros2's StopLine/StopTool send ``/f/bIII7IIIIII0IIIIII/b/f`` (CMD_ID and
  DATA empty).  Read as one frame, CMD_ID 0 with the problem ``empty_cmd_id``,
  FAIL naming the known bug drivers-035, and answered by the emulator (was a
  ``bad_separator`` and ``garbage``, and no reply: the driver blocked in recv).
* whi_arm_interface's ``SetDO(1,1,1)``: three arguments where every manual and SDK
  has four.  A known client bug (drivers-037): still FAIL and refused with 3, the
  message naming it.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conformance.errors import Rule, SpecError
from conformance.judge.judge import Judge
from conformance.judge.stream import Pairing
from conformance.judge.verdict import Direction, Outcome, Reference
from conformance.net.client import Client
from conformance.net.emulator import EmulatorServer
from conformance.protocol.decoder import FrameDecoder, decode_all
from conformance.protocol.frame import Frame, Malformed, encode_frame
from conformance.spec.commands import default_specs
from conformance.spec.dialects import DialectSet, default_dialects, load_dialects
from conformance.twin.controller import Controller

SPECS = default_specs()
DIALECTS = default_dialects()
FIELD = Judge(SPECS, DIALECTS)
BARE = Judge(SPECS)  # no dialects: nothing recorded, nothing named
#: Reply timeout: the test waits on the reply itself, not on the clock.
WAIT = 20.0

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
EMPTY_ID = b"/f/bIII7IIIIII0IIIIII/b/f"
SETDO3 = b"/f/bIII6III204III12IIISetDO(1,1,1)III/b/f"


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


# --------------------------------------------------------------------------- the empty ID


def test_an_empty_cmd_id_is_one_frame() -> None:
    (f,) = decode_all(EMPTY_ID)
    assert isinstance(f, Frame)
    assert (f.cnt, f.cmd_id, f.data, f.length) == (7, 0, "", 0)
    assert f.problems == (Rule.EMPTY_CMD_ID,)
    assert f.raw == EMPTY_ID
    # Not the old reading: no bad_separator, no garbage.
    assert byte_at_a_time(EMPTY_ID) == [f]
    # Between other frames, the frames around it are read as before.
    around = decode_all(SHORT + EMPTY_ID + SHORT)
    assert [type(e).__name__ for e in around] == ["Frame"] * 3
    # The strict reading makes it one Malformed event, saying what it is.
    (m,) = decode_all(EMPTY_ID, strict=True)
    assert isinstance(m, Malformed) and m.rule is Rule.EMPTY_CMD_ID
    assert "ID=empty" in m.detail


def test_an_empty_cmd_id_with_data_is_read_by_len() -> None:
    (f,) = decode_all(b"/f/bIII9IIIIII5IIIHelloIII/b/f")
    assert isinstance(f, Frame) and (f.cmd_id, f.data, f.problems) == (
        0,
        "Hello",
        (Rule.EMPTY_CMD_ID,),
    )
    assert FIELD.request(f).message.startswith("empty CMD_ID (known client bug drivers-035")


def test_the_empty_id_frame_is_judged_for_what_it_is() -> None:
    (f,) = decode_all(EMPTY_ID)
    assert isinstance(f, Frame)
    v = FIELD.request(f, transport="tcp")
    assert v.outcome is Outcome.FAIL and v.rule == "empty_cmd_id"
    assert [x.rule for x in v.findings] == ["empty_cmd_id"]  # no unknown command 0
    assert v.message.startswith("empty CMD_ID and DATA (known client bug drivers-035 (")
    assert "also drivers-036" in v.message
    assert v.source == "manual 1.1" and v.dialect is None
    assert BARE.request(f).message == "empty CMD_ID and DATA"
    # The strict reading's event gets the same words.
    (m,) = decode_all(EMPTY_ID, strict=True)
    assert isinstance(m, Malformed)
    mv = FIELD.malformed(m, Direction.REQUEST)
    assert mv.outcome is Outcome.FAIL and "known client bug drivers-035" in mv.message


def test_the_emulator_refuses_the_empty_id_frame() -> None:
    (reply,) = replies(Controller(SPECS), EMPTY_ID)
    assert (reply.cnt, reply.cmd_id, reply.problems) == (7, 0, ())
    (req,) = decode_all(EMPTY_ID)
    assert isinstance(req, Frame)
    rv = FIELD.reply(reply, req, transport="tcp")
    assert rv.refused and rv.outcome is Outcome.PASS, rv.message
    # decode --dir auto pairs them: the request is a request, the reply its reply.
    pairing = Pairing(FIELD)
    assert pairing.judge_frame(req).direction is Direction.REQUEST
    assert pairing.judge_frame(reply).direction is Direction.REPLY


def test_a_driver_sending_it_gets_a_reply() -> None:
    """The driver waits in recv() after sending: the emulator's reply releases it."""
    with EmulatorServer() as emu:
        c = Client(*emu.address, transport="tcp", timeout=WAIT)
        try:
            c.send_raw(EMPTY_ID)
            ex = c.await_reply(7, 0, request=EMPTY_ID, timeout=WAIT)
            assert ex.reply is not None and ex.reply.data == "robot errcode:14"
            # The connection goes on: the next call is answered as usual.
            c.send_raw(encode_frame(8, 204, "SetDO(1,1,0,0)"))
            nxt = c.await_reply(8, 204, timeout=WAIT)
            assert nxt.reply is not None and nxt.reply.data == "1"
        finally:
            c.close()


# --------------------------------------------------------------------------- SetDO(1,1,1)


def test_a_three_argument_setdo_is_a_known_client_bug() -> None:
    f = decode_all(SETDO3)[0]
    assert isinstance(f, Frame)
    v = FIELD.request(f, transport="tcp")
    assert v.outcome is Outcome.FAIL and v.rule == "arg_count"
    assert v.message.startswith("3 arguments, table 3-1-1 lists 4 (known client bug drivers-037")
    assert "whi_arm_interface@1554b2d614 src/sdk/arm_hardware_fair.cpp:508" in v.message
    assert v.dialect is None and v.findings[0].dialect == "drivers-037"
    assert BARE.request(f).message == "3 arguments, table 3-1-1 lists 4"
    # The manual's four arguments pass; the entry matches nothing else.
    four = decode_all(encode_frame(6, 204, "SetDO(1,1,1,0)"))[0]
    assert isinstance(four, Frame)
    assert FIELD.request(four).outcome is Outcome.PASS


def test_the_emulator_refuses_it_with_3() -> None:
    (reply,) = replies(Controller(SPECS), SETDO3)
    assert (reply.cnt, reply.cmd_id, reply.data) == (6, 204, "3")


# --------------------------------------------------------------------------- the data


def test_the_entries_cite_their_evidence() -> None:
    tail = DIALECTS.get("drivers-034")
    assert tail is not None and tail.kind == "framing" and tail.rule == "buffer_tail"
    assert not tail.defect
    e = tail.evidence[0]
    assert (e.repo, e.line, e.commit[:10]) == ("FAIR-INNOVATION/frcobot_ros", 91, "04b24d4a17")
    # Its example is a frame and the tail, as the driver sends it (padding cut).
    events = decode_all(tail.example.encode())
    assert [e.rule for e in events if isinstance(e, Malformed)] == [Rule.BUFFER_TAIL]
    for eid, name in (("drivers-035", "StopLine"), ("drivers-036", "StopTool")):
        d = DIALECTS.get(eid)
        assert d is not None and d.defect and d.rule == "empty_cmd_id" and d.name == name
        (f,) = decode_all(d.example.encode())
        assert isinstance(f, Frame) and f.problems == (Rule.EMPTY_CMD_ID,)
    setdo = DIALECTS.get("drivers-037")
    assert setdo is not None and setdo.defect and setdo.kind == "arguments"
    assert [p.name for p in setdo.params or ()] == ["nIO", "bopen", "smooth"]
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
