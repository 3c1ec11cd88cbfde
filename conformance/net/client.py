"""The conformance client: sends frames to a target and pairs replies by CNT and CMD_ID.

Real controllers are noisy peers: a reply is paired with its request by CNT and
CMD_ID, never by arrival order, and frames nobody asked for (such as the
command-ID 500 frames a controller sends when a Lua program fails) are kept as
``unsolicited`` rather than taken for a reply.  Bytes that are not frames come back
as :class:`~conformance.protocol.frame.Malformed` events attributed to the wait in which
they arrived.  TCP or UDP; an optional rate limit (frames per second).

A hostile target must not outlast or outgrow the kit: every wait ends at its
deadline (and at :attr:`Client.deadline`, when set) however fast bytes keep
arriving, the decoder never holds more than ``max_frame_size`` bytes, and an
exchange keeps only the first ``max_events`` malformed events and unpaired frames
(their totals are counted), so a target streaming endless bytes or 50 MB reply
blobs is read and discarded in bounded memory.
"""

from __future__ import annotations

import contextlib
import socket
import time
from dataclasses import dataclass, field
from types import TracebackType

from ..errors import ConformanceError
from ..protocol.decoder import FrameDecoder, decode_all
from ..protocol.frame import CNT_MAX, DEFAULT_MAX_FRAME_SIZE, Frame, Malformed, encode_frame
from .addresses import format_address

__all__ = ["DEFAULT_MAX_EVENTS", "DEFAULT_MAX_INBOX", "Client", "Exchange", "TargetUnreachable"]

_IDLE = 0.05  # silence after which a frame waiting on its LEN is decided on
#: Malformed events (and unpaired frames) one exchange keeps; the rest are only counted.
DEFAULT_MAX_EVENTS = 20
#: Unpaired frames kept for later requests (a chatty peer must not grow it forever).
DEFAULT_MAX_INBOX = 64


def _reason(e: OSError) -> str:
    """An OS error in a few lower-case words (``connection refused``)."""
    text = str(e.strerror or e or type(e).__name__)
    return text[:1].lower() + text[1:]


