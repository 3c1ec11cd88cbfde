"""The SDKs' channels in a recording, sans-I/O: XML-RPC calls (20003), CNDE frames (20005)
and realtime packets (20004) through the one recorder (StreamRecorder) into the one layout,
read back by the one reader.

Each channel's bytes are put back from what the recording holds (the records' bytes and the
problems' at their stream offsets) and must be the bytes fed, whatever the chunking and
whatever garbage is among them: nothing is lost, nothing made up.
"""

from __future__ import annotations

import io
import itertools
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conformance.protocol.cnde import (
    CndeType,
    OutputConfig,
    encode_cnde,
    encode_message,
    encode_output_config,
)
from conformance.protocol.http import encode_response
from conformance.protocol.state import encode_state
from conformance.recording.layout import (
    C2S,
    CALL_SCHEMA,
    CHANNEL_SCHEMAS,
    S2C,
    TOPIC_CALLS,
    TOPIC_CNDE,
)
from conformance.recording.reader import RecordingReader, read_recording
from conformance.recording.recorder import StreamRecorder
from conformance.recording.records import CallRecord, value_from_json, value_to_json
from conformance.recording.writer import RecordingWriter
from conformance.recording.xmlrpc_stream import MAX_WAITING
from conformance.spec.cnde import cnde_catalogue
from conformance.spec.realtime import realtime_layout

from .examples import examples
from .sdk_messages import MOVEJ, call, fault, reply

HOST = "127.0.0.1:20003"


def record(
    path: Path, stream: str, reads: Sequence[tuple[str, bytes]], *, close: bool = True
) -> Any:
    """``reads`` (direction, bytes) fed to one connection of ``stream``, in order."""
    with RecordingWriter(path) as w:
        rec = StreamRecorder(w)
        rec.open(1, t_ns=1_000, stream=stream, client="127.0.0.1:4000", upstream=HOST)
        t = 2_000
        for d, data in reads:
            rec.data(1, d, t, data)  # type: ignore[arg-type]
            t += 1_000
        if close:
            rec.close(1, t_ns=t, reason="client closed")
        rec.write_held()
    return read_recording(path)


def put_back(rec: Any, direction: str) -> bytes:
    """One direction's bytes as the recording holds them, at their offsets."""
    pieces: list[tuple[int, bytes]] = []
    for c in rec.calls:
        if direction == C2S and c.request_raw:
            pieces.append((c.request_offset, c.request_raw))
        if direction == S2C and c.reply_raw:
            pieces.append((c.reply_offset, c.reply_raw))
    pieces += [(f.offset, f.raw) for f in rec.cnde if f.dir == direction]
    pieces += [(s.offset, s.raw) for s in rec.realtime if direction == S2C]
    pieces += [(p.offset, p.raw) for p in rec.channel_problems if p.dir == direction and p.raw]
    out = bytearray()
    for offset, raw in sorted(pieces):
        assert offset == len(out), f"a hole or an overlap at {offset} (have {len(out)})"
        out += raw
    return bytes(out)


def chunked(data: bytes, cuts: list[int]) -> list[bytes]:
    at = sorted({c % (len(data) + 1) for c in cuts} | {0, len(data)})
    return [data[a:b] for a, b in itertools.pairwise(at) if b > a]


SESSION_C2S = [
    call("GetControllerIP"),
    call("MoveJ", *MOVEJ),
    call("GetActualJointPosDegree", 1),
    b"POST /RPC2 HTTP/1.1\r\nContent-Length: 9\r\n\r\n<bad xml>",
]
SESSION_S2C = [
    reply([0, "127.0.0.1"]),
    reply(0),
    reply([0, 10.0, -80.0, 95.0, -100.0, -90.0, 5.0]),
    fault(-503, "xmlrpc_syntax"),
]


# --------------------------------------------------------------------------- XML-RPC


