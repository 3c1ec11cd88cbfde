"""A synthetic fleet: robots x firmwares x frames as MCAP recordings, with injected faults.

    python tools/synth_fleet.py OUT --robots 20 --firmwares 3.8.2,3.9.5,3.9.8 --frames 1000000
    python tools/synth_fleet.py OUT --refusal r03/3.9.8/201 --timeout r07/3.8.2/214 \\
        --slow r11/3.9.5/212 --bad r05/3.9.8/682

One recording per robot and firmware (``OUT/<robot>/fw-<firmware>.mcap``, metadata
``robot`` and ``upstream``), written with the kit's own :class:`RecordingWriter` in its
layout: each connection asks ``GetSoftwareVersion()`` (905) first, whose reply names the
firmware, then cycles through the requests of :data:`SESSION` in pipelined bursts (a
burst's requests, then their replies, as a pipelining client's traffic is batched).  The
replies are the emulator's (:class:`~conformance.twin.controller.Controller` answering each request
once; the CNT is then the request's), so the traffic has the emulator's shapes.

Faults (``ROBOT/FIRMWARE/CMD_ID``; ``*`` for any robot or firmware), each on a fifth of
that command's requests: ``--refusal`` (the reply is error code 14), ``--timeout`` (no
reply), ``--slow`` (the reply 250 ms late instead of about 1 ms), ``--bad`` (the reply's
DATA is ``x``, which no return value reads: a FAIL), ``--cnt`` (the reply's CNT is one more
than the request's: ``bad_cnt``, a FAIL).

``--inject garbage,flaws`` (every recording; each frame then at its offset in its stream):
``garbage``, the controller's bytes that are no frame (a ``malformed`` problem) ahead of
every :data:`GARBAGE_EVERY`-th burst's replies and after each connection's last reply;
``flaws``, every :data:`FLAW_EVERY`-th request's LEN two more than its DATA's bytes
(``len_mismatch`` in its frame batch); ``bad_message``, a frame batch that does not read
after the first burst (the reader skips it and names it as damage).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from conformance.protocol.decoder import decode_all  # noqa: E402
from conformance.protocol.frame import Frame, encode_frame  # noqa: E402
from conformance.recording.batch import FrameBatcher  # noqa: E402
from conformance.recording.layout import BATCH_FRAMES, C2S, S2C, TOPIC_FRAMES  # noqa: E402
from conformance.recording.records import ConnectionRecord, Frames, ProblemRecord  # noqa: E402
from conformance.recording.writer import RecordingWriter, default_metadata  # noqa: E402
from conformance.spec.commands import available_spec_versions, load_spec_version  # noqa: E402
from conformance.spec.firmware import version_tuple  # noqa: E402
from conformance.twin.controller import Controller  # noqa: E402

#: The requests each connection cycles through after its 905 (CMD_ID, DATA).
SESSION: tuple[tuple[int, str], ...] = (
    (212, "GetDI(0,0)"),
    (214, "GetAI(0,0)"),
    (201, 'MoveJ("P1")'),
    (212, "GetDI(1,0)"),
    (214, "GetAI(1,0)"),
    (682, "GetAxleExtIOConfig()"),
    (201, 'MoveJ("P2")'),
)
KINDS = ("refusal", "timeout", "slow", "bad", "cnt")
#: A fault hits every FAULT_EVERY-th request of its command.
FAULT_EVERY = 5
BURST = 64
FRAMES_PER_CONNECTION = 200_000
START_NS = 1_767_225_600_000_000_000  # 2026-01-01T00:00:00Z


@dataclass(frozen=True)
class Fault:
    kind: str
    robot: str
    firmware: str
    cmd_id: int

    def hits(self, robot: str, firmware: str) -> bool:
        return self.robot in ("*", robot) and self.firmware in ("*", firmware)


def parse_fault(kind: str, text: str) -> Fault:
    parts = text.split("/")
    if len(parts) != 3 or not parts[2].isdigit():
        raise SystemExit(f"--{kind} {text}: give ROBOT/FIRMWARE/CMD_ID (e.g. r03/3.9.8/201)")
    return Fault(kind, parts[0], parts[1], int(parts[2]))


def spec_for(firmware: str) -> str:
    """The newest shipped spec set not newer than ``firmware`` (else the oldest)."""
    fw = version_tuple(firmware) or (0,)
    known = sorted(available_spec_versions(), key=lambda v: version_tuple(v) or (0,))
    fit = [v for v in known if (version_tuple(v) or (0,)) <= fw]
    return (fit or known)[-1]


def reply_data(firmware: str) -> dict[tuple[int, str], str]:
    """The emulator's reply DATA to each request of the session (and to 905)."""
    ctl = Controller(load_spec_version(spec_for(firmware)))
    out = {}
    for cid, data in ((905, "GetSoftwareVersion()"), *SESSION):
        frames = [
            e
            for a in ctl.answer(Frame(cnt=1, cmd_id=cid, data=data), "tcp")
            for e in decode_all(a.data)
            if isinstance(e, Frame)
        ]
        out[(cid, data)] = frames[0].data if frames else "0"
    # 6.1.4: the web version names the firmware.
    out[(905, "GetSoftwareVersion()")] = f"FR5-V1-001(V6.0),v{firmware},V3.7.77"
    return out


