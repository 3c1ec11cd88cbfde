"""pytest plugin: the packaged conformance suite as test items, and fixtures for your own tests.

Registered through the ``pytest11`` entry point, so any ``pytest`` in any
directory has the options (each also an ini key ``fairino_*`` and a
``FAIRINO_*`` environment variable: :data:`conformance.suite.options.OPTIONS`).
The suite is **off** unless switched on by one of:

* ``--target HOST:PORT`` (ini ``fairino_target``, ``$FAIRINO_TARGET``): run it
  against that endpoint;
* ``--conformance`` (``$FAIRINO_CONFORMANCE=1``): run it against an in-process
  emulator on an ephemeral loopback port.

When on, the cases are added to whatever else pytest collected.  Items are named
``{cmd_id}::{name}/{group}/{what}``: JUnit's classname is the command ID.  This
plugin is a thin front-end: the engine (:mod:`conformance.suite.engine`) selects
and runs the cases, exactly as for ``fairino-conformance run``.

Under ``pytest -n`` (xdist) each worker runs its share against its own engine
and sends each case's result to the controller with the test report, which
writes the JSON, HTML and JUnit reports whole.

Fixtures for a project's own tests (no option needed):

* ``fairino_emulator``: a fresh emulator (TCP and UDP, ports chosen by the
  kernel) for one test; its own failures are raised at teardown;
* ``fairino_emulator_factory``: ``factory(faults=(...), reference=..., dispatch=...)``
  starts more, closed at the end of the session;
* ``fairino_target``: the endpoint under test, a :class:`Target` (``host``,
  ``port``, ``transport``, ``address``): ``--target`` if given, else a session
  emulator;
* ``fairino_client``: a :class:`~conformance.net.client.Client` connected to
  ``fairino_target`` for one test.

Exit status of plain pytest: 0 conformant, 1 conformance failures, 2 when a case
ended in ERROR (kit or connection error), pytest's own codes otherwise.
"""

from __future__ import annotations

import os
import random
import sys
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from .errors import EXIT_ERROR, EXIT_FAIL, EXIT_OK, ConformanceError, EmulatorError
from .judge.verdict import Outcome
from .net.addresses import format_address, parse_address
from .suite.options import OPTIONS, option, resolve

if TYPE_CHECKING:
    from .net.client import Client
    from .net.emulator import EmulatorServer
    from .report.model import CaseResult, Report
    from .suite.config import SuiteConfig
    from .suite.engine import Engine
    from .suite.runner import Case

# pytest loads this plugin into every session of every project where the kit is installed:
# the suite's machinery (engine, emulator, reports) is imported when a session uses it.

__all__ = ["CaseItem", "CommandNode", "Target"]

_CONFIG_KEY = pytest.StashKey["SuiteConfig"]()
_ENGINE_KEY = pytest.StashKey["Engine | None"]()
_CASES_KEY = pytest.StashKey["list[Case]"]()
_MERGED_KEY = pytest.StashKey["Report"]()
_WRITTEN_KEY = pytest.StashKey["list[str]"]()
#: The test report's attributes carrying a case's result (and why the run stopped) from a
#: worker to the controller: pytest and xdist pass a report's extra attributes along, and
#: JUnit XML does not write them (a user property would carry the JSON into every testcase).
_RESULT_ATTR = "fairino_result"
_STOPPED_ATTR = "fairino_stopped"


def pytest_addoption(parser: pytest.Parser) -> None:
    g = parser.getgroup("fairino-conformance", "FAIRINO protocol conformance suite")
    for o in OPTIONS:
        help_text = f"{o.help} [ini {o.ini}, env {o.env}]"
        parser.addini(o.ini, o.help, default=None)
        if o.pytest is None:
            continue
        if o.kind == "flag":
            g.addoption(o.pytest, action="store_true", default=False, dest=o.ini, help=help_text)
        elif o.kind == "list":
            g.addoption(
                o.pytest, action="append", default=[], dest=o.ini, metavar=o.metavar, help=help_text
            )
        else:
            g.addoption(o.pytest, default=None, dest=o.ini, metavar=o.metavar, help=help_text)
    g.addoption(
        "--conformance",
        action="store_true",
        default=False,
        dest="fairino_conformance",
        help="run the suite (against the in-process emulator unless --target is given) "
        "[env FAIRINO_CONFORMANCE=1]",
    )