def test_calls_are_records_with_both_sides_and_their_bytes(tmp_path: Path) -> None:
    reads = [r for q, p in zip(SESSION_C2S, SESSION_S2C, strict=True) for r in ((C2S, q), (S2C, p))]
    rec = record(tmp_path / "s.mcap", "xmlrpc", reads)
    assert not rec.damage
    assert [(c.seq, c.method, c.reply) for c in rec.calls] == [
        (1, "GetControllerIP", "value"),
        (2, "MoveJ", "value"),
        (3, "GetActualJointPosDegree", "value"),
        (4, None, "fault"),
    ]
    movej = rec.calls[1]
    assert movej.params == MOVEJ and movej.value == 0 and movej.http == "POST /RPC2 HTTP/1.1"
    assert movej.request_raw == SESSION_C2S[1] and movej.reply_raw == SESSION_S2C[1]
    assert movej.request_ns is not None and movej.reply_ns is not None
    assert movej.latency_ns == movej.reply_ns - movej.request_ns > 0
    bad = rec.calls[3]
    assert bad.request_error is not None and bad.request_error[0] == "xmlrpc_syntax"
    assert (bad.fault_code, bad.fault_string) == (-503, "xmlrpc_syntax")
    assert put_back(rec, C2S) == b"".join(SESSION_C2S)
    assert put_back(rec, S2C) == b"".join(SESSION_S2C)
    closes = [c for c in rec.connections if c.event == "close"]
    assert closes[0].stream == "xmlrpc" and (closes[0].frames_c2s, closes[0].frames_s2c) == (4, 4)


@settings(max_examples=examples(50), deadline=None)
@given(
    cuts=st.lists(st.integers(0, 5000), max_size=12),
    junk=st.binary(max_size=40),
    where=st.integers(0, 3),
)
def test_any_chunking_and_garbage_loses_nothing(
    tmp_path_factory: pytest.TempPathFactory, cuts: list[int], junk: bytes, where: int
) -> None:
    """The same calls in any chunking give the same records; bytes that break HTTP in the
    middle are kept from there on; and every byte is in the recording at its offset."""
    c2s = b"".join(SESSION_C2S[:where]) + junk + b"".join(SESSION_C2S[where:])
    s2c = b"".join(SESSION_S2C)
    reads = [(C2S, x) for x in chunked(c2s, cuts)] + [(S2C, x) for x in chunked(s2c, cuts)]
    rec = record(tmp_path_factory.mktemp("c") / "c.mcap", "xmlrpc", reads)
    assert put_back(rec, C2S) == c2s
    assert put_back(rec, S2C) == s2c
    methods = [c.method for c in rec.calls if c.has_request]
    # Empty lines before a request line are read as nothing (RFC 9112, 2.2: CRLFs, then LFs).
    rest = junk
    while rest[:2] == b"\r\n":
        rest = rest[2:]
    rest = rest.lstrip(b"\n")
    if not rest:
        assert methods == ["GetControllerIP", "MoveJ", "GetActualJointPosDegree", None]
    else:  # the calls before the junk are whole; the junk is a problem or a broken call
        assert (
            methods[:where] == ["GetControllerIP", "MoveJ", "GetActualJointPosDegree", None][:where]
        )


def test_a_huge_body_is_a_problem_kept_whole_and_its_refusal_pairs(tmp_path: Path) -> None:
    head = b"POST /RPC2 HTTP/1.1\r\nContent-Length: 9999999999\r\n\r\n"
    body = b"x" * (200 * 1024)
    refusal = encode_response(413, "Content Too Large", b"too large\n", keep_alive=False)
    rec = record(tmp_path / "h.mcap", "xmlrpc", [(C2S, head), (C2S, body), (S2C, refusal)])
    (c,) = rec.calls
    assert c.request_error is not None and c.request_error[0] == "http_limit"
    assert (
        c.reply == "error"
        and c.status == 413
        and c.reply_error == ("http_status", "HTTP 413 Content Too Large")
    )
    kept = [p for p in rec.channel_problems if p.rule == "http_limit"]
    assert sum(p.size for p in kept) == len(head) + len(body)
    assert all(p.size <= 64 * 1024 for p in kept)  # in pieces: each record stays small
    assert put_back(rec, C2S) == head + body