#: What ``--inject`` may name (see the module).
INJECT = ("garbage", "flaws", "bad_message")
#: The controller's garbage (injected), and how often: every this many bursts.
GARBAGE = b"\x00junk\xff"
GARBAGE_EVERY = 8
#: Every this many requests' LEN is off (injected ``flaws``).
FLAW_EVERY = 50


def _bad_message(w: RecordingWriter, t: int) -> None:
    """A frame batch that does not read (cut inside a field), written among the frames
    (injected ``bad_message``: the reader skips it and names it as damage)."""
    w.flush()
    w._mcap.add_message(w._channels[TOPIC_FRAMES], t, b"\x12\x05ab", t, 0)


def _off(cnt: int, cmd_id: int, data: str) -> bytes:
    """A frame whose LEN is two more than its DATA's bytes (2.1: ``len_mismatch``)."""
    return b"/f/bIII%dIII%dIII%dIII%sIII/b/f" % (cnt, cmd_id, len(data.encode()) + 2, data.encode())


def _batch(
    held: FrameBatcher,
    conn: int,
    direction: str,
    rows: Sequence[tuple[int, int, str, int, bytes]],
    at: dict[str, int] | None = None,
) -> None:
    """rows: (cnt, cmd_id, data, t_ns, raw), added to ``held``.  ``at``: each direction's
    stream offset (the frames placed there, it moved past them; else every offset 0); a
    frame whose raw LEN is not its DATA's (:func:`_off`) has its LEN and ``len_mismatch``."""
    sizes = [len(r[4]) for r in rows]
    offsets = [0] * len(rows)
    if at is not None:
        start = at[direction]
        offsets = [start + sum(sizes[:k]) for k in range(len(rows))]
        at[direction] = start + sum(sizes)
    lengths = [len(r[2].encode()) for r in rows]
    bad = [r[4] == _off(*r[:3]) for r in rows]
    if any(bad):
        lengths = [n + 2 if b else n for n, b in zip(lengths, bad, strict=True)]
    held.extend(
        Frames(
            streams=[(conn, "tcp", direction)],  # type: ignore[list-item]
            stream=[0] * len(rows),
            cnt=[r[0] for r in rows],
            cmd_id=[r[1] for r in rows],
            name=[None] * len(rows),
            data=[r[2] for r in rows],
            length=lengths,
            offset=offsets,
            first_ns=[r[3] for r in rows],
            complete_ns=[r[3] for r in rows],
            size=sizes,
            raw=b"".join(r[4] for r in rows),
            problems=[("len_mismatch",) if b else () for b in bad] if any(bad) else None,
        )
    )