def _values(config: pytest.Config) -> dict[str, Any]:
    cli: dict[str, Any] = {}
    for o in OPTIONS:
        if o.pytest is not None:
            cli[o.name] = config.getoption(o.ini)
    cli["seed"] = config.getoption("hypothesis_seed", default=None)
    if config.getoption("xmlpath", default=None):
        cli["junitxml"] = None  # pytest writes its own
    return resolve(cli, ini=lambda key: config.getini(key) or None)


def _enabled(config: pytest.Config) -> bool:
    env_on = os.environ.get("FAIRINO_CONFORMANCE", "").strip() not in ("", "0")
    if config.getoption("fairino_conformance") or env_on:
        return True
    t = option("target")
    return bool(config.getoption(t.ini) or config.getini(t.ini) or os.environ.get(t.env))


def _suite_config(config: pytest.Config) -> SuiteConfig:
    from .suite.options import suite_config
    from .suite.spec_choice import with_spec

    values = _values(config)
    seed = None
    workerinput = getattr(config, "workerinput", None)
    if workerinput is not None and values["seed"] is None:
        seed = workerinput.get("fairino_seed")
    hyp_profile = config.getoption("hypothesis_profile", default=None)
    if hyp_profile is not None:
        from hypothesis import settings
        from hypothesis.errors import InvalidArgument

        try:
            settings.get_profile(hyp_profile)
        except InvalidArgument as e:
            raise pytest.UsageError(f"--hypothesis-profile: {e}") from None
    sc = suite_config(values, seed=seed if seed is not None else random.getrandbits(32))
    from dataclasses import replace

    if hyp_profile is not None:
        sc = replace(sc, hypothesis_profile=hyp_profile)
    chosen = workerinput.get("fairino_spec") if workerinput is not None else None
    if chosen is not None:  # the controller asked the target once; its workers do not
        from .spec.firmware import choice_from_json

        return replace(sc, spec=choice_from_json(chosen))
    return with_spec(sc)


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "conformance: a case of the packaged FAIRINO conformance suite"
    )
    if not _enabled(config):
        return
    from .report.model import Report

    try:
        sc = _suite_config(config)
    except ConformanceError as e:
        raise pytest.UsageError(str(e)) from None
    _refuse_shared_state_in_parallel(config, sc)
    if not _is_worker(config):
        _check_report_paths(config)
    if sc.spec is not None and sc.spec.warning and not _is_worker(config):
        print(f"fairino-conformance: warning: {sc.spec.warning}", file=sys.stderr)
    config.stash[_CONFIG_KEY] = sc
    config.stash[_ENGINE_KEY] = None
    merged = Report(
        target=sc.target_label(),
        spec_version="",
        seed=sc.seed,
        transport=sc.transport,
        strict=sc.strict,
        reference=sc.reference,
        meta={
            "profile": sc.profile.name,
            "ran": _how_it_ran(config),
            **({"dry_run": True} if sc.dry_run else {}),
        },
    )
    config.stash[_MERGED_KEY] = merged
    if not _is_worker(config):
        config.pluginmanager.register(_Collector(merged), "fairino-conformance-collector")


@pytest.hookimpl(trylast=True)
def pytest_sessionstart(session: pytest.Session) -> None:
    config = session.config
    if _CONFIG_KEY in config.stash and not _is_worker(config):
        _progress_per_group(config)


def _progress_per_group(config: pytest.Config) -> None:
    """pytest's progress starts a new line each time the first part of a test's ID (its
    file) changes.  The suite's items are named by command ID (JUnit's classname) and run
    group by group, so it started one for each command of each case group: 2,070 lines
    for a clean run.  Its items are drawn under their case group instead (``fairino-
    conformance framing ....``): a line per group, wrapped where pytest wraps a long one.
    The items' IDs stay as they are; only the progress line's label changes, and only
    where pytest draws one (not with ``-v``, where each item has its own line)."""
    tr = config.pluginmanager.get_plugin("terminalreporter")
    if tr is None or config.get_verbosity() > 0:
        return
    draw = tr.write_fspath_result

    def write_fspath_result(nodeid: str, res: str, **markup: bool) -> None:
        draw(_progress_label(nodeid), res, **markup)

    tr.write_fspath_result = write_fspath_result