class TargetUnreachable(ConformanceError):
    """The target refused or did not accept a connection."""

    def __init__(self, message: str, *, reason: str = "") -> None:
        super().__init__(message)
        #: Why, in a few lower-case words (``connection refused``, ``timed out``).
        self.reason = reason or message


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
    #: Totals while waiting, including events past the ones kept in ``malformed``
    #: and ``unsolicited`` (a hostile peer's stream is counted, not stored).
    malformed_count: int = 0
    malformed_bytes: int = 0
    unsolicited_count: int = 0
    #: The socket error that ended the connection (``connection reset by peer``;
    #: over UDP, ``connection refused`` when nothing listens), if one did.
    error: str = ""

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
        max_frame_size: int = DEFAULT_MAX_FRAME_SIZE,
        max_events: int = DEFAULT_MAX_EVENTS,
        max_inbox: int = DEFAULT_MAX_INBOX,
        deadline: float | None = None,
    ) -> None:
        if transport not in ("tcp", "udp"):
            raise ValueError(f"transport must be tcp or udp, not {transport!r}")
        if max_events < 1 or max_inbox < 1:
            raise ValueError("max_events and max_inbox must be at least 1")
        self.host = host.strip("[]")
        self.port = port
        self.transport = transport
        self.timeout = timeout
        self.connect_timeout = connect_timeout if connect_timeout is not None else timeout
        self.rate = rate
        self.max_frame_size = max_frame_size
        self.max_events = max_events
        self.max_inbox = max_inbox
        #: ``time.monotonic()`` value no wait (connect, send, reply) extends past:
        #: the suite sets it to the end of the case's time.
        self.deadline = deadline
        self._sock: socket.socket | None = None
        self._decoder = FrameDecoder(max_frame_size=max_frame_size)
        self._inbox: list[Frame] = []
        self._closed = False
        self._error = ""
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
                timeout = self._clip(self.connect_timeout)
                if timeout <= 0:
                    raise TimeoutError(0, "no time left")
                s = socket.create_connection((self.host, self.port), timeout=timeout)
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            else:
                fam = socket.AF_INET6 if ":" in self.host else socket.AF_INET
                s = socket.socket(fam, socket.SOCK_DGRAM)
                s.connect((self.host, self.port))
        except OSError as e:
            reason = _reason(e)
            raise TargetUnreachable(
                f"cannot connect to {format_address(self.host, self.port)} ({self.transport}): "
                f"{reason}",
                reason=reason,
            ) from None
        self._sock = s
        self._closed = False
        self._error = ""
        self._decoder = FrameDecoder(max_frame_size=self.max_frame_size)
        return self

    def _clip(self, timeout: float) -> float:
        """``timeout`` shortened to what is left before :attr:`deadline`."""
        if self.deadline is None:
            return timeout
        return min(timeout, self.deadline - time.monotonic())

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
            # A peer that does not read must not block us longer than a reply wait.
            sock.settimeout(max(self._clip(self.timeout), 0.001))
            if self.transport == "udp":
                sock.send(raw)
            elif chunk:
                for i in range(0, len(raw), chunk):
                    sock.sendall(raw[i : i + chunk])
            else:
                sock.sendall(raw)
        except OSError as e:
            self._closed = True
            self._error = _reason(e)

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
        except OSError as e:
            self._closed = True
            self._error = _reason(e)
            return self._decoder.close(), True
        if self.transport == "udp":
            return decode_all(data), False
        if not data:
            self._closed = True
            events = self._decoder.close()
            self._decoder = FrameDecoder(max_frame_size=self.max_frame_size)
            return events, True
        return self._decoder.feed(data), False

    def await_reply(
        self, cnt: int, cmd_id: int, *, request: bytes = b"", timeout: float | None = None
    ) -> Exchange:
        """Wait for the frame echoing (cnt, cmd_id); frames for others stay in the inbox.

        Ends at the deadline whatever arrives: a stream of frames or garbage that
        never stops is read, counted and, past the first ``max_events``, dropped.
        """
        start = time.monotonic()
        deadline = start + (self.timeout if timeout is None else timeout)
        if self.deadline is not None:
            deadline = min(deadline, self.deadline)
        unsolicited: list[Frame] = []
        malformed: list[Malformed] = []
        n_malformed = n_bad_bytes = n_unsolicited = 0
        for i, f in enumerate(self._inbox):
            if f.cnt == cnt and f.cmd_id == cmd_id:
                del self._inbox[i]
                return Exchange(request=request, cnt=cnt, cmd_id=cmd_id, reply=f)
        closed = False
        reply: Frame | None = None
        keep = self.max_events
        while reply is None and not closed:
            events, closed = self._read(deadline)
            for e in events:
                if isinstance(e, Malformed):
                    n_malformed += 1
                    n_bad_bytes += len(e.raw)
                    if len(malformed) < keep:
                        malformed.append(e)
                elif reply is None and e.cnt == cnt and e.cmd_id == cmd_id:
                    reply = e
                else:
                    n_unsolicited += 1
                    if len(unsolicited) < keep:
                        unsolicited.append(e)
                    self._inbox.append(e)
            if len(self._inbox) > 2 * self.max_inbox:
                del self._inbox[: -self.max_inbox]
            # Checked after every read, not only after silent ones: a peer that
            # never stops sending must not hold us past the deadline.
            if time.monotonic() >= deadline:
                break
        pending = b""
        if reply is None and self._decoder.buffered:
            pending = b"<%d bytes of an incomplete frame>" % self._decoder.buffered
        del self._inbox[: -self.max_inbox]
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
            malformed_count=n_malformed,
            malformed_bytes=n_bad_bytes,
            unsolicited_count=n_unsolicited,
            error=self._error if closed else "",
        )

    def collect(self, duration: float) -> tuple[list[Frame], list[Malformed], bool]:
        """What arrives within ``duration`` seconds (inbox included): the first
        ``max_inbox`` frames and ``max_events`` malformed events; the rest is dropped."""
        frames, self._inbox = list(self._inbox), []
        malformed: list[Malformed] = []
        deadline = time.monotonic() + duration
        if self.deadline is not None:
            deadline = min(deadline, self.deadline)
        closed = False
        while time.monotonic() < deadline and not closed:
            events, closed = self._read(deadline)
            for e in events:
                if isinstance(e, Malformed):
                    if len(malformed) < self.max_events:
                        malformed.append(e)
                elif len(frames) < self.max_inbox:
                    frames.append(e)
        return frames, malformed, closed