def test_a_call_cut_by_the_close_is_a_truncated_problem_and_a_missing_reply(tmp_path: Path) -> None:
    whole = call("GetDI", 0, 0)
    rec = record(tmp_path / "t.mcap", "xmlrpc", [(C2S, call("GetDO")), (C2S, whole[:-5])])
    (c,) = rec.calls
    assert c.method == "GetDO" and c.reply == "missing" and "closed" in c.detail
    (p,) = rec.channel_problems
    assert p.rule == "truncated" and p.raw == whole[:-5] and p.kind == "xmlrpc"


def test_pipelined_calls_pair_in_order_and_a_flood_of_them_is_bounded(tmp_path: Path) -> None:
    n = MAX_WAITING + 6
    reqs = b"".join(call("GetDI", k, 0) for k in range(n))
    reps = b"".join(reply([0, k]) for k in range(n))
    rec = record(tmp_path / "p.mcap", "xmlrpc", [(C2S, reqs), (S2C, reps)])
    whole = [c for c in rec.calls if c.has_request and c.has_reply]
    assert [(c.params, c.value) for c in whole] == [((k, 0), [0, k]) for k in range(6, n)]
    early = [c for c in rec.calls if c.reply == "separate"]
    alone = [c for c in rec.calls if not c.has_request]
    assert [c.seq for c in early] == [c.seq for c in alone] == list(range(1, 7))
    assert [c.value for c in alone] == [[0, k] for k in range(6)]
    assert put_back(rec, C2S) == reqs and put_back(rec, S2C) == reps


def test_a_gap_ends_the_pairing_honestly(tmp_path: Path) -> None:
    with RecordingWriter(tmp_path / "g.mcap") as w:
        rec = StreamRecorder(w)
        rec.open(1, t_ns=1, stream="xmlrpc")
        rec.data(1, C2S, 2, call("GetDO"))
        rec.data(1, C2S, 3, call("GetDI", 0, 0)[:30])
        rec.gap(1, C2S, 4, 50)
        rec.data(1, C2S, 5, b"tail of a lost body" + call("GetDO"))
        rec.data(1, S2C, 6, reply([0, 0, 0]) + reply([0, 1]))
        rec.finish(t_ns=9)
    r = read_recording(tmp_path / "g.mcap")
    assert [c.reply for c in r.calls if c.has_request] == ["unknown", "unknown"]
    assert {p.rule for p in r.channel_problems} == {"truncated", "gap", "resync"}
    assert [c.value for c in r.calls if not c.has_request] == [[0, 0, 0], [0, 1]]


def test_calls_whose_replies_were_recorded_undecoded_are_not_missing_replies(
    tmp_path: Path,
) -> None:
    """A proxy that stops while its recorder is behind keeps the rest as undecoded bytes:
    a call whose reply is among them has an unknown reply (``check`` judges none), not a
    missing one (which fails as ``no_reply``)."""
    from conformance.offline.check import check_recording
    from conformance.spec.commands import default_specs

    path = tmp_path / "u.mcap"
    with RecordingWriter(path) as w:
        rec = StreamRecorder(w)
        rec.open(1, t_ns=1, stream="xmlrpc", client="127.0.0.1:4000", upstream=HOST)
        rec.data(1, C2S, 2, call("RobotEnable", 1))
        rec.data(1, S2C, 3, reply(0))
        rec.data(1, C2S, 4, call("Mode", 0))
        rec.stop_decoding("the proxy was stopping")
        rec.data(1, S2C, 5, reply(0))
        rec.data(1, C2S, 6, call("SetSpeed", 20))
        rec.finish(t_ns=9)
    r = read_recording(path)
    assert [(c.method, c.reply) for c in r.calls] == [("RobotEnable", "value"), ("Mode", "unknown")]
    assert "recorded undecoded" in r.calls[1].detail
    assert put_back(r, S2C) == reply(0) + reply(0)  # every byte kept
    report = check_recording(r, default_specs())
    assert not [c.id for c in report.cases if c.outcome.value == "FAIL"]


def test_values_as_json_are_read_back_exactly() -> None:
    v: Any = [1, 2.5, "x", True, None, b"\x00\xff", {"a": [1]}, {"$base64": "not a tag here"}]
    assert value_from_json(json.loads(json.dumps(value_to_json(v)))) == v
    with pytest.raises(ValueError, match="no tagged"):
        value_from_json({"a": 1})


