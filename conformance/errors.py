"""One error tree for the whole kit (docs/ARCHITECTURE.md, "Whose fault").

``ConformanceError`` is the root.  Protocol errors split, as in h11, into
``LocalProtocolError`` (we were asked to build something illegal) and
``RemoteProtocolError`` (the peer sent something illegal).  Each protocol error
carries the rule that was broken (a ``Rule`` member, citing the manual where it
can) and the raw bytes involved, as typed fields rather than a formatted string.
"""

from __future__ import annotations

import enum

__all__ = [
    "EXIT_DAMAGED",
    "EXIT_ERROR",
    "EXIT_FAIL",
    "EXIT_INTERRUPTED",
    "EXIT_OK",
    "AddressError",
    "CaptureError",
    "ConformanceError",
    "EmulatorError",
    "FileError",
    "LocalProtocolError",
    "ProtocolError",
    "RecordingError",
    "RemoteProtocolError",
    "ReportFileError",
    "Rule",
    "SpecError",
    "UsageError",
]


class Rule(str, enum.Enum):
    """A protocol rule, by the name reported to users (``problems`` in JSON output)."""

    #: 1.1, table 1-1-1: a frame starts with ``/f/b``.
    BAD_HEAD = "bad_head"
    #: 1.1, table 1-1-1: a frame ends with ``/b/f``.
    BAD_TAIL = "bad_tail"
    #: 1.1, table 1-1-2 row 3: fields are separated by ``III``.
    BAD_SEPARATOR = "bad_separator"
    #: 1.1: CNT is a uint16 frame counter.
    BAD_CNT = "bad_cnt"
    #: 1.1: CMD_ID is a decimal command number.
    BAD_CMD_ID = "bad_cmd_id"
    #: 1.1: CMD_ID is a decimal command number; this frame's CMD_ID field is empty
    #: (``/f/bIII7IIIIII0IIIIII/b/f``: frcobot_ros2 builds it for a name missing
    #: from its map).  The frame is read with CMD_ID 0, what a C reading of the
    #: empty field gives, and this rule in its problems.
    EMPTY_CMD_ID = "empty_cmd_id"
    #: 1.1: LEN is a decimal length.
    BAD_LEN = "bad_len"
    #: 1.1: LEN is the length of DATA (we read it as UTF-8 bytes).
    LEN_MISMATCH = "len_mismatch"
    #: Frame larger than the configured maximum.
    OVERSIZE = "oversize"
    #: Bytes before a frame head that are not a frame (garbage, preamble).
    GARBAGE = "garbage"
    #: Printable text at the very start of a stream, before any frame (a banner or
    #: a client's hello): a deviation lenient peers live with.
    PREAMBLE = "preamble"
    #: NUL padding after a frame (clients sending fixed 4096-byte buffers).
    NUL_PADDING = "nul_padding"
    #: The rest of a fixed-size send buffer after a frame, sent with it: a NUL (the
    #: frame text's terminator), then NULs and the stale ends of earlier, longer
    #: frames written into the same buffer (frcobot_ros sends
    #: ``sizeof(sendCmdLine)`` bytes after each ``sprintf``).  Pure NULs stay
    #: NUL_PADDING.
    BUFFER_TAIL = "buffer_tail"
    #: Stream ended inside a frame.
    TRUNCATED = "truncated"
    #: DATA is not UTF-8.
    BAD_ENCODING = "bad_encoding"
    #: DATA does not follow the call grammar ``Name(arg,...)``.
    BAD_DATA = "bad_data"
    #: A number the kit will not read: non-finite (``1e999``), beyond a double's
    #: range, or more digits than ``data.MAX_NUMBER_DIGITS``.  1.1 and chapter 2
    #: carry C ints and doubles, which are finite and print in a few hundred digits.
    BAD_NUMBER = "bad_number"
    #: DATA beyond the parser's bounds (``data.MAX_DEPTH`` nested arrays,
    #: ``data.MAX_ITEMS`` values): far past anything the manual's tables list, and
    #: a bound on the time and memory one DATA can cost.
    DATA_LIMIT = "data_limit"
    #: Whitespace after a comma in an argument list (lenient peers send it).
    SPACE_IN_ARGS = "space_in_args"
    #: Command ID not in the specs.
    UNKNOWN_COMMAND = "unknown_command"
    #: DATA names another command than CMD_ID's.
    NAME_MISMATCH = "name_mismatch"
    #: The call name or keyword in another letter case than the manual's
    #: (``movej``, ``Stop`` for ``STOP``): the manual does not say whether the
    #: controller matches case, so lenient peers' spelling is NON-STRICT.
    NAME_CASE = "name_case"
    #: Argument count differs from every variant of the command.
    ARG_COUNT = "arg_count"
    #: An argument has the wrong type.
    ARG_TYPE = "arg_type"
    #: An argument is outside the range or enum the manual states.
    ARG_RANGE = "arg_range"
    #: A reply's values do not have the declared shape.
    REPLY_SHAPE = "reply_shape"
    #: A value cannot be encoded (local error).
    UNENCODABLE = "unencodable"
    #: XML-RPC (the official SDKs' channel, port 20003): a body that is not a well-formed
    #: ``methodCall`` or ``methodResponse`` (the XML-RPC specification, xmlrpc.com/spec:
    #: its elements, their nesting, the scalar types' text).
    XMLRPC_SYNTAX = "xmlrpc_syntax"
    #: XML-RPC: a body beyond the kit's bounds (bytes, nesting depth, values, digits of a
    #: number): far past what any SDK sends (``specs/*/xmlrpc.json``), and a bound on what
    #: one body can cost.
    XMLRPC_LIMIT = "xmlrpc_limit"
    #: XML-RPC: a document type declaration or an entity (XML 1.0, 2.8 and 4.2).  No
    #: XML-RPC body needs one, and entities are how a small body becomes a huge one.
    XMLRPC_DTD = "xmlrpc_dtd"
    #: XML-RPC: a number no SDK type holds (a non-finite double; an ``int``/``i4`` past
    #: 32 bits, an ``i8`` past 64).
    XMLRPC_NUMBER = "xmlrpc_number"
    #: HTTP/1.1 framing of XML-RPC (RFC 9112, sections 2-3 and 5): a request or status line
    #: or a header field that cannot be read.
    HTTP_SYNTAX = "http_syntax"
    #: HTTP/1.1: a message without a usable body length (RFC 9112, 6.3: the kit reads
    #: ``Content-Length`` bodies only; a POST without one is answered 411).
    HTTP_LENGTH = "http_length"
    #: HTTP/1.1: a header block or body beyond the kit's bounds (answered 431 or 413).
    HTTP_LIMIT = "http_limit"
    #: CNDE (the SDKs' state channel, port 20005): bytes that are not a frame
    #: ``5A 5A | count | type | len | data | A5 A5`` (specs/fairino-field/channels/cnde.json,
    #: ``frame``).
    CNDE_FRAME = "cnde_frame"
    #: CNDE: a frame whose LEN is past the bound (the SDKs' 4096-byte receive buffer).
    CNDE_LIMIT = "cnde_limit"
    #: CNDE: a frame's data that does not read as its type says (an OUTPUT_CONFIG without
    #: its period, a state name list that is not text).
    CNDE_DATA = "cnde_data"


