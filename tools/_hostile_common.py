"""Shared helpers of tools/hostile.py: the kit's command line, the health query, process
figures (RSS, children, descriptor limits), ports and tables."""

from __future__ import annotations

import contextlib
import resource
import socket
import sys
import time
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from conformance.protocol.decoder import FrameDecoder  # noqa: E402
from conformance.protocol.frame import encode_frame  # noqa: E402
from conformance.spec.commands import Command, Variant, default_specs  # noqa: E402

LOOPBACK = "127.0.0.1"
SERVER_NOFILE = 1024  # the issue's `ulimit -n 1024`
RSS_LIMIT_MB = 300


# --------------------------------------------------------------------------- helpers


#: The checkout whose kit :func:`kit` runs when none is given (``--kit-root``); None: this one.
KIT_ROOT: Path | None = None


def kit(*args: str, root: Path | None = None) -> list[str]:
    """The kit's command line: this checkout's, or another checkout's (``root``, else
    :data:`KIT_ROOT`), found first on PYTHONPATH (``-P``: not the working directory's)."""
    where = root if root is not None else KIT_ROOT
    if where is None:
        return [sys.executable, "-m", "conformance", *args]
    return ["env", f"PYTHONPATH={where}", sys.executable, "-P", "-m", "conformance", *args]


def health_query() -> tuple[Command, Variant]:
    """The lowest-ID argument-less query (the suite's own health check picks the same way)."""
    specs = default_specs()
    for c in sorted(specs, key=lambda c: c.cmd_id):
        if c.safety.value != "query" or len(specs.by_id(c.cmd_id)) != 1:
            continue
        for v in c.variants:
            if v.form == "call" and not v.params and v.returns.arity >= 1:
                return c, v
    raise SystemExit("the specs have no argument-less query")


HEALTH_CMD, _ = health_query()
HEALTH = encode_frame(1, HEALTH_CMD.cmd_id, f"{HEALTH_CMD.name}()")


def ask_health(host: str, port: int, timeout: float = 10.0) -> str:
    """'ok <ms>' when a fresh connection gets the health query answered, else what went wrong."""
    t0 = time.monotonic()
    try:
        with socket.create_connection((host, port), timeout=timeout) as s:
            s.sendall(HEALTH)
            dec = FrameDecoder()
            while True:
                data = s.recv(65536)
                if not data:
                    return "closed without answering"
                for e in dec.feed(data):
                    if getattr(e, "cmd_id", None) == HEALTH_CMD.cmd_id:
                        return f"ok {1000 * (time.monotonic() - t0):.0f} ms"
    except OSError as e:
        return f"FAILED ({e.strerror or e})"


def vm_kb(pid: int, key: str) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def children(pid: int) -> list[int]:
    try:
        text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    except OSError:
        return []
    return [int(x) for x in text.split()]


def limit_nofile() -> None:
    resource.setrlimit(resource.RLIMIT_NOFILE, (SERVER_NOFILE, SERVER_NOFILE))


def raise_own_nofile() -> int:
    _soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    with contextlib.suppress(ValueError, OSError):
        resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
    return resource.getrlimit(resource.RLIMIT_NOFILE)[0]


def free_port() -> int:
    s = socket.socket()
    s.bind((LOOPBACK, 0))
    port = int(s.getsockname()[1])
    s.close()
    return port


def table(title: str, header: tuple[str, ...], rows: Sequence[tuple[str, ...]]) -> None:
    widths = [
        max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(header)
    ]
    print(f"\n## {title}\n")
    print("| " + " | ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)) + " |")
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for r in rows:
        print("| " + " | ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) + " |")
    sys.stdout.flush()