def test_a_call_message_that_does_not_fit_its_schema_is_damage_not_a_crash(tmp_path: Path) -> None:
    path = tmp_path / "d.mcap"
    with RecordingWriter(path) as w:
        rec = StreamRecorder(w)
        rec.open(1, t_ns=1, stream="xmlrpc")
        rec.data(1, C2S, 2, call("GetDO"))
        rec.data(1, S2C, 3, reply([0, 1, 2]))
        rec.write_held()
        w._register(TOPIC_CALLS)
        ch = w._channels[TOPIC_CALLS]
        bad = {"conn": 1, "seq": 2, "method": "X", "reply": "value", "fault_code": -(1 << 40)}
        w._mcap.add_message(
            channel_id=ch, log_time=4, data=json.dumps(bad).encode(), publish_time=4, sequence=9
        )
        w._mcap.add_message(
            channel_id=ch, log_time=5, data=b"{not json", publish_time=5, sequence=10
        )
        rec.finish(t_ns=9)
    r = read_recording(path)
    assert [c.method for c in r.calls] == ["GetDO"]
    assert len(r.damage) == 2
    assert "fault_code" in str(r.damage[0]) and "not JSON" in str(r.damage[1])
    assert CHANNEL_SCHEMAS[CALL_SCHEMA]["properties"]["fault_code"]["minimum"] == -(1 << 31)


