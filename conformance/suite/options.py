"""The suite's options, defined once: flag, ini key, environment variable, type, default, help.

``fairino-conformance run`` builds its argparse parser from :data:`OPTIONS`, the
pytest plugin its option group and ini keys, and docs/testing.md's option table is
checked against it (``tests/test_engine.py``).  :func:`resolve` reads one
value per option with the precedence command line > ini key > environment
variable > default, and :func:`suite_config` turns the values into a
:class:`~conformance.suite.config.SuiteConfig`, validating each with a message
that names the option.
"""

from __future__ import annotations

import argparse
import math
import os
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import UsageError
from .config import DEFAULT_BUDGET, GROUPS, PROFILES, SuiteConfig

__all__ = [
    "OPTIONS",
    "Option",
    "add_to_argparse",
    "load_expected_failures",
    "option",
    "resolve",
    "suite_config",
]

_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"", "0", "false", "no", "off"}


@dataclass(frozen=True, kw_only=True)
class Option:
    """One suite option.

    ``kind``: ``text``, ``float``, ``int``, ``flag`` (on/off) or ``list``
    (repeatable; comma-separated in ini keys and environment variables).
    ``run_flag`` / ``pytest_flag``: the flag in ``fairino-conformance run`` and
    in pytest (None where that front-end has its own: pytest's ``--junitxml``,
    Hypothesis' ``--hypothesis-seed``).
    """

    name: str
    kind: str
    help: str
    default: Any = None
    choices: tuple[str, ...] | None = None
    metavar: str | None = None
    run_flag: str | None = ""
    pytest_flag: str | None = ""
    #: Must be > 0 (timeouts, budget, rate).
    positive: bool = False
    #: The default as docs/testing.md's table shows it, where ``default`` is None for a reason.
    default_text: str | None = None

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")

    @property
    def run(self) -> str | None:
        return self.flag if self.run_flag == "" else self.run_flag

    @property
    def pytest(self) -> str | None:
        return self.flag if self.pytest_flag == "" else self.pytest_flag

    @property
    def ini(self) -> str:
        return f"fairino_{self.name}"

    @property
    def env(self) -> str:
        return f"FAIRINO_{self.name.upper()}"


OPTIONS: tuple[Option, ...] = (
    Option(
        name="target",
        kind="text",
        metavar="HOST:PORT",
        help="the endpoint under test (default: the built-in emulator)",
    ),
    Option(
        name="transport",
        kind="text",
        choices=("tcp", "udp", "xmlrpc"),
        default="tcp",
        help="tcp or udp; xmlrpc: the SDKs' calls (port 20003): the examples, valid and "
        "invalid cases of each command the SDKs send",
    ),
    Option(
        name="profile",
        kind="text",
        choices=tuple(PROFILES),
        default="default",
        help="how many Hypothesis examples per case: quick, default or thorough",
    ),
    Option(
        name="reference",
        kind="text",
        choices=("field", "manual"),
        default="field",
        help="field: a recorded field dialect is DIALECT, not a failure; manual: the manual alone",
    ),
    Option(
        name="spec_version",
        kind="text",
        metavar="VERSION",
        default_text="3.8.2",
        help="the spec set to judge against: 3.8.2, 3.9.8, a spec-set directory, or auto "
        "(ask the target's GetSoftwareVersion, ID 905, once: the newest spec set not newer "
        "than its firmware)",
    ),
    Option(
        name="commands",
        kind="list",
        metavar="IDS",
        help="only these commands: IDs, names, globs (comma-separated, repeatable)",
    ),
    Option(
        name="exclude",
        kind="list",
        metavar="IDS",
        help="leave these commands out: IDs, names, globs",
    ),
    Option(
        name="groups",
        kind="list",
        metavar="GROUPS",
        help=f"only these case groups: {', '.join(GROUPS)}",
    ),
    Option(name="case", kind="list", metavar="ID", help="only the case with this ID (repeatable)"),
    Option(
        name="strict",
        kind="flag",
        pytest_flag="--strict-conformance",  # pytest owns --strict
        help="NON-STRICT departures fail",
    ),
    Option(
        name="expected_failures",
        kind="text",
        metavar="FILE",
        help="baseline: case IDs (one a line) or a JSON report; listed failures are expected",
    ),
    Option(
        name="reply_timeout",
        kind="float",
        default=2.0,
        positive=True,
        metavar="SECONDS",
        help="seconds to wait for a reply",
    ),
    Option(
        name="case_timeout",
        kind="float",
        default=60.0,
        positive=True,
        metavar="SECONDS",
        help="time budget of one case, seconds",
    ),
    Option(
        name="recovery_timeout",
        kind="float",
        default=10.0,
        positive=True,
        metavar="SECONDS",
        help="how long a silent or crashed target may take to answer again, seconds",
    ),
    Option(
        name="budget",
        kind="float",
        default=DEFAULT_BUDGET,
        positive=True,
        metavar="SECONDS",
        help="time budget of the whole run, seconds (3 hours)",
    ),
    Option(
        name="rate",
        kind="float",
        positive=True,
        metavar="PER_SECOND",
        help="at most this many frames per second",
    ),
    Option(
        name="seed",
        kind="int",
        pytest_flag=None,  # pytest: Hypothesis' --hypothesis-seed
        metavar="N",
        help="Hypothesis seed (default: random, printed in every reproduction)",
    ),
    Option(
        name="update_baseline",
        kind="text",
        metavar="FILE",
        help="after the run, write its failing case IDs here: the baseline "
        "--expected-failures reads (FILE may be that baseline)",
    ),
    Option(name="report_json", kind="text", metavar="PATH", help="write the JSON report here"),
    Option(name="report_html", kind="text", metavar="PATH", help="write the HTML report here"),
    Option(
        name="junitxml",
        kind="text",
        metavar="PATH",
        pytest_flag=None,  # pytest's own --junitxml
        help="write a JUnit XML report here (classname = command ID)",
    ),
    Option(
        name="allow_motion",
        kind="flag",
        help="send motion and program commands to a non-loopback target",
    ),
    Option(name="allow_io", kind="flag", help="send I/O commands to a non-loopback target"),
    Option(
        name="allow_config",
        kind="flag",
        help="send configuration commands to a non-loopback target",
    ),
    Option(
        name="allow_destructive",
        kind="list",
        metavar="NAME",
        help="send this destructive command (by name or ID; repeatable)",
    ),
    Option(
        name="emulator_fault",
        kind="list",
        metavar="KIND[:CMD_IDS]",
        help="inject a fault into the built-in emulator (to test the kit itself)",
    ),
    Option(
        name="dry_run", kind="flag", help="decide every case (selection, safety) but send nothing"
    ),
    Option(
        name="quiet",
        kind="flag",
        pytest_flag=None,  # pytest: -q
        help="no progress line",
    ),
    Option(
        name="verbose",
        kind="flag",
        pytest_flag=None,  # pytest: -v
        help="every command's row in the table (default: the failures, the rows that are "
        "not PASS and the totals)",
    ),
)

