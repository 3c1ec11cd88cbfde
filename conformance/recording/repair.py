"""Repair: an unfinished recording rewritten as a valid, indexed one (:func:`recover`),
and output files that appear whole or not at all (:func:`atomic_output`)."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from dataclasses import dataclass

from .._version import __version__
from .salvage import MAGIC, Damage, Walk

__all__ = ["RecoverResult", "atomic_output", "recover"]


@contextlib.contextmanager
def atomic_output(dst: str | os.PathLike[str]) -> Iterator[str]:
    """A temporary path next to ``dst`` to write the output to: renamed to ``dst`` when
    the block succeeds, removed when it fails, so a failed command never leaves a
    half-written file (``recover``, ``import-pcap``).  A directory that cannot be
    written is a :class:`~conformance.errors.RecordingError` naming ``dst``."""
    import secrets

    from ..errors import RecordingError

    final = os.fspath(dst)
    if os.path.isdir(final):
        # Said before a temporary name next to it could be the one an error names.
        raise RecordingError(
            f"cannot write {final}: it is a directory (give the name of a file to write)",
            path=final,
        )
    head, name = os.path.split(final)
    tmp = os.path.join(head, f".{name}.{secrets.token_hex(4)}.part")
    try:
        # O_EXCL: a name nobody else has; mode 0o666 less the umask, as open() gives.
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    except OSError as e:
        raise RecordingError(f"cannot write {final}: {e.strerror or e}", path=str(final)) from None
    try:
        yield tmp
        try:
            os.replace(tmp, final)
        except OSError as e:  # a directory made meanwhile, a read-only target...
            raise RecordingError(f"cannot write {final}: {e.strerror or e}", path=final) from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


@dataclass(frozen=True, kw_only=True)
class RecoverResult:
    messages: int
    was_complete: bool
    stopped: str
    #: What could not be kept (damaged chunks, regions): each says what it cost.
    damage: tuple[Damage, ...] = ()


def recover(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> RecoverResult:
    """Rewrite an unfinished or damaged recording (e.g. of a killed proxy, a copy with a
    bad chunk) as a valid, indexed MCAP file.

    Every record that can be read is kept: schemas, channels, messages (with their
    times and sequence numbers) and metadata, from every readable chunk; a damaged
    chunk is skipped and the reading goes on (:class:`~.salvage.Walk`), and each part
    not kept is in the result's ``damage``.
    """
    from mcap.records import Channel, Message, Metadata, Schema
    from mcap.writer import Writer

    from ..errors import RecordingError, UsageError

    if os.path.abspath(os.fspath(src)) == os.path.abspath(os.fspath(dst)):
        raise UsageError("recover writes a new file: give another output path")
    try:
        fin = open(src, "rb")  # noqa: SIM115
    except FileNotFoundError:
        raise RecordingError(f"no such recording: {os.fspath(src)}", path=os.fspath(src)) from None
    except OSError as e:
        name = os.fspath(src)
        raise RecordingError(f"cannot read {name}: {e.strerror or e}", path=name) from None
    with fin, atomic_output(dst) as tmp, open(tmp, "wb") as fout:
        if fin.read(8) != MAGIC:
            raise RecordingError(f"{os.fspath(src)} is not an MCAP file", path=os.fspath(src))
        walk = Walk(fin, os.fspath(src))
        out = Writer(fout)
        out.start(profile="", library=f"fairino-conformance/{__version__} (recovered)")
        schema_map: dict[int, int] = {}
        chan_map: dict[int, int] = {}
        # A channel first declared in a lost chunk: its summary's copy, declared when
        # a message of it comes (as the file's own order would have it).
        known = {r.id: r for r in walk.summary_records() if isinstance(r, Channel)}
        schemas = {r.id: r for r in walk.summary_records() if isinstance(r, Schema)}

        def schema(sid: int) -> int:
            if sid not in schema_map and sid in schemas:
                s = schemas[sid]
                schema_map[sid] = out.register_schema(s.name, s.encoding, s.data)
            return schema_map.get(sid, 0)

        def channel(c: Channel) -> None:
            chan_map[c.id] = out.register_channel(
                c.topic, c.message_encoding, schema(c.schema_id), dict(c.metadata)
            )

        n = 0
        for rec, _ in walk.records():
            if isinstance(rec, Schema):
                schemas.setdefault(rec.id, rec)
                schema(rec.id)
            elif isinstance(rec, Channel) and rec.id not in chan_map:
                channel(rec)
            elif isinstance(rec, Message):
                if rec.channel_id not in chan_map and rec.channel_id in known:
                    channel(known[rec.channel_id])
                if rec.channel_id in chan_map:
                    out.add_message(
                        chan_map[rec.channel_id],
                        rec.log_time,
                        rec.data,
                        rec.publish_time,
                        rec.sequence,
                    )
                    n += 1
            elif isinstance(rec, Metadata):
                out.add_metadata(rec.name, dict(rec.metadata))
        out.finish()  # type: ignore[no-untyped-call]
    return RecoverResult(
        messages=n,
        was_complete=walk.complete,
        stopped="" if walk.complete else walk.stopped,
        damage=tuple(walk.damage),
    )
