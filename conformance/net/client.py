"""The conformance client: sends frames to a target and pairs replies by CNT and CMD_ID.

Real controllers are noisy peers: a reply is paired with its request by CNT and
CMD_ID, never by arrival order, and frames nobody asked for (such as the
command-ID 500 frames a controller sends when a Lua program fails) are kept as
``unsolicited`` rather than taken for a reply.  Bytes that are not frames come back
as :class:`~conformance.frame.Malformed` events attributed to the wait in which
they arrived.  TCP or UDP; an optional rate limit (frames per second).
"""

from __future__ import annotations

import contextlib
import socket
import time
from dataclasses import dataclass, field
from types import TracebackType

from ..errors import ConformanceError
from ..frame import CNT_MAX, Frame, FrameDecoder, Malformed, decode_all, encode_frame

__all__ = ["Client", "Exchange", "TargetUnreachable"]

_IDLE = 0.05  # silence after which a frame waiting on its LEN is decided on


class TargetUnreachable(ConformanceError):
    """The target refused or did not accept a connection."""


@dataclass(frozen=True, kw_only=True)
class Exchange:
    """One request and what came back while waiting for its reply."""

    request: bytes
    cnt: int
    cmd_id: int
    reply: Frame | None = None
    #: Frames received while waiting that did not pair with this request.
    unsolicited: tuple[Frame, ...] = ()
    #: Bytes that were not frames, received while waiting.
    malformed: tuple[Malformed, ...] = ()
    #: The peer closed the connection while we waited.
    closed: bool = False
    elapsed: float = 0.0
    #: Bytes of an incomplete frame still buffered when the wait ended.
    pending: bytes = field(default=b"", repr=False)

    @property
    def timed_out(self) -> bool:
        return self.reply is None and not self.closed

    def near_misses(self) -> list[Frame]:
        """Unpaired frames that look like a botched reply (same CNT or same CMD_ID)."""
        return [f for f in self.unsolicited if f.cnt == self.cnt or f.cmd_id == self.cmd_id]


