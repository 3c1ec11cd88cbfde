"""pytest plugin: the packaged conformance suite, one test item per case.

Registered through the ``pytest11`` entry point, so any ``pytest`` in any
directory has the options.  The suite is **off** unless switched on by one of:

* ``--target HOST:PORT`` (or ini key ``fairino_target``, or ``$FAIRINO_TARGET``):
  run it against that endpoint;
* ``--conformance`` (or ``$FAIRINO_CONFORMANCE=1``): run it against an in-process
  emulator on an ephemeral loopback port.

When on, the cases are added to whatever else pytest collected (the project's
own ``pytest`` run, without these options, stays as it is).  Items are named
``{cmd_id}::{name}/{group}/{what}``: JUnit's classname is the command ID.  Select
one case with ``--case ID`` (what the reproduction lines use), or with ``-k``.

Exit status of plain pytest: 0 conformant (NON-STRICT and UNIMPLEMENTED pass,
as xfail for the latter), 1 conformance failures, 2 when a case ended in ERROR
(kit or connection error), pytest's own codes otherwise (4 usage, 5 nothing
collected).

Bounded against hostile targets: ``--case-timeout`` ends a case, ``--budget``
the run (default 3 hours, see ``SuiteConfig.budget``).  When the target does not
answer at the start, dies mid-run, or the budget runs out, the session stops
with one line naming the address and the reason (pytest's "Interrupted"), exit
status 2, and the report lists the cases not run.
"""

from __future__ import annotations

import os
import random
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from .errors import ConformanceError
from .net import parse_address
from .report import CaseResult, Outcome
from .safety import SafetyPolicy
from .suite.config import DEFAULT_BUDGET, GROUPS, PROFILES, SuiteConfig
from .suite.runner import Case, SuiteRunner

__all__ = ["CaseItem", "CommandNode", "load_expected_failures"]

_CONFIG_KEY = pytest.StashKey[SuiteConfig]()
_RUNNER_KEY = pytest.StashKey["SuiteRunner | None"]()
_CASES_KEY = pytest.StashKey["list[Case]"]()

#: (option dest, ini key, environment variable, help, default)
_SETTINGS: tuple[tuple[str, str, str, str, str | None], ...] = (
    ("target", "fairino_target", "FAIRINO_TARGET", "HOST:PORT of the endpoint under test", None),
    ("transport", "fairino_transport", "FAIRINO_TRANSPORT", "tcp (default) or udp", "tcp"),
    ("profile", "fairino_profile", "FAIRINO_PROFILE", "quick, default or thorough", "default"),
    (
        "reference",
        "fairino_reference",
        "FAIRINO_REFERENCE",
        "field (default: a recorded field dialect is DIALECT, not a failure) or manual "
        "(the manual alone)",
        "field",
    ),
    (
        "reply_timeout",
        "fairino_reply_timeout",
        "FAIRINO_REPLY_TIMEOUT",
        "seconds to wait for a reply (2)",
        "2",
    ),
    (
        "case_timeout",
        "fairino_case_timeout",
        "FAIRINO_CASE_TIMEOUT",
        "time budget of one case, seconds (60)",
        "60",
    ),
    (
        "recovery_timeout",
        "fairino_recovery_timeout",
        "FAIRINO_RECOVERY_TIMEOUT",
        "how long a silent or crashed target may take to answer again, seconds (10)",
        None,
    ),
    (
        "budget",
        "fairino_budget",
        "FAIRINO_BUDGET",
        "time budget of the whole run, seconds (10800: 3 hours)",
        None,
    ),
    ("rate", "fairino_rate", "FAIRINO_RATE", "at most this many frames per second", None),
    (
        "report_json",
        "fairino_report_json",
        "FAIRINO_REPORT_JSON",
        "write the JSON report here",
        None,
    ),
    (
        "report_html",
        "fairino_report_html",
        "FAIRINO_REPORT_HTML",
        "write the HTML report here",
        None,
    ),
    (
        "expected_failures",
        "fairino_expected_failures",
        "FAIRINO_EXPECTED_FAILURES",
        "baseline file of case IDs expected to fail",
        None,
    ),
)


