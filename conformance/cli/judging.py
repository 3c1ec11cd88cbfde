"""The options every judging sub-command shares: ``--reference`` and ``--dialects-dir``.

One definition, so that ``check``, ``info``, ``decode``, ``replay``, ``diff``,
``serve``, ``emulate`` and ``run`` read them alike and build the same
:class:`~conformance.judge.judge.Judge`.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import threading
from collections.abc import Iterator
from typing import IO

from ..errors import UsageError
from ..judge.judge import Judge, Verdict
from ..judge.verdict import REFERENCE_ENV, Reference, reference_from
from ..protocol.frame import Frame, Malformed
from ..recording.records import CallRecord, FrameRecord, ProblemRecord, value_to_json
from ..spec.commands import SpecSet
from ..spec.dialects import DIALECTS_ENV, dialects_from

__all__ = [
    "DIALECTS_ENV",
    "VerdictSink",
    "add_judge_options",
    "dialects_from",
    "judge_from",
    "malformed_line",
    "reference_of",
    "verdict_line",
    "verdict_sink",
]

REFERENCE_HELP = (
    "what frames are held to: 'field' (default; a recorded field dialect is DIALECT, "
    "not a failure) or 'manual' (the manual alone: DIALECT fails); "
    f"env {REFERENCE_ENV}"
)


def add_judge_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--reference", choices=[r.value for r in Reference], default=None, help=REFERENCE_HELP
    )
    p.add_argument(
        "--dialects-dir",
        metavar="DIR",
        default=None,
        help=f"field dialect files (default: the shipped specs/fairino-field; env {DIALECTS_ENV})",
    )


def reference_of(args: argparse.Namespace) -> Reference:
    return reference_from(getattr(args, "reference", None))


def judge_from(args: argparse.Namespace, specs: SpecSet, *, strict: bool = False) -> Judge:
    """The judge the options describe; its field dialects are those of the firmware the
    spec choice knows (``args.spec_choice``, set by ``specs_of``/``spec_choice_of``), all of
    them when it knows none."""
    choice = getattr(args, "spec_choice", None)
    return Judge(
        specs,
        dialects_from(
            getattr(args, "dialects_dir", None),
            specs,
            version=choice.firmware if choice is not None else None,
        ),
        reference=reference_of(args),
        strict=strict,
    )


def malformed_line(raw: bytes, verdict: Verdict, **extra: object) -> str:
    """A run of bytes that is not a frame and its verdict as a JSON line (``kind``
    ``malformed``): ``--verdicts`` lists these too, so a run's only FAIL is never missing."""
    doc: dict[str, object] = {
        "kind": "malformed",
        "dir": verdict.direction.value,
        "size": len(raw),
        "raw": raw[:200].decode("utf-8", "replace"),
        **extra,
        **verdict.to_json(),
    }
    return json.dumps(doc, ensure_ascii=False)


def verdict_line(
    frame: FrameRecord | Frame | Malformed | ProblemRecord | CallRecord,
    verdict: Verdict,
    **extra: object,
) -> str:
    """One frame and its verdict as a JSON line (``check --verdicts``, ``serve --verdicts``);
    an XML-RPC call's request or reply (``kind`` ``call``: its method and parameters).

    The same keys from every front-end, so that their outputs compare line for line.
    """
    if isinstance(frame, (Malformed, ProblemRecord)):
        return malformed_line(frame.raw, verdict, **extra)
    if isinstance(frame, CallRecord):
        call: dict[str, object] = {
            "kind": "call",
            "dir": verdict.direction.value,
            "seq": frame.seq,
            "method": frame.method,
            "params": None if frame.params is None else [value_to_json(p) for p in frame.params],
            "reply": frame.reply,
            **extra,
            **verdict.to_json(),
        }
        return json.dumps(call, ensure_ascii=False)
    doc: dict[str, object] = {
        "kind": "frame",
        "dir": verdict.direction.value,
        "cnt": frame.cnt,
        "cmd_id": frame.cmd_id,
        "data": frame.data,
        **extra,
        **verdict.to_json(),
    }
    return json.dumps(doc, ensure_ascii=False)


class VerdictSink:
    """Writes verdict lines to a file (``-``: stdout), flushed line by line.

    A write that fails (a full disk: ENOSPC, EFBIG, EIO; a closed pipe) never ends the
    command: it is said at once on stderr, naming the path, the error and the lines
    written so far, and the lines after it are counted, not written (``lost``).  ``serve``
    goes on serving; the command says at its end how many lines the file lacks.
    """

    def __init__(self, path: str, who: str) -> None:
        self.path = path
        self.who = who
        self.written = 0
        self.lost = 0
        self.error: str | None = None
        self._lock = threading.Lock()
        if path == "-":
            self._file: IO[str] = sys.stdout
            return
        try:
            self._file = open(path, "w", encoding="utf-8")  # noqa: SIM115 - closed by close()
        except OSError as e:
            raise UsageError(f"cannot write {path}: {e.strerror}") from None

    def __call__(self, line: str) -> None:
        with self._lock:
            if self.error is not None:
                self.lost += 1
                return
            try:
                self._file.write(line + "\n")
                self._file.flush()
            except (OSError, ValueError) as e:  # ValueError: a stdout closed under us
                self.error = getattr(e, "strerror", None) or str(e)
                self.lost += 1
                print(
                    f"{self.who}: cannot write verdicts to {self.path}: {self.error}; "
                    f"{self.written} lines written, the ones after are not (it goes on)",
                    file=sys.stderr,
                    flush=True,
                )
            else:
                self.written += 1

    def summary(self) -> str | None:
        """What the file lacks, for the command's last lines (None: nothing lost)."""
        if not self.lost:
            return None
        return (
            f"{self.who}: verdicts: {self.written} lines written to {self.path}, "
            f"{self.lost} not written ({self.error})"
        )

    def close(self) -> None:
        if self._file is sys.stdout:
            with contextlib.suppress(OSError, ValueError):
                sys.stdout.flush()
            return
        try:
            self._file.close()  # its last flush may fail too: said as a write would be
        except OSError as e:
            if self.error is None:
                self.error = e.strerror or str(e)
                print(
                    f"{self.who}: cannot write verdicts to {self.path}: {self.error}",
                    file=sys.stderr,
                    flush=True,
                )


@contextlib.contextmanager
def verdict_sink(path: str, who: str = "fairino-conformance") -> Iterator[VerdictSink]:
    """A :class:`VerdictSink` to ``path``, closed on exit."""
    sink = VerdictSink(path, who)
    try:
        yield sink
    finally:
        sink.close()
