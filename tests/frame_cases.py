"""Shared table of frames: one row drives both the encoder and the decoder tests.

Each row: (id, (cnt, cmd_id, data), the exact bytes).  Rows come from the
manual's examples (section cited) and from the cases the decoder must keep apart
(DATA containing ``III`` or ``/b/f``, non-ASCII DATA, empty DATA).
"""

from __future__ import annotations

FRAME_CASES: list[tuple[str, tuple[int, int, str], bytes]] = [
    # 2.1, table 2-3: MoveJ by point name.
    ("movej-point", (4, 201, 'MoveJ("P1")'), b'/f/bIII4III201III11IIIMoveJ("P1")III/b/f'),
    # 2.1: the reply to it.
    ("movej-reply", (4, 201, "1"), b"/f/bIII4III201III1III1III/b/f"),
    # 2.35, table 2-48: a bare keyword.
    ("stop-keyword", (4, 102, "STOP"), b"/f/bIII4III102III4IIISTOPIII/b/f"),
    # 3.1.1, table 3-1-1.
    ("setdo", (32, 204, "SetDO(0,0,0,0)"), b"/f/bIII32III204III14IIISetDO(0,0,0,0)III/b/f"),
    # 3.2.2: a decimal reply.
    ("getai-reply", (38, 214, "409.50"), b"/f/bIII38III214III6III409.50III/b/f"),
    # 6.3.1: a comma-separated reply.
    (
        "joints-reply",
        (4, 375, "41.713891,-56.263053,89.381937,-119.227549,-89.816387,156.073953"),
        b"/f/bIII4III375III64III41.713891,-56.263053,89.381937,-119.227549,-89.816387,156.073953III/b/f",
    ),
    # Gripper queries reply space-separated values.
    ("space-reply", (7, 229, "0 0"), b"/f/bIII7III229III3III0 0III/b/f"),
    # DATA containing the separator and the tail: LEN decides.
    ("data-with-III", (1, 500, "aIIIb"), b"/f/bIII1III500III5IIIaIIIbIII/b/f"),
    ("data-with-tail", (1, 500, "x/b/fIII/b/f"), b"/f/bIII1III500III12IIIx/b/fIII/b/fIII/b/f"),
    ("data-leading-I", (1, 500, "IIx"), b"/f/bIII1III500III3IIIIIxIII/b/f"),
    ("data-trailing-I", (1, 500, "xII"), b"/f/bIII1III500III3IIIxIIIII/b/f"),
    ("empty-data", (0, 0, ""), b"/f/bIII0III0III0IIIIII/b/f"),
    # LEN counts UTF-8 bytes, not characters.
    ("utf8-data", (9, 500, "程序"), "/f/bIII9III500III6III程序III/b/f".encode()),
    ("max-cnt", (65535, 1, "GetX()"), b"/f/bIII65535III1III6IIIGetX()III/b/f"),
    # 5.1.1: an unquoted IP address argument.
    (
        "ip-args",
        (3, 150, "RobotIPConfig(192.168.58.2,255.255.255.0)"),
        b"/f/bIII3III150III41IIIRobotIPConfig(192.168.58.2,255.255.255.0)III/b/f",
    ),
]

#: Deviations a lenient decoder accepts, with the problem it must report.
#: (id, bytes, expected (cnt, cmd_id, data), expected problems)
LENIENT_CASES: list[tuple[str, bytes, tuple[int, int, str], tuple[str, ...]]] = [
    (
        "len-too-small",
        b'/f/bIII4III201III10IIIMoveJ("P1")III/b/f',
        (4, 201, 'MoveJ("P1")'),
        ("len_mismatch",),
    ),
    (
        "len-too-large",
        b'/f/bIII4III201III12IIIMoveJ("P1")III/b/f/f/bIII1III1III0IIIIII/b/f',
        (4, 201, 'MoveJ("P1")'),
        ("len_mismatch",),
    ),
    (
        "two-I-separator",
        b'/f/bII4II201III11IIIMoveJ("P1")III/b/f',
        (4, 201, 'MoveJ("P1")'),
        ("bad_separator",),
    ),
    (
        "four-I-separator",
        b'/f/bIIII4III201III11IIIMoveJ("P1")III/b/f',
        (4, 201, 'MoveJ("P1")'),
        ("bad_separator",),
    ),
    # 5.x: SetCollisionStrategy's example ends with IIII/b/f.
    (
        "four-I-tail",
        b"/f/bIII202III569III50IIISetCollisionStrategy(2,1000,150,250,{5,5,5,5,5,5})IIII/b/f",
        (202, 569, "SetCollisionStrategy(2,1000,150,250,{5,5,5,5,5,5})"),
        ("bad_separator",),
    ),
    ("cnt-over-uint16", b"/f/bIII70000III1III1IIIxIII/b/f", (70000, 1, "x"), ("bad_cnt",)),
    ("not-utf8", b"/f/bIII1III1III1III\xffIII/b/f", (1, 1, "\ufffd"), ("bad_encoding",)),
]

#: Bytes that are never a frame: (id, bytes, rules of the Malformed events expected, in order).
MALFORMED_CASES: list[tuple[str, bytes, tuple[str, ...]]] = [
    ("garbage-only", b"\x01\xfehello", ("garbage",)),
    ("preamble-only", b"hello world\r\n", ("preamble",)),
    ("preamble-then-frame", b"HELLO\n/f/bIII1III1III1IIIxIII/b/f", ("preamble",)),
    ("nul-only", b"\x00" * 16, ("nul_padding",)),
    ("non-numeric-cnt", b"/f/bIIIxIII201III1III1III/b/f", ("bad_cnt", "garbage")),
    ("non-numeric-id", b"/f/bIII4IIIabcIII1III1III/b/f", ("bad_cmd_id", "garbage")),
    ("non-numeric-len", b"/f/bIII4III201IIIzIII1III/b/f", ("bad_len", "garbage")),
    ("no-separator", b"/f/b4III201III1III1III/b/f", ("bad_separator", "garbage")),
    (
        "missing-tail-then-frame",
        b"/f/bIII4III201III3IIIabc/f/bIII5III201III1III1III/b/f",
        ("bad_tail",),
    ),
    ("truncated", b'/f/bIII4III201III11IIIMoveJ("P', ("truncated",)),
    ("truncated-header", b"/f/bIII4II", ("truncated",)),
]