def test_a_recording_without_the_channels_has_none_of_their_topics(tmp_path: Path) -> None:
    with RecordingWriter(tmp_path / "n.mcap") as w:
        StreamRecorder(w).finish(t_ns=1)
    from mcap.reader import make_reader

    with open(tmp_path / "n.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        topics = {c.topic for c in summary.channels.values()}
    assert TOPIC_CALLS not in topics and TOPIC_CNDE not in topics


# --------------------------------------------------------------------------- CNDE

NAMES = ("actual_joint_pos", "program_state", "cfg_DO_box")


def cnde_session() -> tuple[bytes, bytes]:
    layout = cnde_catalogue().layout(NAMES)
    c2s = encode_cnde(
        0, CndeType.OUTPUT_CONFIG, encode_output_config(OutputConfig(period_ms=8, names=NAMES))
    )
    c2s += encode_cnde(1, CndeType.START)
    s2c = encode_cnde(0, CndeType.MESSAGE, encode_message(True))
    s2c += encode_cnde(1, CndeType.MESSAGE, encode_message(True))
    for k in range(3):
        values = {"actual_joint_pos": [float(k)] * 6, "program_state": 1, "cfg_DO_box": k}
        s2c += encode_cnde(2 + k, CndeType.OUTPUT_STATE, layout.pack(values))
    return c2s, s2c


def test_cnde_frames_are_read_with_the_configuration_accepted(tmp_path: Path) -> None:
    c2s, s2c = cnde_session()
    rec = record(tmp_path / "c.mcap", "cnde", [(C2S, c2s), (S2C, s2c)])
    kinds = [(f.dir, f.kind) for f in rec.cnde]
    assert kinds[:2] == [(C2S, "OUTPUT_CONFIG"), (C2S, "START")]
    states = [f for f in rec.cnde if f.kind == "OUTPUT_STATE"]
    assert [s.fields["cfg_DO_box"] for s in states] == [0, 1, 2]  # type: ignore[index]
    assert states[2].fields["actual_joint_pos"] == [2.0] * 6  # type: ignore[index]
    assert rec.cnde[0].config == {"period_ms": 8, "names": list(NAMES)}
    assert put_back(rec, C2S) == c2s and put_back(rec, S2C) == s2c


@settings(max_examples=examples(50), deadline=None)
@given(
    cuts=st.lists(st.integers(0, 400), max_size=10),
    junk=st.binary(max_size=30),
    at=st.integers(0, 400),
)
def test_cnde_any_chunking_and_garbage_loses_nothing(
    tmp_path_factory: pytest.TempPathFactory, cuts: list[int], junk: bytes, at: int
) -> None:
    c2s, s2c = cnde_session()
    at = min(at, len(s2c))
    s2c = s2c[:at] + junk + s2c[at:]
    reads = [(C2S, x) for x in chunked(c2s, cuts)] + [(S2C, x) for x in chunked(s2c, cuts)]
    rec = record(tmp_path_factory.mktemp("n") / "n.mcap", "cnde", reads)
    assert put_back(rec, C2S) == c2s
    assert put_back(rec, S2C) == s2c


def test_a_flood_of_frame_heads_is_a_few_problems_not_one_a_byte(tmp_path: Path) -> None:
    flood = b"\x5a" * 5000
    rec = record(tmp_path / "f.mcap", "cnde", [(S2C, flood)])
    assert put_back(rec, S2C) == flood
    assert len(rec.channel_problems) <= 4
    assert any("more like it" in p.detail for p in rec.channel_problems)


def test_a_state_frame_of_another_length_says_so(tmp_path: Path) -> None:
    c2s, s2c = cnde_session()
    s2c += encode_cnde(9, CndeType.OUTPUT_STATE, b"\x00" * 7)
    rec = record(tmp_path / "l.mcap", "cnde", [(C2S, c2s), (S2C, s2c)])
    last = rec.cnde[-1]
    assert last.fields is None and "7 bytes" in last.detail


# --------------------------------------------------------------------------- 20004


def test_realtime_packets_go_to_their_own_topic(tmp_path: Path) -> None:
    lay = realtime_layout("1236")
    packets = [encode_state(lay, {"jt_cur_pos": [float(k)] * 6}, cnt=k) for k in range(3)]
    rec = record(tmp_path / "r.mcap", "realtime", [(S2C, b"".join(packets) + b"\x01\x02")])
    assert [s.cnt for s in rec.realtime] == [0, 1, 2] and not rec.states
    assert rec.realtime[1].fields["jt_cur_pos"] == [1.0] * 6
    assert all(s.version == lay.version and s.checksum_ok for s in rec.realtime)
    assert [p.kind for p in rec.channel_problems] == ["realtime"]
    assert put_back(rec, S2C) == b"".join(packets) + b"\x01\x02"
    reader = RecordingReader(tmp_path / "r.mcap")
    assert sum(1 for x in reader.items() if getattr(x, "realtime", False)) == 3


def test_the_stream_names_are_checked(tmp_path: Path) -> None:
    with RecordingWriter(io.BytesIO()) as w, pytest.raises(ValueError, match="unknown stream"):
        StreamRecorder(w).open(1, t_ns=1, stream="sdk")


def test_the_reply_alone_record_has_no_request(tmp_path: Path) -> None:
    rec = record(tmp_path / "a.mcap", "xmlrpc", [(S2C, reply(0))])
    (c,) = rec.calls
    assert isinstance(c, CallRecord) and not c.has_request and c.value == 0 and c.seq is None


def test_an_unfinished_recording_of_the_channels_is_recovered_whole(tmp_path: Path) -> None:
    """A proxy killed mid-session leaves an unfinished file: recover keeps every call, CNDE
    frame and 20004 packet flushed before (their topics and schemas too)."""
    from conformance.recording.repair import recover

    path = tmp_path / "killed.mcap"
    w = RecordingWriter(path)
    rec = StreamRecorder(w)
    rec.open(1, t_ns=1, stream="xmlrpc")
    for k, (q, p) in enumerate(zip(SESSION_C2S, SESSION_S2C, strict=True)):
        rec.data(1, C2S, 10 + k, q)
        rec.data(1, S2C, 20 + k, p)
    rec.open(2, t_ns=30, stream="cnde")
    c2s, s2c = cnde_session()
    rec.data(2, C2S, 31, c2s)
    rec.data(2, S2C, 32, s2c)
    rec.write_held()
    w.flush()  # then the process dies: no summary, no footer
    w._file.close()  # type: ignore[union-attr]
    result = recover(path, tmp_path / "fixed.mcap")
    assert not result.was_complete
    r = read_recording(tmp_path / "fixed.mcap")
    assert [c.method for c in r.calls] == [
        "GetControllerIP",
        "MoveJ",
        "GetActualJointPosDegree",
        None,
    ]
    assert [f.kind for f in r.cnde].count("OUTPUT_STATE") == 3
