"""Client mode: judge every frame a client sends to the emulator, per command ID (sans-I/O).

``fairino-conformance serve`` feeds :meth:`ClientValidator.observe` with each
event a connection produced.  Framing problems, unknown command IDs, argument
count / type / range violations and LEN mismatches are FAIL; a CNT that does not
count up by one per frame is NON-STRICT (the manual calls CNT a frame counter but
does not say a client must increment it).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

from ..errors import Rule
from ..frame import Frame, Malformed
from ..model import Action
from ..report import CaseResult, Outcome, Report
from ..spec import SpecSet
from ..validate import validate_request
from .runner import show

__all__ = ["ClientValidator"]

_PER_COMMAND = 50  # failing frames kept per command (the rest are counted)


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
        self._last_cnt: dict[str, int] = {}

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
            check = validate_request(event, self.specs)
            name = check.command.name if check.command else (check.name or "?")
            cid = event.cmd_id
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
            last = self._last_cnt.get(peer)
            if last is not None and event.cnt != (last + 1) % 0x10000:
                self._add(
                    cid,
                    name,
                    "cnt",
                    Outcome.NON_STRICT,
                    f"CNT {event.cnt} after {last} on this connection (not counting up by one)",
                    event.raw or event.encode(),
                )
            self._last_cnt[peer] = event.cnt

    def _add(
        self, cid: int, name: str, group: str, outcome: Outcome, detail: str, raw: bytes
    ) -> None:
        cases = self._cases.setdefault(cid, [])
        self._names.setdefault(cid, name)
        if len(cases) >= _PER_COMMAND:
            return
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
            return r