class ConformanceError(Exception):
    """Root of every error the kit raises on purpose."""


class UsageError(ConformanceError):
    """A user mistake (bad option, missing file): the CLI prints it in one line."""


class AddressError(UsageError):
    """An address (``HOST:PORT``) that cannot be read: ``text`` as given, ``reason`` why,
    ``option`` where it came from (``--target``; may be empty)."""

    def __init__(self, text: str, reason: str, *, option: str = "") -> None:
        shown = text if len(text) <= 80 else text[:77] + "..."
        super().__init__(f"{option + ': ' if option else ''}bad address {shown!r}: {reason}")
        self.text = text
        self.reason = reason
        self.option = option


class FileError(ConformanceError):
    """A file the kit was given is missing or is not what it should be (whose fault: the
    file's, not the kit's); ``path`` names it.  The CLI prints it in one line, exit 2."""

    def __init__(self, message: str, *, path: str = "") -> None:
        super().__init__(message)
        self.path = path


class RecordingError(FileError):
    """A recording that cannot be read or written (missing, not MCAP, not the kit's)."""


class CaptureError(FileError):
    """A pcap/pcapng capture that cannot be read, or an interface a live capture cannot
    open (``path`` is then the interface's name)."""


class ReportFileError(FileError):
    """A file given as a conformance report (``report show``, ``--expected-failures``) that is
    not one."""


class EmulatorError(ConformanceError):
    """The built-in emulator's own machinery failed (a thread died, the kit failed on a
    client's bytes): the kit's fault, not the target's; exit code 2."""


class SpecError(ConformanceError):
    """The spec files are missing, malformed or do not match the schema."""

    def __init__(self, message: str, *, path: str | None = None) -> None:
        super().__init__(message if path is None else f"{path}: {message}")
        self.path = path


class ProtocolError(ConformanceError):
    """A protocol rule was broken.  ``rule`` says which, ``raw`` holds the bytes."""

    def __init__(self, message: str, *, rule: Rule, raw: bytes = b"") -> None:
        super().__init__(message)
        self.rule = rule
        self.raw = raw
        self.message = message

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.message!r}, rule={self.rule.value}, raw={self.raw!r})"


class LocalProtocolError(ProtocolError):
    """We were asked to build a frame or value that breaks the protocol."""


class RemoteProtocolError(ProtocolError):
    """The peer sent bytes that break the protocol."""


# Exit codes, the same for every command (``run``, ``serve``, ``check`` ...) and the plugin.
EXIT_OK = 0
#: Conformance failures (or, for ``decode --strict``, malformed input).
EXIT_FAIL = 1
#: Kit error, bad usage, unreachable target.
EXIT_ERROR = 2
#: A damaged recording (a chunk or message that could not be read): the readable rest
#: was read and judged, each damaged part named on stderr (``check``, ``info``,
#: ``recover``, ``diff``, ``export-pcap``); a recording that lost data never passes.
EXIT_DAMAGED = 3
#: Interrupted (Ctrl-C, SIGTERM): 128 + SIGINT, as shells report it.
EXIT_INTERRUPTED = 130