_BY_NAME = {o.name: o for o in OPTIONS}


def option(name: str) -> Option:
    return _BY_NAME[name]


def add_to_argparse(p: argparse.ArgumentParser) -> None:
    """``run``'s options, from :data:`OPTIONS` (values stay strings/lists until :func:`resolve`)."""
    for o in OPTIONS:
        if o.run is None:
            continue
        flags = [o.run, *{"quiet": ["-q"], "verbose": ["-v"]}.get(o.name, [])]
        help_text = f"{o.help} [ini {o.ini}, env {o.env}]"
        if o.kind == "flag":
            p.add_argument(*flags, dest=o.name, action="store_true", default=None, help=help_text)
        elif o.kind == "list":
            p.add_argument(
                *flags,
                dest=o.name,
                action="append",
                default=None,
                metavar=o.metavar,
                help=help_text,
            )
        else:
            p.add_argument(
                *flags,
                dest=o.name,
                default=None,
                metavar=o.metavar,
                choices=o.choices,
                help=help_text,
            )


def _split(text: str) -> list[str]:
    """Comma-separated items; a bare command ID after ``KIND:IDS`` belongs to it
    (``--emulator-fault wrong_cnt:201,203`` is one fault on two IDs, not two items)."""
    out: list[str] = []
    for x in (x.strip() for x in text.replace("\n", ",").split(",")):
        if not x:
            continue
        if out and ":" in out[-1] and _MORE_IDS.fullmatch(x):
            out[-1] += f",{x}"
        else:
            out.append(x)
    return out


_MORE_IDS = re.compile(r"\d+(@[0-9.]+)?")


def _convert(o: Option, raw: Any, where: str) -> Any:
    if o.kind == "flag":
        if isinstance(raw, bool):
            return raw
        text = str(raw).strip().lower()
        if text in _TRUE:
            return True
        if text in _FALSE:
            return False
        raise UsageError(f"{where}: {raw!r} is not on or off (1/0, true/false, yes/no)")
    if o.kind == "list":
        items = raw if isinstance(raw, list) else [raw]
        return [x for item in items for x in _split(str(item))]
    text = str(raw).strip()
    if o.choices is not None and text.lower() not in o.choices:
        raise UsageError(f"{where} must be one of {', '.join(o.choices)}, not {text!r}")
    if o.kind == "float":
        try:
            value = float(text)
        except ValueError:
            raise UsageError(f"{where}: {text!r} is not a number") from None
        if o.positive and not (value > 0 and math.isfinite(value)):
            raise UsageError(f"{where} must be positive, not {text}")
        return value
    if o.kind == "int":
        try:
            return int(text)
        except ValueError:
            raise UsageError(f"{where}: {text!r} is not an integer") from None
    return text.lower() if o.choices is not None else text


