"""Runs cases against a target: connections, health checks, verdicts, reproduction lines.

Bounded against hostile targets (a kit must outlive the peer it tests):

* each case has a deadline (``case_timeout``): every wait of the case is clipped
  to it, so a case overruns it by at most one reply timeout, and a case that runs
  out is ERROR;
* the run has a budget (``budget``): when it runs out, the run stops;
* the run stops at once, with one line naming the address and the reason, when
  the target does not answer the health query at the start (refused, silent,
  closing, garbage) or when, after a case that ended with the target silent or
  gone, it does not answer again within the recovery timeout.

A stopped run leaves every remaining case ERROR with that one reason
(``Report.stopped``; the cases are marked ``not_run``).

Over the SDKs' XML-RPC (``--transport xmlrpc``) the target's port 20003 is spoken to through
:class:`~conformance.net.xmlrpc_client.XmlRpcClient` (:meth:`SuiteRunner.xmlrpc_call`), its
health is a harmless query over XML-RPC, and each call is judged by the one call judge
(:attr:`SuiteRunner.call_judge`); a case that calls a method is allowed by that method's
safety class (:func:`permitted`: introspection never unless named).

A case's function returns how it ended (:class:`CaseEnd`: outcome, detail, frames, the
bytes that reproduce it), or raises it (:class:`CaseFailure`); :func:`case_result` makes
that the case's report row, the one place a :class:`~conformance.report.model.CaseResult`
of the suite is made.  Replies are read by the judge alone: :meth:`SuiteRunner.judge`
gives the cases its :class:`~conformance.judge.judge.Verdict`.
"""

from __future__ import annotations

import math
import time
import zlib
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from ..errors import ConformanceError
from ..judge.calls import CallJudge
from ..judge.judge import Verdict
from ..judge.verdict import Outcome, Reference
from ..net.client import Client, Exchange, TargetUnreachable
from ..net.xmlrpc_client import XmlRpcClient, XmlRpcExchange
from ..protocol.frame import Frame, Malformed, encode_frame
from ..protocol.xmlrpc import XmlRpcValue
from ..report.model import CaseResult, Report
from ..report.text import shell_printf
from ..spec.commands import Command, SpecSet, Variant
from ..spec.dialects import dialects_from
from ..spec.knowledge import default_data, health_query, unsolicited_ids
from ..spec.xmlrpc import params_for
from .config import SuiteConfig
from .evidence import describe_exchange, reproduction
from .judging import RequestMemo, is_shape_fault, request_frame, transport_free
from .liveness import AstrayWatch

__all__ = [
    "Case",
    "CaseEnd",
    "CaseFailure",
    "RequestMemo",
    "SuiteRunner",
    "case_result",
    "describe_exchange",
    "not_run_result",
    "permitted",
    "shell_printf",
    "transport_free",
]


@dataclass(frozen=True, kw_only=True)
class CaseEnd:
    """How a case ended, as its function returns it (or raises it, :class:`CaseFailure`):
    what :func:`case_result` makes its report row from."""

    outcome: Outcome
    detail: str = ""
    frames: tuple[str, ...] = ()
    #: The bytes the case sent that show the outcome: its reproduction line sends them.
    raw: bytes = b""
    #: The run had stopped before the case (``SuiteRunner.stopped``).
    not_run: bool = False


class CaseFailure(Exception):
    """Raised inside a case to end it with an outcome (FAIL, NON-STRICT, UNIMPLEMENTED...)."""

    def __init__(
        self,
        outcome: Outcome,
        detail: str,
        *,
        frames: tuple[str, ...] = (),
        raw: bytes = b"",
        sticky: bool = False,
    ) -> None:
        super().__init__(detail)
        self.end = CaseEnd(outcome=outcome, detail=detail, frames=frames, raw=raw)
        #: A transport failure (no reply, closed): later examples of the case fail the same way.
        self.sticky = sticky