def _progress_label(nodeid: str) -> str:
    """A case item's progress label, ``fairino-conformance GROUP``; any other ID as it is."""
    cmd_id, sep, rest = nodeid.partition("::")
    parts = rest.split("/")
    if not sep or not cmd_id.isdigit() or len(parts) < 3:
        return nodeid
    return f"fairino-conformance {parts[1]}::{rest}"


def _check_report_paths(config: pytest.Config) -> None:
    """The reports' paths, checked before the session runs a case (not after the whole run)."""
    from .report.write import check_report_paths

    values = _values(config)
    names = ("report_json", "report_html", "junitxml", "update_baseline")
    try:
        check_report_paths({option(k).pytest or option(k).flag: values[k] for k in names})
    except ConformanceError as e:
        raise pytest.UsageError(str(e)) from None


def _how_it_ran(config: pytest.Config) -> str:
    """How the session ran, for the report: one process, or xdist's workers."""
    workers = getattr(config.option, "numprocesses", None)
    return f"pytest -n {workers} (xdist workers)" if workers else "pytest, one process"


#: The case group whose cases move the arm and read it back (Set/Get pairs, motion versus
#: position queries): against one target they must not run on two workers at once.
_SHARED_STATE_GROUP = "stateful"


def _refuse_shared_state_in_parallel(config: pytest.Config, sc: SuiteConfig) -> None:
    """``pytest -n N --target …`` with the stateful group: two workers would move the same
    arm and read each other's positions (against a real controller: two workers sending
    motion at once), so it is refused in one line.  The built-in emulator is one per
    worker, so it is always safe."""
    workers = config.getoption("numprocesses", default=None)
    if _is_worker(config) or not workers or sc.embedded:
        return
    if _SHARED_STATE_GROUP in sc.groups:
        raise pytest.UsageError(
            f"the {_SHARED_STATE_GROUP} group moves the target's arm and reads it back, so two "
            "workers (-n) must not share one --target: run it with -n 0, or leave it out "
            "with --groups"
        )


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node: Any) -> None:
    """xdist: every worker uses the controller's seed (one reproduction for the run)."""
    sc = node.config.stash.get(_CONFIG_KEY, None)
    if sc is not None:
        node.workerinput["fairino_seed"] = sc.seed
        if sc.spec is not None:
            node.workerinput["fairino_spec"] = sc.spec.to_json()


def _is_worker(config: pytest.Config) -> bool:
    return hasattr(config, "workerinput")


def _engine(config: pytest.Config) -> Engine:
    from .suite.engine import Engine

    engine = config.stash.get(_ENGINE_KEY, None)
    if engine is None:
        engine = Engine(config.stash[_CONFIG_KEY])  # the spec set its config chose
        config.stash[_ENGINE_KEY] = engine
    return engine


# --------------------------------------------------------------------------- collection