def resolve(
    cli: Mapping[str, Any],
    ini: Callable[[str], Any] | None = None,
    env: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """Every option's value: command line, else ini key, else environment variable, else default.

    ``cli`` maps option names to what the command line gave (None or an empty
    list when not given); ``ini`` reads an ini key (None or "" when unset).
    """
    env = os.environ if env is None else env
    out: dict[str, Any] = {}
    for o in OPTIONS:
        raw = cli.get(o.name)
        where = o.run or o.flag
        if raw in (None, [], False) and ini is not None:
            v = ini(o.ini)
            if v not in (None, "", []):
                raw, where = v, f"{o.flag} (from ini {o.ini})"
        if raw in (None, [], False):
            v = env.get(o.env)
            if v not in (None, ""):
                raw, where = v, f"{o.flag} (from ${o.env})"
        if raw in (None, [], False):
            out[o.name] = [] if o.kind == "list" else (False if o.kind == "flag" else o.default)
            continue
        out[o.name] = _convert(o, raw, where)
    return out


def load_expected_failures(path: str) -> frozenset[str]:
    """Case IDs, one a line; ``#`` starts a comment.  A JSON report works too (its FAILs),
    read by :func:`~conformance.report.load_report`.  A file that is not UTF-8 text or not
    a report is a :class:`~conformance.errors.ReportFileError` naming it."""
    from ..errors import ReportFileError

    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise UsageError(f"--expected-failures: cannot read {path}: {e.strerror or e}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ReportFileError(
            f"--expected-failures: {path} is not UTF-8 text (byte 0x{data[e.start]:02x} at "
            f"offset {e.start})",
            path=path,
        ) from None
    if text.lstrip().startswith("{"):
        from ..report.model import load_report

        try:
            rep = load_report(path)
        except ReportFileError as e:
            raise ReportFileError(f"--expected-failures: {e}", path=path) from None
        from ..report.baseline import baseline_cases

        return frozenset(c.id for c in baseline_cases(rep))  # what report baseline writes
    ids = (line.split("#", 1)[0].strip() for line in text.splitlines())
    return frozenset(i for i in ids if i)


def suite_config(values: Mapping[str, Any], *, seed: int | None = None) -> SuiteConfig:
    """A :class:`SuiteConfig` from :func:`resolve`'s values (``seed``: when not among them)."""
    import random

    from ..net.addresses import parse_address
    from ..spec.safety import SafetyPolicy
    from ..twin.faults import parse_fault

    target_text = values["target"]
    # The SDKs' XML-RPC port is 20003 on a controller (specs/*/xmlrpc.json).
    default_port = 20003 if values["transport"] == "xmlrpc" else 8080
    target = (
        None
        if target_text is None
        else parse_address(target_text, default_port=default_port, option="--target")
    )
    faults: Sequence[str] = values["emulator_fault"]
    for f in faults:
        parse_fault(f)
    groups = tuple(values["groups"])
    bad = [g for g in groups if g not in GROUPS]
    if bad:
        raise UsageError(f"--groups: unknown case group {bad[0]!r} (one of: {', '.join(GROUPS)})")
    expected = values["expected_failures"]
    chosen_seed = values["seed"] if values["seed"] is not None else seed
    return SuiteConfig(
        target=target,
        transport=values["transport"],
        commands=tuple(values["commands"]),
        exclude=tuple(values["exclude"]),
        groups=groups or GROUPS,
        profile=PROFILES[values["profile"]],
        strict=values["strict"],
        reference=values["reference"],
        reply_timeout=values["reply_timeout"],
        case_timeout=values["case_timeout"],
        recovery_timeout=values["recovery_timeout"],
        budget=values["budget"],
        rate=values["rate"],
        seed=chosen_seed if chosen_seed is not None else random.getrandbits(32),
        safety=SafetyPolicy.for_target(
            target[0] if target else None,
            embedded=target is None,
            allow_config=values["allow_config"],
            allow_io=values["allow_io"],
            allow_motion=values["allow_motion"],
            destructive=values["allow_destructive"],
        ),
        emulator_faults=tuple(faults),
        expected_failures=load_expected_failures(expected) if expected else frozenset(),
        dry_run=values["dry_run"],
        spec_version=values["spec_version"],
    )


def options_table() -> str:
    """docs/testing.md's option table (markdown), generated from :data:`OPTIONS`."""
    rows = [
        "| `run` | pytest | ini key | environment | default | what |",
        "|---|---|---|---|---|---|",
    ]
    for o in OPTIONS:
        if o.kind == "flag":
            default = "off"
        elif o.kind == "list":
            default = "all" if o.name in ("commands", "groups") else "none"
        elif o.default_text is not None:
            default = o.default_text
        elif o.default is None:
            default = "-"
        else:
            default = f"{o.default:g}" if isinstance(o.default, float) else str(o.default)
        run_flag = f"`{o.run}`" if o.run else "-"
        py_flag = (
            f"`{o.pytest}`"
            if o.pytest
            else {
                "seed": "`--hypothesis-seed`",
                "junitxml": "`--junitxml` (pytest's)",
                "quiet": "`-q` (pytest's)",
                "verbose": "`-v` (pytest's)",
            }.get(o.name, "-")
        )
        what = o.help
        rows.append(f"| {run_flag} | {py_flag} | `{o.ini}` | `{o.env}` | {default} | {what} |")
    return "\n".join(rows)


if __name__ == "__main__":  # python -m conformance.suite.options: docs/testing.md's table
    print(options_table())