class Client:
    """One connection to a target (TCP stream, or UDP datagrams to one address)."""

    def __init__(
        self,
        host: str,
        port: int,
        *,
        transport: str = "tcp",
        timeout: float = 2.0,
        rate: float | None = None,
        connect_timeout: float | None = None,
    ) -> None:
        if transport not in ("tcp", "udp"):
            raise ValueError(f"transport must be tcp or udp, not {transport!r}")
        self.host = host.strip("[]")
        self.port = port
        self.transport = transport
        self.timeout = timeout
        self.connect_timeout = connect_timeout if connect_timeout is not None else timeout
        self.rate = rate
        self._sock: socket.socket | None = None
        self._decoder = FrameDecoder()
        self._inbox: list[Frame] = []
        self._closed = False
        self._cnt = 0
        self._last_send = 0.0
        self.frames_sent = 0

    # ------------------------------------------------------------------ connection

    @property
    def connected(self) -> bool:
        return self._sock is not None and not self._closed

    def connect(self) -> Client:
        if self._sock is not None:
            return self
        try:
            if self.transport == "tcp":
                s = socket.create_connection((self.host, self.port), timeout=self.connect_timeout)
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            else:
                fam = socket.AF_INET6 if ":" in self.host else socket.AF_INET
                s = socket.socket(fam, socket.SOCK_DGRAM)
                s.connect((self.host, self.port))
        except OSError as e:
            raise TargetUnreachable(
                f"cannot connect to {self.host}:{self.port} ({self.transport}): {e.strerror or e}"
            ) from None
        self._sock = s
        self._closed = False
        self._decoder = FrameDecoder()
        return self

    def close(self) -> None:
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.close()
        self._sock = None
        self._inbox.clear()

    def reconnect(self) -> Client:
        self.close()
        return self.connect()

    def __enter__(self) -> Client:
        return self.connect()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # ------------------------------------------------------------------ sending

    def next_cnt(self) -> int:
        """CNT values 1..65535, then 0 again (1.1: a uint16 counter)."""
        self._cnt = (self._cnt + 1) % (CNT_MAX + 1)
        return self._cnt

    def _throttle(self) -> None:
        if self.rate:
            gap = 1.0 / self.rate - (time.monotonic() - self._last_send)
            if gap > 0:
                time.sleep(gap)
        self._last_send = time.monotonic()

    def send_raw(self, raw: bytes, *, chunk: int | None = None) -> None:
        """Send bytes as they are (``chunk``: in pieces of that many bytes, TCP only)."""
        sock = self.connect()._sock
        assert sock is not None
        self._throttle()
        self.frames_sent += max(1, raw.count(b"/f/b"))
        try:
            if self.transport == "udp":
                sock.send(raw)
            elif chunk:
                for i in range(0, len(raw), chunk):
                    sock.sendall(raw[i : i + chunk])
            else:
                sock.sendall(raw)
        except OSError:
            self._closed = True

    def request(self, cmd_id: int, data: str, *, cnt: int | None = None) -> Exchange:
        """Send one frame and wait for its reply."""
        c = self.next_cnt() if cnt is None else cnt
        raw = encode_frame(c, cmd_id, data)
        self.send_raw(raw)
        return self.await_reply(c, cmd_id, request=raw)

    # ------------------------------------------------------------------ receiving

    def _read(self, deadline: float) -> tuple[list[Frame | Malformed], bool]:
        """Events from the next bytes to arrive before ``deadline``; (events, closed)."""
        sock = self._sock
        if sock is None or self._closed:
            return [], True
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return [], False
        pending = self._decoder.buffered > 0
        sock.settimeout(min(remaining, _IDLE) if pending else remaining)
        try:
            data = sock.recv(65536)
        except (TimeoutError, BlockingIOError):
            return (self._decoder.resolve_pending() if pending else []), False
        except OSError:
            self._closed = True
            return self._decoder.close(), True
        if self.transport == "udp":
            return decode_all(data), False
        if not data:
            self._closed = True
            events = self._decoder.close()
            self._decoder = FrameDecoder()
            return events, True
        return self._decoder.feed(data), False

    def await_reply(
        self, cnt: int, cmd_id: int, *, request: bytes = b"", timeout: float | None = None
    ) -> Exchange:
        """Wait for the frame echoing (cnt, cmd_id); frames for others stay in the inbox."""
        start = time.monotonic()
        deadline = start + (self.timeout if timeout is None else timeout)
        unsolicited: list[Frame] = []
        malformed: list[Malformed] = []
        for i, f in enumerate(self._inbox):
            if f.cnt == cnt and f.cmd_id == cmd_id:
                del self._inbox[i]
                return Exchange(request=request, cnt=cnt, cmd_id=cmd_id, reply=f)
        closed = False
        reply: Frame | None = None
        while reply is None and not closed:
            events, closed = self._read(deadline)
            for e in events:
                if isinstance(e, Malformed):
                    malformed.append(e)
                elif reply is None and e.cnt == cnt and e.cmd_id == cmd_id:
                    reply = e
                else:
                    unsolicited.append(e)
                    self._inbox.append(e)
            if not events and time.monotonic() >= deadline:
                break
        pending = b""
        if reply is None and self._decoder.buffered:
            pending = b"<%d bytes of an incomplete frame>" % self._decoder.buffered
        del self._inbox[:-64]  # bounded: a chatty peer must not grow it forever
        return Exchange(
            request=request,
            cnt=cnt,
            cmd_id=cmd_id,
            reply=reply,
            unsolicited=tuple(unsolicited),
            malformed=tuple(malformed),
            closed=closed,
            elapsed=time.monotonic() - start,
            pending=pending,
        )

    def collect(self, duration: float) -> tuple[list[Frame], list[Malformed], bool]:
        """Everything that arrives within ``duration`` seconds (inbox included)."""
        frames, self._inbox = list(self._inbox), []
        malformed: list[Malformed] = []
        deadline = time.monotonic() + duration
        closed = False
        while time.monotonic() < deadline and not closed:
            events, closed = self._read(deadline)
            for e in events:
                (malformed if isinstance(e, Malformed) else frames).append(e)  # type: ignore[arg-type]
        return frames, malformed, closed