def pytest_addoption(parser: pytest.Parser) -> None:
    g = parser.getgroup("fairino-conformance", "FAIRINO protocol conformance suite")
    for dest, ini, env, help_text, _default in _SETTINGS:
        g.addoption(
            f"--{dest.replace('_', '-')}",
            dest=f"fairino_{dest}",
            default=None,
            help=f"{help_text} [ini {ini}, env {env}]",
        )
        parser.addini(ini, help_text, default=None)
    g.addoption(
        "--conformance",
        action="store_true",
        default=False,
        dest="fairino_conformance",
        help="run the suite (against the in-process emulator unless --target is given)",
    )
    g.addoption(
        "--commands",
        action="append",
        default=[],
        dest="fairino_commands",
        help="only these commands: IDs, names, globs, comma-separated [env FAIRINO_COMMANDS]",
    )
    g.addoption(
        "--exclude",
        action="append",
        default=[],
        dest="fairino_exclude",
        help="leave these commands out (IDs, names, globs) [env FAIRINO_EXCLUDE]",
    )
    g.addoption(
        "--groups",
        action="append",
        default=[],
        dest="fairino_groups",
        help=f"only these case groups ({', '.join(GROUPS)})",
    )
    g.addoption(
        "--case",
        action="append",
        default=[],
        dest="fairino_case",
        help="run only the case with this ID (repeatable)",
    )
    # pytest owns --strict (an alias of --strict-markers); ``fairino-conformance run --strict``
    # maps to this.
    g.addoption(
        "--strict-conformance",
        action="store_true",
        default=False,
        dest="fairino_strict",
        help="NON-STRICT departures fail [env FAIRINO_STRICT=1]",
    )
    g.addoption(
        "--allow-motion",
        action="store_true",
        default=False,
        dest="fairino_allow_motion",
        help="send motion and program commands to a non-loopback target",
    )
    g.addoption(
        "--allow-io",
        action="store_true",
        default=False,
        dest="fairino_allow_io",
        help="send I/O commands to a non-loopback target",
    )
    g.addoption(
        "--allow-config",
        action="store_true",
        default=False,
        dest="fairino_allow_config",
        help="send configuration commands to a non-loopback target",
    )
    g.addoption(
        "--allow-destructive",
        action="append",
        default=[],
        dest="fairino_allow_destructive",
        metavar="NAME",
        help="send this destructive command (by name or ID; repeatable)",
    )
    g.addoption(
        "--emulator-fault",
        action="append",
        default=[],
        dest="fairino_emulator_fault",
        metavar="KIND[:CMD_IDS]",
        help="inject a fault into the in-process emulator (kit self-test)",
    )
    g.addoption(
        "--dry-run",
        action="store_true",
        default=False,
        dest="fairino_dry_run",
        help="decide every case (safety, selection) but send nothing",
    )


def _setting(config: pytest.Config, dest: str) -> str | None:
    for d, ini, env, _h, default in _SETTINGS:
        if d == dest:
            v = config.getoption(f"fairino_{dest}")
            if v is None:
                v = config.getini(ini) or None
            if v is None:
                v = os.environ.get(env) or None
            return str(v) if v is not None else default
    raise KeyError(dest)


def _float(config: pytest.Config, dest: str) -> float | None:
    v = _setting(config, dest)
    if v is None:
        return None
    try:
        return float(v)
    except ValueError:
        raise pytest.UsageError(f"--{dest.replace('_', '-')}: {v!r} is not a number") from None


def _positive(config: pytest.Config, dest: str, default: float) -> float:
    v = _float(config, dest)
    if v is None:
        return default
    if not v > 0:
        raise pytest.UsageError(f"--{dest.replace('_', '-')} must be positive, not {v:g}")
    return v