@dataclass(frozen=True, kw_only=True)
class Case:
    """One case: content-derived ID, group, command blamed, and the function that runs it."""

    id: str
    group: str
    cmd_id: int
    name: str
    run: Callable[[SuiteRunner, Case], CaseEnd] = field(repr=False, compare=False)
    command: Command | None = field(default=None, repr=False, compare=False)
    variant: Variant | None = field(default=None, repr=False, compare=False)
    extra: Any = field(default=None, repr=False, compare=False)
    #: The XML-RPC method the case calls (``--transport xmlrpc``), None for a frame's case.
    method: str | None = field(default=None, compare=False)

    @property
    def item_name(self) -> str:
        """The pytest item's name (its class, in JUnit terms, is the command ID)."""
        return self.id.split("/", 1)[1]

    @property
    def seed_offset(self) -> int:
        return zlib.crc32(self.id.encode())

    def spec(self) -> tuple[Command, Variant]:
        """A command case's command and variant (an XML-RPC or sequence case has none)."""
        assert self.command is not None and self.variant is not None
        return self.command, self.variant


def permitted(config: SuiteConfig, case: Case, specs: SpecSet) -> tuple[bool, str]:
    """Whether the safety profile lets ``case`` be sent (and why not): by its XML-RPC
    method's class where it calls one, else by its command's; a case of no command always."""
    if case.method is not None:
        return config.safety.permits_method(case.method, specs)
    if case.command is not None:
        return config.safety.permits(case.command, specs)
    return True, ""


