"""Client mode: judge every frame a client sends to the emulator, per command ID (sans-I/O).

``fairino-conformance serve`` feeds :meth:`ClientValidator.observe` with each
event a connection produced.  Framing problems, unknown command IDs, argument
count / type / range violations and LEN mismatches are FAIL; a CNT that does not
count up by one per frame is NON-STRICT (the manual calls CNT a frame counter but
does not say a client must increment it).

Bounded whatever a client sends: per-peer state is dropped when its connection
closes (and at most ``_MAX_PEERS`` peers are remembered, for UDP), at most
``_PER_COMMAND`` failing frames are kept per command ID, unknown command IDs
beyond the first ``_MAX_UNKNOWN_IDS`` are lumped into one counted entry under ID
0, and failure texts are cut at ``_DETAIL_MAX`` characters.  A connection the
emulator dropped because the kit failed on it (:class:`~conformance.model.Dropped`)
is an ERROR of the command ID whose frame caused it (ID 0 if not a frame).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Sequence

from ..errors import Rule
from ..frame import Frame, Malformed
from ..actions import Action, Dropped
from ..report import CaseResult, Outcome, Report
from ..spec import SpecSet
from ..validate import validate_request
from .runner import show

__all__ = ["ClientValidator"]

_PER_COMMAND = 50  # failing frames kept per command (the rest are counted)
_MAX_UNKNOWN_IDS = 64  # unknown command IDs judged one by one (the rest are lumped)
_MAX_PEERS = 4096  # peers whose last CNT is remembered (UDP peers never "close")
_DETAIL_MAX = 500  # characters of a failure's text


class ClientValidator:
    def __init__(self, specs: SpecSet, *, target: str = "client", strict: bool = False) -> None:
        self.specs = specs
        self.target = target
        self.strict = strict
        self.frames = 0
        self._lock = threading.Lock()
        self._cases: dict[int, list[CaseResult]] = {}
        self._passes: dict[int, int] = {}
        self._names: dict[int, str] = {}
        self._last_cnt: OrderedDict[str, int] = OrderedDict()
        self._known = frozenset(specs.cmd_ids)
        self._unknown_ids: set[int] = set()
        self._lumped = 0  # frames with an unknown command ID not tracked one by one
        self._lumped_example: int | None = None
        self._unlisted = 0  # failing frames past _PER_COMMAND
        self._drops: dict[str, int] = {}

    def observe(self, peer: str, event: Frame | Malformed, actions: Sequence[Action] = ()) -> None:
        with self._lock:
            self.frames += 1
            if isinstance(event, Malformed):
                self._add(
                    0,
                    "protocol",
                    "framing",
                    Outcome.FAIL,
                    f"{event.rule.value}: {event.detail}",
                    event.raw,
                )
                return
            cid = event.cmd_id
            if not self._tracked(cid):
                self._lumped += 1
                if self._lumped_example is None:
                    self._lumped_example = cid
                self._count_cnt(peer, event.cnt)
                return
            check = validate_request(event, self.specs)
            name = check.command.name if check.command else (check.name or "?")
            self._names.setdefault(cid, name)
            viols = [v for v in check.violations]
            if viols:
                group = (
                    "framing"
                    if any(
                        v.rule in (Rule.LEN_MISMATCH, Rule.BAD_SEPARATOR, Rule.BAD_CNT)
                        for v in viols
                    )
                    else "arguments"
                )
                if any(v.rule is Rule.UNKNOWN_COMMAND for v in viols):
                    group = "unknown"
                self._add(
                    cid,
                    name,
                    group,
                    Outcome.FAIL,
                    "; ".join(v.detail for v in viols),
                    event.raw or event.encode(),
                )
            else:
                self._passes[cid] = self._passes.get(cid, 0) + 1
            last = self._count_cnt(peer, event.cnt)
            if last is not None and event.cnt != (last + 1) % 0x10000:
                self._add(
                    cid,
                    name,
                    "cnt",
                    Outcome.NON_STRICT,
                    f"CNT {event.cnt} after {last} on this connection (not counting up by one)",
                    event.raw or event.encode(),
                )

    def connection_closed(self, peer: str, drop: Dropped | None = None) -> None:
        """A connection ended (``EmulatorServer``'s ``on_close``): forget the peer's state.

        ``drop``: why the emulator closed it, when it did.  A kit failure on the
        peer's bytes is an ERROR of the command ID whose frame caused it (a
        protocol error that escaped the judge, a FAIL); limits are counted in the
        report's ``meta``.
        """
        with self._lock:
            self._last_cnt.pop(peer, None)
            if drop is None:
                return
            self._drops[drop.kind] = self._drops.get(drop.kind, 0) + 1
            if drop.kind not in ("error", "protocol"):
                return
            cid = drop.cmd_id if drop.cmd_id is not None and self._tracked(drop.cmd_id) else 0
            cmds = self.specs.by_id(cid) if cid else ()
            name = self._names.get(cid) or (cmds[0].name if cmds else "protocol")
            outcome = Outcome.ERROR if drop.kind == "error" else Outcome.FAIL
            self._add(cid, name, "dropped", outcome, f"connection closed: {drop.reason}", drop.raw)

    def _tracked(self, cid: int) -> bool:
        """Whether ``cid`` gets entries of its own (every spec ID, the first unknown ones)."""
        if cid in self._known or cid in self._unknown_ids:
            return True
        if len(self._unknown_ids) < _MAX_UNKNOWN_IDS:
            self._unknown_ids.add(cid)
            return True
        return False

    def _count_cnt(self, peer: str, cnt: int) -> int | None:
        """Remember ``peer``'s CNT; return the one before."""
        last = self._last_cnt.pop(peer, None)
        self._last_cnt[peer] = cnt
        if len(self._last_cnt) > _MAX_PEERS:
            self._last_cnt.popitem(last=False)
        return last

    def _add(
        self, cid: int, name: str, group: str, outcome: Outcome, detail: str, raw: bytes
    ) -> None:
        cases = self._cases.setdefault(cid, [])
        self._names.setdefault(cid, name)
        if len(cases) >= _PER_COMMAND:
            self._unlisted += 1
            return
        if len(detail) > _DETAIL_MAX:
            detail = detail[:_DETAIL_MAX] + f"...(+{len(detail) - _DETAIL_MAX} characters)"
        cases.append(
            CaseResult(
                id=f"{cid}/{name}/client/{group}-{len(cases) + 1}",
                cmd_id=cid,
                name=name,
                group=f"client-{group}",
                outcome=outcome,
                detail=detail,
                frames=(f">> {show(raw)}",),
            )
        )

    def report(self) -> Report:
        with self._lock:
            r = Report(
                target=self.target,
                spec_version=self.specs.spec_version,
                strict=self.strict,
                meta={"mode": "client", "frames": self.frames},
            )
            if self._unlisted:
                r.meta["failing_frames_not_listed"] = self._unlisted
            if self._drops:
                r.meta["connections_dropped"] = dict(sorted(self._drops.items()))
            for cid in sorted(set(self._cases) | set(self._passes)):
                name = self._names.get(cid, "?")
                n = self._passes.get(cid, 0)
                if n:
                    r.add(
                        CaseResult(
                            id=f"{cid}/{name}/client/conforming",
                            cmd_id=cid,
                            name=name,
                            group="client",
                            outcome=Outcome.PASS,
                            detail=f"{n} conforming frame(s)",
                        )
                    )
                for c in self._cases.get(cid, ()):
                    r.add(c)
            if self._lumped:
                r.add(
                    CaseResult(
                        id="0/protocol/client/unknown-ids-not-tracked",
                        cmd_id=0,
                        name=self._names.get(0, "protocol"),
                        group="client-unknown",
                        outcome=Outcome.FAIL,
                        detail=f"{self._lumped} more frame(s) with unknown command IDs past "
                        f"the first {_MAX_UNKNOWN_IDS} (e.g. {self._lumped_example}), "
                        "not judged one by one",
                    )
                )
            return r