def _garbage(conn: int, at: dict[str, int], t_ns: int) -> ProblemRecord:
    """The controller's garbage at its stream's offset (moved past it), read at ``t_ns``."""
    offset = at[S2C]
    at[S2C] += len(GARBAGE)
    return ProblemRecord(
        conn=conn,
        dir=S2C,
        kind="malformed",
        rule="garbage",
        detail=f"{len(GARBAGE)} bytes that are not a frame",
        size=len(GARBAGE),
        complete_ns=t_ns,
        first_ns=t_ns,
        offset=offset,
        raw=GARBAGE,
    )


def write_recording(
    path: Path,
    robot: str,
    firmware: str,
    frames: int,
    faults: Sequence[Fault],
    start_ns: int,
    *,
    chunk_size: int = 1 << 20,
    batch_frames: int | None = None,
    inject: Sequence[str] = (),
    per_connection: int | None = None,
) -> int:
    """One robot's recording on one firmware: ``frames`` frames (requests and replies);
    returns how many were written.  ``chunk_size``, ``batch_frames``: the MCAP chunks' size
    and the frames a message holds at most (small: many chunks and messages in a small file); ``inject``:
    of :data:`INJECT` (see the module); ``per_connection``: the frames of a connection
    (about: its bursts are halved to fit; default :data:`FRAMES_PER_CONNECTION`)."""
    replies = reply_data(firmware)
    mine = {(f.kind, f.cmd_id) for f in faults if f.hits(robot, firmware)}
    encoded: dict[tuple[int, int, str], bytes] = {}

    def raw(cnt: int, cid: int, data: str) -> bytes:
        key = (cnt, cid, data)
        b = encoded.get(key)
        if b is None:
            if len(encoded) > 200_000:
                encoded.clear()
            b = encoded[key] = encode_frame(cnt, cid, data)
        return b

    host = f"10.0.{int(robot.strip('r') or 0) % 250}.{len(firmware)}"
    md = default_metadata(start_ns, robot=robot, upstream=f"{host}:8080", source="synth_fleet")
    path.parent.mkdir(parents=True, exist_ok=True)
    written = 0
    t = start_ns
    conn = 0
    seen: dict[int, int] = {}
    held = FrameBatcher()
    most = batch_frames or BATCH_FRAMES

    with RecordingWriter(path, metadata=md, chunk_size=chunk_size) as w:

        def write(record: ConnectionRecord | ProblemRecord) -> None:
            """A record after the frames held (as the recorder writes them)."""
            if len(held):
                w.write_frames(held.take())
            w.write(record)

        while written < frames:
            conn += 1
            write(
                ConnectionRecord(
                    conn=conn,
                    event="open",
                    t_ns=t,
                    client=f"10.1.0.9:{40000 + conn}",
                    upstream=f"{host}:8080",
                )
            )
            per_conn = min(per_connection or FRAMES_PER_CONNECTION, frames - written)
            cnt = 0
            step = 0
            at: dict[str, int] | None = {C2S: 0, S2C: 0} if inject else None
            bursts = 0
            last_reply = t
            while per_conn - 0 > 0 and written < frames:
                reqs: list[tuple[int, int, str, int, bytes]] = []
                reps: list[tuple[int, int, str, int, bytes]] = []
                n = min(BURST, max(1, (frames - written) // 2))
                if per_connection:
                    n = min(n, max(1, per_conn // 2))
                for _ in range(n):
                    cnt = (cnt + 1) % 0x10000
                    cid, data = (
                        (905, "GetSoftwareVersion()")
                        if step == 0
                        else SESSION[(step - 1) % len(SESSION)]
                    )
                    step += 1
                    t += 1_000_000  # a request a millisecond
                    flawed = "flaws" in inject and (written + len(reqs)) % FLAW_EVERY == 0
                    wire = _off(cnt, cid, data) if flawed else raw(cnt, cid, data)
                    reqs.append((cnt, cid, data, t, wire))
                    k = seen[cid] = seen.get(cid, 0) + 1
                    hit = k % FAULT_EVERY == 0
                    if hit and ("timeout", cid) in mine:
                        continue
                    rdata = replies[(cid, data)]
                    late = 800_000 + (cnt % 7) * 50_000
                    if hit and ("refusal", cid) in mine:
                        rdata = "14"
                    if hit and ("bad", cid) in mine:
                        rdata = "x"
                    if hit and ("slow", cid) in mine:
                        late = 250_000_000
                    rcnt = (cnt + 1) % 0x10000 if hit and ("cnt", cid) in mine else cnt
                    reps.append((rcnt, cid, rdata, t + late, raw(rcnt, cid, rdata)))
                _batch(held, conn, C2S, reqs, at)
                written += len(reqs)
                per_conn -= len(reqs)
                if reps and written < frames:
                    reps = reps[: frames - written]
                    bursts += 1
                    if at is not None and "garbage" in inject and bursts % GARBAGE_EVERY == 0:
                        write(_garbage(conn, at, reps[0][3] - 1))  # ahead of a reply
                    _batch(held, conn, S2C, reps, at)
                    if "bad_message" in inject and conn == 1 and bursts == 1:
                        w.write_frames(held.take())
                        _bad_message(w, t)
                    last_reply = max(last_reply, *(r[3] for r in reps))
                    written += len(reps)
                    per_conn -= len(reps)
                if len(held) >= most:
                    w.write_frames(held.take())
            if at is not None and "garbage" in inject:
                write(_garbage(conn, at, last_reply + 1))  # no reply follows
            t += 2_000_000
            write(ConnectionRecord(conn=conn, event="close", t_ns=t, reason="client closed"))
    return written


def write_capture(
    path: Path, robot: str, firmware: str, frames: int, faults: Sequence[Fault], start_ns: int
) -> int:
    """The traffic of :func:`write_recording`'s recording as a pcap capture at ``path``
    (:func:`~conformance.pcap.export_pcap`; each frame at its place in its stream, in
    the order its first byte came); returns the frames written."""
    import dataclasses

    from conformance.pcap.export import export_pcap
    from conformance.recording.reader import read_recording

    mcap = path.with_name(path.name + ".tmp.mcap")
    written = write_recording(mcap, robot, firmware, frames, faults, start_ns)
    rec = read_recording(mcap)
    mcap.unlink()
    at: dict[tuple[int, str], int] = {}
    placed = []
    for f in sorted(rec.frames, key=lambda f: f.first_ns):
        k = (f.conn, f.dir)
        placed.append(dataclasses.replace(f, offset=at.get(k, 0)))
        at[k] = at.get(k, 0) + len(f.raw)
    export_pcap(dataclasses.replace(rec, frames=tuple(placed)), path)
    return written


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("out", help="the directory to write the recordings into")
    ap.add_argument("--robots", type=int, default=20)
    ap.add_argument("--firmwares", default="3.8.2,3.9.5,3.9.8")
    ap.add_argument("--frames", type=int, default=100_000, help="frames per robot and firmware")
    for k in KINDS:
        ap.add_argument(f"--{k}", action="append", default=[], metavar="ROBOT/FW/CMD_ID")
    ap.add_argument("--inject", default="", help=f"of {','.join(INJECT)} (see above)")
    a = ap.parse_args(argv)
    inject = [x for x in a.inject.split(",") if x]
    if set(inject) - set(INJECT):
        raise SystemExit(f"--inject {a.inject}: give some of {','.join(INJECT)}")
    faults = [parse_fault(k, x) for k in KINDS for x in getattr(a, k)]
    firmwares = [f.strip() for f in a.firmwares.split(",") if f.strip()]
    out = Path(a.out)
    t0 = time.perf_counter()
    total = 0
    for i in range(a.robots):
        robot = f"r{i + 1:02d}"
        for j, fw in enumerate(firmwares):
            # A day per firmware: the fleet upgraded on 1 and 2 January.
            start = START_NS + j * 86_400_000_000_000 + i * 1_000_000_000
            total += write_recording(
                out / robot / f"fw-{fw}.mcap", robot, fw, a.frames, faults, start, inject=inject
            )
    dt = time.perf_counter() - t0
    print(
        f"{total} frames in {a.robots * len(firmwares)} recordings, {dt:.1f} s ({total / dt:,.0f} frames/s)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
