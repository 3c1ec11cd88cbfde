"""The one judge, remembering its verdicts per distinct frame (``export-parquet``'s speed).

A fleet's traffic repeats: the same requests with a new CNT each time, and the same
replies to them.  :class:`MemoJudge` is :class:`~conformance.judge.judge.Judge` itself; it only
remembers what a verdict is a pure function of, and asks the judge for anything else:

* a request without framing problems: its ID, DATA and transport (as the suite's
  ``RequestMemo`` reads it); the CNT step is still decided for each frame by
  :meth:`Judge.request` on top of the remembered verdict;
* a reply without framing problems whose CNT and ID echo its request's: its ID and DATA,
  the request's ID, DATA and transport, and which dialect the request verdict follows
  (``bad_cnt``, ``bad_cmd_id``, ``unsolicited`` and framing messages name the frame's
  own numbers, so those are judged each time).
"""

from __future__ import annotations

from typing import Any

from ..judge.judge import Judge, Verdict
from ..protocol.frame import Frame
from ..spec.commands import Variant

__all__ = ["MemoJudge"]

#: Entries kept before the memo starts again (a fleet's distinct frames are far fewer).
LIMIT = 200_000


class MemoJudge(Judge):
    """:class:`Judge` with a memo of request and reply verdicts (see the module)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._requests: dict[tuple[int, str, str | None], Verdict] = {}
        self._replies: dict[tuple[object, ...], Verdict] = {}
        self.hits = 0
        self.misses = 0

    @classmethod
    def of(cls, judge: Judge) -> MemoJudge:
        """The memo over ``judge``'s spec set, dialects, reference and strictness."""
        return cls(judge.specs, judge.dialects, reference=judge.reference, strict=judge.strict)

    def _request(self, frame: Frame, transport: str | None) -> Verdict:
        if frame.problems:
            return super()._request(frame, transport)
        key = (frame.cmd_id, frame.data, transport)
        v = self._requests.get(key)
        if v is None:
            self.misses += 1
            if len(self._requests) >= LIMIT:
                self._requests.clear()
            v = self._requests[key] = super()._request(frame, transport)
        else:
            self.hits += 1
        return v

    def reply(
        self,
        frame: Frame,
        request: Frame | None,
        request_verdict: Verdict | None = None,
        *,
        transport: str | None = None,
        paired: bool = True,
        variant: Variant | None = None,
    ) -> Verdict:
        if (
            request is None
            or variant is not None
            or frame.problems
            or request.problems
            or frame.cnt != request.cnt
            or frame.cmd_id != request.cmd_id
        ):
            return super().reply(
                frame, request, request_verdict, transport=transport, paired=paired, variant=variant
            )
        d = request_verdict.dialect if request_verdict is not None else None
        key = (frame.cmd_id, frame.data, request.data, transport, d.id if d is not None else None)
        v = self._replies.get(key)
        if v is None:
            self.misses += 1
            if len(self._replies) >= LIMIT:
                self._replies.clear()
            v = self._replies[key] = super().reply(
                frame, request, request_verdict, transport=transport, paired=paired
            )
        else:
            self.hits += 1
        return v