class SuiteRunner:
    """Session state: the target (or the in-process emulator), a connection, the report."""

    def __init__(self, config: SuiteConfig, specs: SpecSet) -> None:
        self.config = config
        self.specs = specs
        self.emulator: Any = None
        self.address: tuple[str, int] | None = config.target
        self._client: Client | None = None
        self._unknown: tuple[str, Verdict] | None = None
        self._unknown_learnt = False
        self.health_command, self.health_variant = health_query(specs)
        #: The one judge of every frame (conformance/judge/judge.py), under the run's
        #: reference; the built-in emulator judges with it too.
        self.frame_judge = RequestMemo(
            specs,
            dialects_from(None, specs, version=config.firmware),
            reference=Reference(config.reference),
            strict=config.strict,
        )
        #: Why the run stopped (one line naming the target), or None while it goes on.
        self.stopped: str | None = None
        self.last_case: str | None = None
        self.report = Report(
            target=config.target_label(),
            spec_version=specs.spec_version,
            seed=config.seed,
            transport=config.transport,
            strict=config.strict,
            reference=config.reference,
            meta={"profile": config.profile.name},
        )
        self.case_started = 0.0
        #: Replies of the current case that followed a field dialect: (source, message).
        self._dialects: list[tuple[str, str]] = []
        #: ``time.monotonic()`` values: the end of the current case, of the run.
        self.case_deadline = math.inf
        self.run_deadline = math.inf
        # The last exchange of the case ended with nothing from the target (silent,
        # closed): after the case, make sure it is still alive.
        self._suspect = False
        self._request_frames: tuple[tuple[bytes, int, int], Frame] | None = None
        self._liveness = AstrayWatch()
        self._xmlrpc: XmlRpcClient | None = None
        self._call_judge: CallJudge | None = None

    @property
    def xmlrpc(self) -> bool:
        """The run speaks the SDKs' XML-RPC (``--transport xmlrpc``)."""
        return self.config.transport == "xmlrpc"

    @property
    def call_judge(self) -> CallJudge:
        """The one judge of XML-RPC calls, under the run's reference (made on first use)."""
        if self._call_judge is None:
            self._call_judge = CallJudge(self.frame_judge)
        return self._call_judge

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> None:
        """Start the budget's clock; check the target (the emulator is started instead)."""
        self.run_deadline = time.monotonic() + self.config.budget
        if self.config.embedded:
            from ..net.emulator import EmulatorServer

            emu = EmulatorServer(
                self.specs,
                udp_port=0 if self.config.transport == "udp" else None,
                xmlrpc_port=0 if self.xmlrpc else None,
                faults=self.config.emulator_faults,
                judge=self.frame_judge,  # it accepts what the run's reference accepts
            )
            emu.start()
            self.emulator = emu
            self.address = emu.udp_address if self.config.transport == "udp" else emu.address
            if self.xmlrpc:
                self.address = emu.xmlrpc_address
            self.report.meta["emulator_faults"] = list(self.config.emulator_faults)
        else:
            # Fail fast: a target that does not answer the harmless query at the
            # start (refused, silent, closing, sending garbage) would make every
            # case wait and fail; stop with one line instead.
            why = self.probe()
            if why is not None:
                self.stopped = f"target {self.target_label()} {why}"
                self.report.stopped = self.stopped

    def target_label(self) -> str:
        return self.config.target_label(self.address)

    def close(self) -> None:
        self.drop_client()
        if self.emulator is not None:
            emu, self.emulator = self.emulator, None
            emu.close()

    # ------------------------------------------------------------------ connections

    def _fresh_client(self, deadline: float) -> Client:
        assert self.address is not None
        host, port = self.address
        return Client(
            host,
            port,
            transport=self.config.transport,
            timeout=self.config.reply_timeout,
            rate=self.config.rate,
            max_frame_size=self.config.max_reply_size,
            deadline=None if math.isinf(deadline) else deadline,
        )

    def new_client(self) -> Client:
        """A new connection for the current case (its waits end with the case's time)."""
        self.check_budget()
        return self._fresh_client(self.case_deadline)

    def client(self) -> Client:
        """The case's connection (kept between cases while the target behaves)."""
        self.check_budget()
        if self._client is None or not self._client.connected:
            if self._client is not None:
                self._client.close()
            self._client = self._fresh_client(self.case_deadline).connect()
        self._client.deadline = None if math.isinf(self.case_deadline) else self.case_deadline
        return self._client

    def drop_client(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
        if self._xmlrpc is not None:
            self._xmlrpc.close()
            self._xmlrpc = None

    # ------------------------------------------------------------------ XML-RPC

    def xmlrpc_call(
        self, method: str, params: Sequence[XmlRpcValue], *, fresh: bool = False
    ) -> XmlRpcExchange:
        """One XML-RPC call on the case's connection (kept open between calls; ``fresh``:
        on a connection of its own), its wait clipped to the case's time.  No answer
        makes the target suspect (it is checked after the case)."""
        self.check_budget()
        assert self.address is not None
        wait = min(self.config.reply_timeout, max(0.01, self.case_deadline - time.monotonic()))
        if fresh:
            with XmlRpcClient(*self.address, timeout=wait) as c:
                ex = c.call(method, params)
        else:
            if self._xmlrpc is None:
                self._xmlrpc = XmlRpcClient(*self.address, timeout=wait)
            self._xmlrpc.timeout = wait
            ex = self._xmlrpc.call(method, params)
        if ex.kind == "missing":
            self._suspect = True
            if time.monotonic() >= self.case_deadline:
                raise self.overrun()
        return ex

    def _xmlrpc_health(self) -> tuple[str, list[XmlRpcValue]]:
        """The harmless XML-RPC call: the health query's method if the SDKs send it, else
        GetControllerIP (the python SDK's constructor asks it), with its SDK defaults."""
        surface = self.call_judge.surface
        for name in (self.health_command.name, "GetControllerIP"):
            m = surface.method(name)
            if m is not None and m.forms:
                return name, params_for(m.forms[0], [])
        return "GetControllerIP", []

    def _probe_xmlrpc(self) -> str | None:
        """None when the target answers the harmless call with any response, else why not."""
        method, params = self._xmlrpc_health()
        assert self.address is not None
        try:
            with XmlRpcClient(*self.address, timeout=self.config.reply_timeout) as c:
                ex = c.call(method, params)
        except TargetUnreachable as e:
            return f"unreachable: {e.reason}"
        if ex.reply is not None or ex.status is not None:
            return None
        assert ex.error is not None
        return f"accepted a connection but did not answer {method} over XML-RPC ({ex.error[1]})"

    def overrun(self) -> CaseFailure:
        """The case's time is up (its own timeout, or the run's budget)."""
        if self.case_deadline >= self.run_deadline:
            detail = f"the run budget of {self.config.budget:g} s ran out during the case"
        else:
            detail = f"case exceeded its time budget of {self.config.case_timeout:g} s"
        # Sticky: the examples Hypothesis would still try must end at once too.
        return CaseFailure(Outcome.ERROR, detail, sticky=True)

    def check_budget(self) -> None:
        if time.monotonic() >= self.case_deadline:
            raise self.overrun()

    def _waited(self, ex: Exchange) -> None:
        """Note an exchange without a reply: silence past the case's end is not the target's fault."""
        self._liveness.exchange(ex)
        if ex.reply is None:
            if not ex.unsolicited_count:
                self._suspect = True
            if time.monotonic() >= self.case_deadline:
                raise self.overrun()

    def exchange(self, cmd_id: int, data: str, *, client: Client | None = None) -> Exchange:
        c = client or self.client()
        ex = c.request(cmd_id, data)
        if ex.reply is None and client is None:
            # Closed, or silent: a late reply or a half frame would pollute the next case.
            self.drop_client()
        self._waited(ex)
        return ex

    def exchanges(self, cmd_id: int, datas: Sequence[str]) -> Generator[Exchange, None, None]:
        """Requests of one command, each with its exchange, in order.

        Against the built-in emulator over TCP they all go in one write before
        the first reply is read: it answers a connection's frames in turn (1.1,
        and the transport cases check that it does), and each request then costs
        no hand-over between the kit's thread and the emulator's.  Against any
        other target (or with ``--rate``) each request waits for the reply to
        the one before, as :meth:`exchange`: a target that cannot take coalesced
        frames fails the transport cases, not every case that sends several
        requests.  A consumer that stops early (a failed check) drops the
        connection with the replies still due on it.
        """
        if (
            len(datas) < 2
            or not self.config.embedded
            or self.config.transport != "tcp"
            or self.config.rate
        ):
            for data in datas:
                yield self.exchange(cmd_id, data)
            return
        c = self.client()
        sent = [(c.next_cnt(), data) for data in datas]
        raws = [encode_frame(cnt, cmd_id, data) for cnt, data in sent]
        c.send_raw(b"".join(raws))
        done = 0
        try:
            for (cnt, _), raw in zip(sent, raws, strict=True):
                ex = c.await_reply(cnt, cmd_id, request=raw)
                if ex.reply is None:
                    self.drop_client()
                done += 1
                self._waited(ex)
                yield ex
        finally:
            if done < len(sent):
                self.drop_client()

    def send_raw_exchange(
        self,
        raw: bytes,
        cnt: int,
        cmd_id: int,
        *,
        chunk: int | None = None,
        client: Client | None = None,
        timeout: float | None = None,
    ) -> Exchange:
        c = client or self.client()
        c.send_raw(raw, chunk=chunk)
        ex = c.await_reply(cnt, cmd_id, request=raw, timeout=timeout)
        if ex.reply is None and client is None:
            self.drop_client()
        self._waited(ex)
        return ex

    def probe_silence(self, client: Client, window: float) -> Exchange:
        """Send the harmless query on ``client``; wait up to ``window`` for its reply.

        A target answers one connection's frames in order (1.1: one reply per request,
        in turn), so the probe's reply proves that the frames sent before it got no
        reply but those already read: silence is decided on that event, not on a fixed
        wait.  A probe swallowed by a broken frame leaves it unanswered after
        ``window``, which is the old fixed wait.
        """
        cnt = client.next_cnt()
        hid = self.health_command.cmd_id
        raw = encode_frame(cnt, hid, default_data(self.health_command, self.health_variant))
        client.send_raw(raw)
        return client.await_reply(cnt, hid, request=raw, timeout=window)

    def send_raw_probed(self, raw: bytes, cnt: int, cmd_id: int, *, window: float) -> Exchange:
        """Like :meth:`send_raw_exchange` for a frame that may get no reply at all:
        its silence is decided by :meth:`probe_silence` (at most ``window`` seconds)."""
        c = self.client()
        c.send_raw(raw)
        probe = self.probe_silence(c, window)
        ex = c.await_reply(cnt, cmd_id, request=raw, timeout=0.0)
        if ex.reply is None:
            ex = replace(
                ex,
                unsolicited=probe.unsolicited,
                malformed=probe.malformed,
                closed=probe.closed,
                elapsed=probe.elapsed,
                pending=probe.pending,
                malformed_count=probe.malformed_count,
                malformed_bytes=probe.malformed_bytes,
                unsolicited_count=probe.unsolicited_count,
                error=probe.error,
            )
        if probe.reply is None:
            # Swallowed, closed or silent: as after a fixed wait without a reply.
            self.drop_client()
            self._waited(ex)
        return ex

    # ------------------------------------------------------------------ health / unknown

    def _health_exchange(self) -> Exchange:
        """The harmless query on a fresh connection (waits bounded by the run's budget)."""
        data = default_data(self.health_command, self.health_variant)
        with self._fresh_client(self.run_deadline) as c:
            return c.request(self.health_command.cmd_id, data)

    def health(self) -> tuple[bool, str]:
        """A harmless query on a fresh connection; (ok, what went wrong)."""
        if self.xmlrpc:
            why = self._probe_xmlrpc()
            if why is None:
                self._suspect = False
            return why is None, why or ""
        try:
            ex = self._health_exchange()
        except TargetUnreachable as e:
            return False, str(e)
        if ex.reply is None:
            return False, "connection closed" if ex.closed else "no reply"
        verdict = self.reply_verdict(ex, self.health_variant)
        if verdict.refused or verdict.fails(self.frame_judge.reference):
            return False, f"reply {ex.reply.data!r}"
        self._suspect = False
        return True, ""

    def probe(self) -> str | None:
        """Is the target alive?  None when it answers the health query with any frame.

        Otherwise why not, as words that follow the address: ``unreachable:
        connection refused``, ``accepted a connection but did not answer GetX
        (ID n) within 2 s``...  A reply that breaks the protocol still counts as
        alive: judging it is the cases' business, not a reason to stop.
        """
        if self.xmlrpc:
            return self._probe_xmlrpc()
        name = f"{self.health_command.name} (ID {self.health_command.cmd_id})"
        try:
            ex = self._health_exchange()
        except TargetUnreachable as e:
            return f"unreachable: {e.reason}"
        if ex.reply is not None or ex.unsolicited_count:
            return None
        accepted = "accepted a connection but " if self.config.transport == "tcp" else ""
        if ex.closed and ex.error and not accepted:
            return f"unreachable: {ex.error}"  # UDP: the ICMP answer to a closed port
        if ex.closed:
            # A reset or an orderly close: which one is a race between its close and our send.
            why = f"{accepted}closed it instead of answering {name}"
            why += f" ({ex.error})" if ex.error else ""
        else:
            why = f"{accepted}did not answer {name} within {self.config.reply_timeout:g} s"
        if ex.malformed_count:
            why += f" (it sent {ex.malformed_bytes} bytes that are not frames)"
        elif ex.pending:
            why += " (it sent the start of a frame and no more)"
        return why

    def wait_alive(self, until: float) -> str | None:
        """Probe until the target answers or ``until``; None, or why it is not alive."""
        why = self.probe()
        while why is not None and time.monotonic() < min(until, self.run_deadline):
            time.sleep(0.05)
            why = self.probe()
        return why

    def recover(self, until: float | None = None) -> bool:
        """Wait (up to the recovery timeout, or ``until``) for the target to answer again."""
        deadline = time.monotonic() + self.config.recovery_timeout
        deadline = min(deadline, self.run_deadline, until if until is not None else math.inf)
        while time.monotonic() < deadline:
            if self.health()[0]:
                return True
            time.sleep(0.05)
        return False

    def _stop_dead(self, case: Case, why: str) -> None:
        if time.monotonic() >= self.run_deadline:
            # The wait for the target was cut short by the budget: that is the reason.
            self.stopped = f"run budget of {self.config.budget:g} s used up after case {case.id}"
        else:
            self.stopped = (
                f"target {self.target_label()} died after case {case.id}: {why} "
                f"(no answer for {self.config.recovery_timeout:g} s)"
            )
        self.report.stopped = self.stopped

    def unknown_fingerprint(self) -> tuple[str, Verdict] | None:
        """How the target answers an unknown command ID: its reply's DATA and the judge's
        verdict on it (None: it stays silent)."""
        if not self._unknown_learnt:
            self._unknown_learnt = True
            unknown = next(i for i in range(9999, 100000) if not self.specs.by_id(i))
            with self.new_client() as c:
                ex = c.request(unknown, "Conformance()")
            if ex.reply is None and time.monotonic() >= self.case_deadline:
                self._unknown_learnt = False  # cut short: learn it in a later case
                raise self.overrun()
            if ex.reply is None:
                self._unknown = None
            else:
                self._unknown = (ex.reply.data, self.reply_verdict(ex, None))
        return self._unknown

    def is_unimplemented(self, reply: Frame) -> bool:
        fp = self.unknown_fingerprint()
        return fp is not None and fp[1].refused and reply.data.strip() == fp[0].strip()

    # ------------------------------------------------------------------ judging

    def framing_problems(self, ex: Exchange, verdict: Verdict | None = None) -> list[str]:
        """How an exchange departs from 1.1 framing and echo rules (empty when it conforms).

        ``verdict``: the judge's verdict on the reply read without a variant, when
        the caller has it already (see :meth:`judge`).
        """
        out: list[str] = []
        bad = [m for m in ex.malformed]
        if bad:
            total = max(ex.malformed_bytes, sum(len(m.raw) for m in bad))
            out.append(
                f"{total} bytes that are not a frame arrived "
                f"({', '.join(sorted({m.rule.value for m in bad}))})"
            )
        if ex.reply is None:
            if ex.closed:
                out.append("the target closed the connection instead of replying")
            else:
                near = [f for f in ex.near_misses() if f.cmd_id not in unsolicited_ids(self.specs)]
                if near:
                    f = near[0]
                    if f.cnt == ex.cnt and f.cmd_id != ex.cmd_id:
                        out.append(
                            f"reply CMD_ID {f.cmd_id} does not echo the request's {ex.cmd_id}"
                        )
                    elif f.cmd_id == ex.cmd_id:
                        out.append(f"reply CNT {f.cnt} does not echo the request's {ex.cnt}")
                elif ex.pending:
                    out.append("an incomplete reply frame (no tail?) and then silence")
                else:
                    out.append(f"no reply within {self.config.reply_timeout:g} s")
        else:
            v = verdict if verdict is not None else self.reply_verdict(ex, None)
            failing = v.failing_findings(self.frame_judge.reference, strict=self.config.strict)
            out += [f.message for f in failing if not is_shape_fault(f)]
        return out

    def shape_faults(self, verdict: Verdict) -> list[str]:
        """How a reply's DATA departs from the returns it was due, where that fails the run
        (:func:`~.judging.is_shape_fault`): the messages of the judge's findings."""
        failing = verdict.failing_findings(self.frame_judge.reference)
        return [f.message for f in failing if is_shape_fault(f)]

    def reply_verdict(self, ex: Exchange, variant: Variant | None) -> Verdict:
        """The judge's verdict on an exchange's reply (read against ``variant`` if given)."""
        assert ex.reply is not None
        v = self.frame_judge.reply(
            ex.reply,
            self._request_frame(ex),
            transport=self.config.transport,
            variant=variant,
        )
        if v.outcome is Outcome.DIALECT and len(self._dialects) < 8:
            self._dialects.append((v.source, v.message))
        return v

    def _request_frame(self, ex: Exchange) -> Frame:
        """The request of an exchange as a frame (the last one decoded is kept)."""
        key = (ex.request, ex.cnt, ex.cmd_id)
        if self._request_frames is not None and self._request_frames[0] == key:
            return self._request_frames[1]
        frame = request_frame(ex)
        self._request_frames = (key, frame)
        return frame

    def judge(self, ex: Exchange, variant: Variant | None) -> Verdict | None:
        """Raise CaseFailure for framing problems; else the judge's verdict on the reply read
        against ``variant`` (None without one): ``refused``, ``form`` and ``code`` say how it
        refused, :meth:`shape_faults` how its DATA departs from the returns."""
        self._waited(ex)
        verdict: Verdict | None = None
        if ex.reply is not None and variant is not None:
            rv = self.frame_judge.request(self._request_frame(ex))
            if rv.variant is variant and rv.dialect is None:
                # The judge reads a reply against its request's own variant, so read
                # against ``variant`` it is the very verdict framing_problems wants.
                verdict = self.reply_verdict(ex, variant)
        probs = self.framing_problems(ex, verdict)
        if probs:
            raise CaseFailure(
                Outcome.FAIL,
                "; ".join(probs),
                frames=describe_exchange(ex),
                raw=ex.request,
                sticky=ex.reply is None,
            )
        assert ex.reply is not None
        if variant is None:
            return None
        if verdict is None:
            verdict = self.reply_verdict(ex, variant)
        return verdict

    def check_request_valid(self, cmd_id: int, data: str) -> bool:
        """Whether the judge lets a request pass (NON-STRICT and, under ``field``, DIALECT too).

        A generated "invalid" request that a recorded field dialect covers is
        valid to a controller that speaks the dialect, so it is no invalid case.
        """
        v = self.frame_judge.request(
            Frame(cnt=1, cmd_id=cmd_id, data=data), transport=self.config.transport
        )
        return not v.fails(self.frame_judge.reference)

    # ------------------------------------------------------------------ running cases

    def reproduce(self, case: Case, raw: bytes) -> str:
        """A shell line re-running exactly this case (:func:`.evidence.reproduction`)."""
        return reproduction(self.config, case.id, raw)

    def run(self, case: Case) -> CaseResult:
        """Run one case (never raises): safety, a dead target and kit errors become outcomes."""
        self._dialects = []
        started = time.monotonic()
        end = self._run(case)
        source = ""
        if end.outcome is Outcome.PASS and self._dialects:
            # Passed, with a reply in a recorded field dialect (a failure only under the
            # manual reference, where the reply's check already failed the case).
            source = self._dialects[0][0]
            end = replace(
                end,
                outcome=Outcome.DIALECT,
                detail=f"{end.detail}; {self._dialects[0][1]}".lstrip("; "),
            )
        astray = self._liveness.case_done(case.cmd_id, case.id)
        if astray is not None and self.stopped is None:
            self.stopped = self.report.stopped = f"target {self.target_label()} {astray}"
        if self._suspect and self.stopped is None:
            # The case ended with the target silent or gone: alive, or the run stops.
            self._suspect = False
            why = self.wait_alive(time.monotonic() + self.config.recovery_timeout)
            if why is not None:
                self.drop_client()
                self._stop_dead(case, why)
        reproduce = ""
        if (
            end.outcome is Outcome.NON_STRICT or self.report.fails(end.outcome)
        ) and not end.not_run:
            reproduce = self.reproduce(case, end.raw)
        result = case_result(
            case,
            end,
            reproduce=reproduce,
            source=source,
            duration=0.0 if end.not_run else time.monotonic() - started,
        )
        self.report.add(result)
        if not end.not_run:
            self.last_case = case.id
        return result

    def not_run(self, case: Case) -> CaseResult:
        """Record a case the run never reached (it stopped: ``stopped`` says why)."""
        result = not_run_result(case, self.stopped or "the run stopped")
        self.report.add(result)
        return result

    def _run(self, case: Case) -> CaseEnd:
        # A stopped run reaches no case, one the safety profile skips neither: it is not
        # run, not SKIPPED (a lone SKIPPED row under "350 ERROR" told another story).
        now = time.monotonic()
        if self.stopped is None and now >= self.run_deadline:
            after = f" after case {self.last_case}" if self.last_case else ""
            self.stopped = f"run budget of {self.config.budget:g} s used up{after}"
            self.report.stopped = self.stopped
        if self.stopped is not None:
            return CaseEnd(outcome=Outcome.ERROR, detail=f"not run: {self.stopped}", not_run=True)
        ok, why = permitted(self.config, case, self.specs)
        if not ok:
            return CaseEnd(outcome=Outcome.SKIPPED, detail=why)
        self.case_started = now
        self.case_deadline = min(now + self.config.case_timeout, self.run_deadline)
        self._suspect = False
        try:
            return case.run(self, case)
        except CaseFailure as f:
            return f.end
        except TargetUnreachable as e:
            self._suspect = False
            gone = self.wait_alive(time.monotonic() + self.config.recovery_timeout)
            if gone is None:
                return CaseEnd(outcome=Outcome.FAIL, detail=f"target dropped during the case: {e}")
            self._stop_dead(case, gone)
            return CaseEnd(outcome=Outcome.ERROR, detail=str(e))
        except ConformanceError as e:
            return CaseEnd(outcome=Outcome.ERROR, detail=f"kit error: {e}")
        except OSError as e:
            return CaseEnd(outcome=Outcome.ERROR, detail=f"connection error: {e}")

    def after_disturbance(self, case: Case, frames: tuple[str, ...], raw: bytes) -> CaseEnd | None:
        """Health check on a fresh connection; a failure is blamed on ``case``.

        The wait for recovery ends with the case's time; a target still silent
        then is checked again after the case (and may stop the run).
        """
        ok, why = self.health()
        if ok:
            return None
        self.drop_client()
        detail = f"a harmless query on a fresh connection failed afterwards ({why})"
        if not self.recover(until=self.case_deadline):
            self._suspect = True
            detail += f"; target did not recover within {self.config.recovery_timeout:g} s"
        return CaseEnd(outcome=Outcome.FAIL, detail=detail, frames=frames, raw=raw)


_ = Malformed, encode_frame


def case_result(
    case: Case, end: CaseEnd, *, reproduce: str = "", source: str = "", duration: float = 0.0
) -> CaseResult:
    """The report row of ``case``, which ended as ``end``: the one place the suite makes one
    (a run's case, one it never reached, a dry run's)."""
    return CaseResult(
        id=case.id,
        cmd_id=case.cmd_id,
        name=case.name,
        group=case.group,
        outcome=end.outcome,
        detail=end.detail,
        reproduce=reproduce,
        frames=end.frames,
        not_run=end.not_run,
        source=source,
        duration=duration,
    )


def not_run_result(case: Case, why: str) -> CaseResult:
    """A case the run never reached: ERROR, ``not_run``, with the reason the run stopped."""
    return case_result(case, CaseEnd(outcome=Outcome.ERROR, detail=f"not run: {why}", not_run=True))