class CommandNode(pytest.Collector):
    """All cases blamed on one command ID (JUnit classname = the command ID)."""

    def __init__(self, *, cases: list[Case], **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.cases = cases

    def collect(self) -> list[pytest.Item]:
        return [CaseItem.from_parent(self, name=c.item_name, case=c) for c in self.cases]


class CaseFailed(Exception):
    def __init__(self, result: CaseResult, status: str) -> None:
        super().__init__(result.detail)
        self.result = result
        #: What the report counts the case as (FAIL, ERROR, XPASS, ...).
        self.status = status


class CaseItem(pytest.Item):
    """One conformance case: the engine runs it; pytest shows the outcome."""

    def __init__(self, *, case: Case, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.case = case
        #: The case's result and why the run stopped, once run (see pytest_runtest_makereport).
        self.result: CaseResult | None = None
        self.stopped: str | None = None
        self.add_marker("conformance")
        self.user_properties.append(("case_id", case.id))
        self.user_properties.append(("group", case.group))

    def runtest(self) -> None:
        engine = _engine(self.config)
        finished = engine.step(self.case)  # the engine's CaseFinished, as ``run`` gets it
        result = finished.result
        # The controller (xdist) or this process rebuilds the report from it.
        self.result = result
        if engine.runner.stopped is not None:
            # Unreachable, dead, or out of budget: the rest would only repeat it.
            self.session.shouldstop = engine.runner.stopped
            self.stopped = engine.runner.stopped
        outcome = result.outcome
        if outcome is Outcome.DIALECT:
            # JUnit shows the dialect and its source as properties of the testcase.
            self.user_properties.append(("dialect", result.source))
        if finished.failing:  # the engine's decision (Report.failing), not asked again
            raise CaseFailed(result, engine.report.status(result).value)
        if result.expected:
            pytest.xfail(f"expected failure: {result.detail}")
        if outcome is Outcome.SKIPPED:
            pytest.skip(result.detail or "skipped")
        if outcome is Outcome.UNIMPLEMENTED:
            pytest.xfail(f"UNIMPLEMENTED: {result.detail}")

    def repr_failure(self, excinfo: pytest.ExceptionInfo[BaseException], style: Any = None) -> str:
        if isinstance(excinfo.value, CaseFailed):
            r = excinfo.value.result
            lines = [f"{excinfo.value.status}: {r.detail}"]
            lines += [f"  {f}" for f in r.frames]
            if r.reproduce:
                lines.append(f"reproduce: {r.reproduce}")
            return "\n".join(lines)
        return str(super().repr_failure(excinfo, style=style))  # type: ignore[arg-type]

    def reportinfo(self) -> tuple[Path, int | None, str]:
        return Path(__file__).parent / "suite" / "cases" / "__init__.py", None, self.case.id


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Any:
    """The call's test report carries the case's result as attributes of its own (not user
    properties, which JUnit XML would write into every testcase)."""
    report = yield
    if isinstance(item, CaseItem) and call.when == "call" and item.result is not None:
        setattr(report, _RESULT_ATTR, _result_json(item.result))
        if item.stopped is not None:
            setattr(report, _STOPPED_ATTR, item.stopped)
    return report


def _result_json(r: CaseResult) -> dict[str, Any]:
    return {"cmd_id": r.cmd_id, "name": r.name, **r.to_json()}


def _result_from(doc: dict[str, Any]) -> CaseResult:
    from .report.model import CaseResult

    return CaseResult.from_json(doc, cmd_id=doc["cmd_id"], name=doc["name"])


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(
    session: pytest.Session, config: pytest.Config, items: list[pytest.Item]
) -> None:
    if _CONFIG_KEY not in config.stash:
        return
    engine = _engine(config)
    try:
        cases = engine.select(_values(config)["case"])
    except ConformanceError as e:
        raise pytest.UsageError(str(e)) from None
    config.stash[_CASES_KEY] = cases
    if not _is_worker(config):
        for w in engine.warnings(cases):
            config.stash[_MERGED_KEY].meta.setdefault("warnings", []).append(w)
            print(f"fairino-conformance: warning: {w}", file=sys.stderr)
    nodes: dict[int, list[Case]] = {}
    for c in cases:
        nodes.setdefault(c.cmd_id, []).append(c)
    collectors = {
        cid: CommandNode.from_parent(session, name=str(cid), nodeid=str(cid), cases=cs)
        for cid, cs in nodes.items()
    }
    by_id: dict[int, dict[str, pytest.Item]] = {}
    for cid, col in collectors.items():
        collected = col.collect()
        by_id[cid] = {i.name: i for i in collected}
        # Reported as collected, as pytest's own collectors are: "collected N items"
        # then counts the cases (it said "collected 0 items", then ran 3,457).
        session.ihook.pytest_collectreport(
            report=pytest.CollectReport(col.nodeid, "passed", None, list[Any](collected))
        )
    items.extend(by_id[c.cmd_id][c.item_name] for c in cases)


def pytest_report_collectionfinish(
    config: pytest.Config, items: list[pytest.Item]
) -> str | list[str]:
    """After "collected N items": what the suite added, and against what."""
    from .report.text import plural

    cases = config.stash.get(_CASES_KEY, None)
    if cases is None or _is_worker(config):
        return []
    sc = config.stash[_CONFIG_KEY]
    commands = len({c.cmd_id for c in cases})
    groups = ", ".join(sorted({c.group for c in cases}))
    dry = "; dry run, nothing is sent" if sc.dry_run else ""
    spec = f"; spec {sc.spec.label()}" if sc.spec is not None else ""
    return (
        f"fairino-conformance: {plural(len(cases), 'case')} of "
        f"{plural(commands, 'command')} ({groups}) against {sc.target_label()}{spec}{dry}"
    )


# --------------------------------------------------------------------------- reporting


class _Collector:
    """Each case's result, from this process or an xdist worker, into the session's report."""

    def __init__(self, report: Report) -> None:
        self.report = report

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        doc = getattr(report, _RESULT_ATTR, None)
        if not isinstance(doc, dict) or report.when != "call":
            return
        self.report.add(_result_from(doc))
        stopped = getattr(report, _STOPPED_ATTR, None)
        if stopped and self.report.stopped is None:
            self.report.stopped = str(stopped)


def pytest_terminal_summary(terminalreporter: Any, exitstatus: int, config: pytest.Config) -> None:
    from .suite.present import dry_run_lines

    report = config.stash.get(_MERGED_KEY, None)
    if report is None or not report.cases or _is_worker(config):
        return
    tr = terminalreporter
    tr.section("FAIRINO conformance: results per command ID")
    values = _values(config)
    verbose = config.getoption("verbose", default=0) > 0 or values["verbose"]
    if report.meta.get("dry_run"):
        tr.write_line("\n".join(dry_run_lines(report, verbose=verbose)))
    else:  # quiet by default, as ``run``: the rows that are not PASS; -v lists every command
        width = getattr(getattr(tr, "_tw", None), "fullwidth", 100)
        text = report.render_terminal(
            width=max(width, 80), only_failures=not verbose, hidden_note="-v lists them"
        )
        tr.write_line(text)
    written = config.stash.get(_WRITTEN_KEY, [])
    if written:
        tr.write_line(f"reports written: {', '.join(written)}")


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    config = session.config
    if _CONFIG_KEY not in config.stash:
        return
    engine = config.stash.get(_ENGINE_KEY, None)
    if engine is not None:
        engine.note_address()
        for err in engine.finish():  # the emulator's machinery failed: a kit error
            print(f"fairino-conformance: emulator failure: {err.message}", file=sys.stderr)
            session.exitstatus = EXIT_ERROR
    if _is_worker(config):
        return
    report = config.stash[_MERGED_KEY]
    # Ctrl-C (pytest's INTERRUPTED, before this hook changes the status): the report says
    # after how many cases, and lists the rest as not run, as ``run`` does.
    interrupted = int(exitstatus) == int(pytest.ExitCode.INTERRUPTED)
    _finish_report(config, report, engine, interrupted=interrupted)
    _write_reports(config, report)
    if report.exit_code() == EXIT_ERROR and int(exitstatus) in (EXIT_OK, EXIT_FAIL):
        session.exitstatus = EXIT_ERROR


def _finish_report(
    config: pytest.Config, report: Report, engine: Engine | None, *, interrupted: bool = False
) -> None:
    """Spec version, the emulator's address, and the cases a stopped or interrupted session
    never ran (the engine's :func:`~conformance.suite.engine.stop_report`, as for ``run``)."""
    from .spec.dialects import dialects_from
    from .suite.engine import stop_report
    from .suite.spec_choice import load_chosen, note_spec

    sc = config.stash[_CONFIG_KEY]
    if sc.spec is not None:
        dialects = dialects_from(None, load_chosen(sc.spec), version=sc.firmware)
        note_spec(report, sc.spec, dialects)
    if engine is not None:
        report.meta.update({k: v for k, v in engine.report.meta.items() if k not in report.meta})
    cases = config.stash.get(_CASES_KEY, None)
    if cases is None:  # the xdist controller collects nothing itself
        try:
            cases = _engine(config).select(_values(config)["case"])
        except ConformanceError:
            cases = []
    stop_report(report, cases, interrupted=interrupted)


def _write_reports(config: pytest.Config, report: Report) -> None:
    from .report.write import write_reports

    values = _values(config)
    notes: list[str] = []
    config.stash[_WRITTEN_KEY] = write_reports(
        report,
        json_path=values["report_json"],
        html_path=values["report_html"],
        junit_path=values["junitxml"],
        baseline_path=None if report.meta.get("dry_run") else values["update_baseline"],
        notes=notes,
    )
    for note in notes:
        print(f"fairino-conformance: {note}", file=sys.stderr)


# --------------------------------------------------------------------------- fixtures


@dataclass(frozen=True)
class Target:
    """The endpoint under test: ``--target`` (ini, env), or the session's emulator."""

    host: str
    port: int
    transport: str = "tcp"
    #: ``--reply-timeout`` (ini, env): how long ``fairino_client`` waits for a reply.
    reply_timeout: float = 2.0

    @property
    def address(self) -> str:
        return format_address(self.host, self.port)


EmulatorFactory = Callable[..., "EmulatorServer"]


@pytest.fixture(scope="session")
def fairino_emulator_factory() -> Iterator[EmulatorFactory]:
    """Start emulators for the session: ``factory(faults=("wrong_cnt:201",), reference="manual",
    dispatch="any", udp=True, spec_version="3.9.8")``; each listens on 127.0.0.1, ports chosen
    by the kernel, and plays the firmware of its spec set (the default's, else the one named:
    GetSoftwareVersion answers it, and the field dialects are those of its range).
    Closed at the end of the session, re-raising any failure of their own."""
    from .net.emulator import EmulatorServer
    from .suite.spec_choice import load_chosen

    servers: list[EmulatorServer] = []

    def make(
        *,
        faults: Iterable[str] = (),
        reference: str = "field",
        dispatch: str = "recorded",
        udp: bool = True,
        spec_version: str | None = None,
    ) -> EmulatorServer:
        from .judge.judge import Judge
        from .judge.verdict import Reference
        from .spec.dialects import dialects_from
        from .suite.spec_choice import choose

        choice = choose(spec_version, option="spec_version")
        specs = load_chosen(choice)
        dialects = dialects_from(None, specs, version=choice.firmware)
        judge = Judge(specs, dialects, reference=Reference(reference))
        emu = EmulatorServer(
            specs,
            udp_port=0 if udp else None,
            faults=tuple(faults),
            judge=judge,
            dispatch=dispatch,
        )
        emu.start()
        servers.append(emu)
        return emu

    yield make
    errors = []
    for emu in servers:
        try:
            emu.close()
        except (EmulatorError, RuntimeError) as e:
            errors.append(e)
    if errors:
        raise errors[0]


@pytest.fixture
def fairino_emulator() -> Iterator[EmulatorServer]:
    """A fresh emulator for one test (TCP and UDP on 127.0.0.1, ports chosen by the kernel).

    Its ``address`` / ``udp_address`` are where to connect; a failure of its own
    (a kit bug) is raised at teardown."""
    from .net.emulator import EmulatorServer

    with EmulatorServer(udp_port=0) as emu:
        yield emu


@pytest.fixture(scope="session")
def fairino_target(
    request: pytest.FixtureRequest, fairino_emulator_factory: EmulatorFactory
) -> Target:
    """The endpoint under test: ``--target`` / ini ``fairino_target`` / ``$FAIRINO_TARGET``,
    else an emulator started for the session."""
    config = request.config
    values = resolve(
        {o.name: config.getoption(o.ini) for o in OPTIONS if o.pytest is not None},
        ini=lambda key: config.getini(key) or None,
    )
    timeout = float(values["reply_timeout"])
    if values["target"]:
        host, port = parse_address(values["target"], default_port=8080, option="--target")
        return Target(host, port, values["transport"], timeout)
    played = values["spec_version"]  # auto: the emulator plays the default
    emu = fairino_emulator_factory(
        udp=values["transport"] == "udp",
        spec_version=None if (played or "").lower() in ("", "auto") else played,
    )
    if values["transport"] == "udp":
        assert emu.udp_address is not None
        return Target(emu.udp_address[0], emu.udp_address[1], "udp", timeout)
    return Target(emu.address[0], emu.address[1], "tcp", timeout)


@pytest.fixture
def fairino_client(fairino_target: Target) -> Iterator[Client]:
    """A client connected to ``fairino_target`` for one test (closed after it); it waits
    ``--reply-timeout`` for a reply."""
    from .net.client import Client

    t = fairino_target
    with Client(t.host, t.port, transport=t.transport, timeout=t.reply_timeout) as c:
        yield c