def load_expected_failures(path: str) -> frozenset[str]:
    """Case IDs, one a line; ``#`` starts a comment.  A JSON report works too (its FAILs)."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as e:
        raise pytest.UsageError(
            f"--expected-failures: cannot read {path}: {e.strerror or e}"
        ) from None
    if text.lstrip().startswith("{"):
        import json

        from .report import Report

        try:
            rep = Report.from_json(json.loads(text))
        except (ValueError, KeyError, TypeError) as e:
            raise pytest.UsageError(f"--expected-failures: {path} is not a report: {e}") from None
        return frozenset(c.id for c in rep.cases if c.outcome in (Outcome.FAIL, Outcome.ERROR))
    ids = (line.split("#", 1)[0].strip() for line in text.splitlines())
    return frozenset(i for i in ids if i)


def _enabled(config: pytest.Config) -> bool:
    return bool(
        config.getoption("fairino_conformance")
        or os.environ.get("FAIRINO_CONFORMANCE", "").strip() not in ("", "0")
        or _setting(config, "target")
    )


def _split_env(values: list[str], env: str) -> tuple[str, ...]:
    if not values and os.environ.get(env):
        values = [os.environ[env]]
    return tuple(values)


def _suite_config(config: pytest.Config) -> SuiteConfig:
    target_text = _setting(config, "target")
    target = parse_address(target_text, default_port=8080) if target_text else None
    profile_name = _setting(config, "profile") or "default"
    if profile_name not in PROFILES:
        raise pytest.UsageError(
            f"--profile must be one of {', '.join(PROFILES)}, not {profile_name!r}"
        )
    seed_opt = config.getoption("hypothesis_seed", default=None)
    try:
        seed = int(seed_opt) if seed_opt is not None else random.getrandbits(32)
    except ValueError:
        raise pytest.UsageError(f"--hypothesis-seed must be an integer, not {seed_opt!r}") from None
    hyp_profile = config.getoption("hypothesis_profile", default=None)
    if hyp_profile is not None:
        from hypothesis import settings
        from hypothesis.errors import InvalidArgument

        try:
            settings.get_profile(hyp_profile)
        except InvalidArgument as e:
            raise pytest.UsageError(f"--hypothesis-profile: {e}") from None
    host = target[0] if target else None
    safety = SafetyPolicy.for_target(
        host,
        embedded=target is None,
        allow_config=config.getoption("fairino_allow_config"),
        allow_io=config.getoption("fairino_allow_io"),
        allow_motion=config.getoption("fairino_allow_motion"),
        destructive=config.getoption("fairino_allow_destructive"),
    )
    groups = tuple(
        g.strip() for v in config.getoption("fairino_groups") for g in v.split(",") if g.strip()
    )
    expected = _setting(config, "expected_failures")
    strict = config.getoption("fairino_strict") or os.environ.get("FAIRINO_STRICT", "") not in (
        "",
        "0",
    )
    return SuiteConfig(
        target=target,
        transport=(_setting(config, "transport") or "tcp").lower(),
        commands=_split_env(config.getoption("fairino_commands"), "FAIRINO_COMMANDS"),
        exclude=_split_env(config.getoption("fairino_exclude"), "FAIRINO_EXCLUDE"),
        groups=groups or GROUPS,
        profile=PROFILES[profile_name],
        strict=bool(strict),
        reference=(_setting(config, "reference") or "field").lower(),
        reply_timeout=_float(config, "reply_timeout") or 2.0,
        case_timeout=_float(config, "case_timeout") or 60.0,
        recovery_timeout=_positive(config, "recovery_timeout", 10.0),
        budget=_positive(config, "budget", DEFAULT_BUDGET),
        rate=_float(config, "rate"),
        seed=seed,
        safety=safety,
        emulator_faults=tuple(config.getoption("fairino_emulator_fault")),
        expected_failures=load_expected_failures(expected) if expected else frozenset(),
        hypothesis_profile=hyp_profile,
    )


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "conformance: a case of the packaged FAIRINO conformance suite"
    )
    if not _enabled(config):
        return
    try:
        config.stash[_CONFIG_KEY] = _suite_config(config)
    except ConformanceError as e:
        raise pytest.UsageError(str(e)) from None
    config.stash[_RUNNER_KEY] = None


# --------------------------------------------------------------------------- collection


class CommandNode(pytest.Collector):
    """All cases blamed on one command ID (JUnit classname = the command ID)."""

    def __init__(self, *, cases: list[Case], **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.cases = cases

    def collect(self) -> list[pytest.Item]:
        return [CaseItem.from_parent(self, name=c.item_name, case=c) for c in self.cases]


class CaseFailed(Exception):
    def __init__(self, result: CaseResult, prefix: str = "") -> None:
        super().__init__(result.detail)
        self.result = result
        self.prefix = prefix


class CaseItem(pytest.Item):
    """One conformance case."""

    def __init__(self, *, case: Case, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.case = case
        self.add_marker("conformance")
        self.user_properties.append(("case_id", case.id))
        self.user_properties.append(("group", case.group))

    def runtest(self) -> None:
        config = self.config.stash[_CONFIG_KEY]
        if self.config.getoption("fairino_dry_run"):
            if self.case.command is not None:
                from .spec import default_specs

                ok, why = config.safety.permits(self.case.command, default_specs())
                if not ok:
                    pytest.skip(why)
            pytest.skip("dry run: would run")
        runner = _runner(self.config)
        result = runner.run(self.case)
        if runner.stopped is not None:
            # Unreachable, dead, or out of budget: the rest would only repeat it.
            self.session.shouldstop = runner.stopped
        expected = self.case.id in config.expected_failures
        outcome = result.outcome
        if outcome is Outcome.NON_STRICT and config.strict:
            outcome = Outcome.FAIL
        if outcome is Outcome.DIALECT:
            # JUnit shows the dialect and its source as properties of the testcase.
            self.user_properties.append(("dialect", result.source))
            if config.reference == "manual":
                outcome = Outcome.FAIL
        if expected:
            if outcome in (Outcome.FAIL, Outcome.ERROR):
                pytest.xfail(f"expected failure: {result.detail}")
            if outcome is Outcome.PASS:
                raise CaseFailed(result, "listed in --expected-failures but passed: ")
        if outcome in (Outcome.FAIL, Outcome.ERROR):
            raise CaseFailed(result)
        if outcome is Outcome.SKIPPED:
            pytest.skip(result.detail or "skipped")
        if outcome is Outcome.UNIMPLEMENTED:
            pytest.xfail(f"UNIMPLEMENTED: {result.detail}")

    def repr_failure(self, excinfo: pytest.ExceptionInfo[BaseException], style: Any = None) -> str:
        if isinstance(excinfo.value, CaseFailed):
            r = excinfo.value.result
            lines = [f"{r.outcome.value}: {excinfo.value.prefix}{r.detail}"]
            lines += [f"  {f}" for f in r.frames]
            if r.reproduce:
                lines.append(f"reproduce: {r.reproduce}")
            return "\n".join(lines)
        return str(super().repr_failure(excinfo, style=style))  # type: ignore[arg-type]

    def reportinfo(self) -> tuple[Path, int | None, str]:
        return Path(__file__).parent / "suite" / "cases.py", None, self.case.id


def _runner(config: pytest.Config) -> SuiteRunner:
    runner = config.stash.get(_RUNNER_KEY, None)
    if runner is None:
        from .spec import default_specs

        runner = SuiteRunner(config.stash[_CONFIG_KEY], default_specs())
        runner.start()
        config.stash[_RUNNER_KEY] = runner
    return runner


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(
    session: pytest.Session, config: pytest.Config, items: list[pytest.Item]
) -> None:
    if _CONFIG_KEY not in config.stash:
        return
    from .spec import default_specs
    from .suite.cases import build_cases

    sc = config.stash[_CONFIG_KEY]
    try:
        cases = build_cases(default_specs(), sc)
    except ConformanceError as e:
        raise pytest.UsageError(str(e)) from None
    wanted = set(config.getoption("fairino_case"))
    if wanted:
        unknown = wanted - {c.id for c in cases}
        if unknown:
            raise pytest.UsageError(f"--case: no case {sorted(unknown)[0]!r} in this selection")
        cases = [c for c in cases if c.id in wanted]
    config.stash[_CASES_KEY] = cases
    nodes: dict[int, list[Case]] = {}
    order: list[int] = []
    for c in cases:
        if c.cmd_id not in nodes:
            nodes[c.cmd_id] = []
            order.append(c.cmd_id)
        nodes[c.cmd_id].append(c)
    collectors = {
        cid: CommandNode.from_parent(session, name=str(cid), nodeid=str(cid), cases=nodes[cid])
        for cid in order
    }
    by_id = {cid: {i.name: i for i in col.collect()} for cid, col in collectors.items()}
    items.extend(by_id[c.cmd_id][c.item_name] for c in cases)


# --------------------------------------------------------------------------- reporting


def pytest_terminal_summary(terminalreporter: Any, exitstatus: int, config: pytest.Config) -> None:
    runner = config.stash.get(_RUNNER_KEY, None)
    if runner is None or not runner.report.cases:
        return
    tr = terminalreporter
    tr.section("FAIRINO conformance: results per command ID")
    width = getattr(tr, "_tw", None)
    tr.write_line(runner.report.render_terminal(width=max(getattr(width, "fullwidth", 100), 80)))
    for path_key in ("report_json", "report_html"):
        path = _setting(config, path_key)
        if path:
            tr.write_line(f"{path_key.replace('_', ' ')} written to {path}")


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    config = session.config
    runner = config.stash.get(_RUNNER_KEY, None)
    if runner is None:
        return
    try:
        runner.close()
    except Exception as e:  # the emulator's thread failed: a kit error
        print(f"fairino-conformance: emulator failure: {e}", file=sys.stderr)
        session.exitstatus = 2
    if runner.stopped is not None:
        # The session stopped early: the report still lists every selected case.
        done = {c.id for c in runner.report.cases}
        for item in session.items:
            if isinstance(item, CaseItem) and item.case.id not in done:
                runner.not_run(item.case)
    _write_reports(config, runner)
    if runner.report.exit_code() == 2 and int(exitstatus) in (0, 1):
        session.exitstatus = 2


def _write_reports(config: pytest.Config, runner: SuiteRunner) -> None:
    if runner.address is not None and runner.config.embedded:
        runner.report.meta["emulator_address"] = f"{runner.address[0]}:{runner.address[1]}"
    jpath = _setting(config, "report_json")
    if jpath:
        Path(jpath).write_text(runner.report.dumps(), encoding="utf-8")
    hpath = _setting(config, "report_html")
    if hpath:
        from .report import render_html

        Path(hpath).write_text(render_html([runner.report]), encoding="utf-8")


def current_runner(config: pytest.Config) -> SuiteRunner | None:
    """The session's runner (for ``fairino-conformance run`` and tests)."""
    return config.stash.get(_RUNNER_KEY, None)


def iter_cases(config: pytest.Config) -> Iterator[Case]:
    yield from config.stash.get(_CASES_KEY, [])
