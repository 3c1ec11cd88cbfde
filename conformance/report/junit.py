"""The report as JUnit XML: one testcase per case, classname = command ID.

A case's element follows its status (report/model.py), named in its ``type``: a failing
case (FAIL, XPASS, and NON-STRICT or DIALECT where the run fails them) is a ``failure``,
ERROR and NOT-RUN an ``error``, XFAIL, SKIPPED and UNIMPLEMENTED ``skipped``.  The suite's
``totals`` property counts cases and commands by status, as the terminal does."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

from ..judge.verdict import Outcome
from .model import CaseResult, Report, Status, spec_label

__all__ = ["junit_xml", "write_junit"]


def _testcase(c: CaseResult, report: Report) -> ET.Element:
    tc = ET.Element(
        "testcase", classname=str(c.cmd_id), name=c.id.split("/", 1)[-1], time=_seconds(c.duration)
    )
    props = ET.SubElement(tc, "properties")
    ET.SubElement(props, "property", name="case_id", value=c.id)
    ET.SubElement(props, "property", name="group", value=c.group)
    if c.source:
        prop = "dialect" if c.outcome is Outcome.DIALECT else "source"
        ET.SubElement(props, "property", name=prop, value=c.source)
    text = "\n".join([c.detail, *c.frames, *([f"reproduce: {c.reproduce}"] if c.reproduce else [])])
    status = report.status(c)
    element = _element(c, status, report)
    if element is not None:
        message = f"expected failure: {c.detail}" if status is Status.XFAIL else c.detail
        if element == "failure":
            message = f"{status.value}: {c.detail}"
        el = ET.SubElement(tc, element, type=status.value, message=message[:500])
        if element != "skipped":
            el.text = text
    return tc


def _element(c: CaseResult, status: Status, report: Report) -> str | None:
    """The JUnit element of a case of ``status``, or None for a passed one."""
    if status in (Status.ERROR, Status.NOT_RUN):
        return "error"
    if report.failing(c):  # FAIL, XPASS, and NON-STRICT / DIALECT where the run says so
        return "failure"
    if status in (Status.XFAIL, Status.SKIPPED, Status.UNIMPLEMENTED):
        return "skipped"
    return None


def _seconds(duration: float) -> str:
    """A case's time as JUnit writes it: seconds (to the microsecond: a case against the
    built-in emulator may take less than a millisecond)."""
    return f"{duration:.6f}"


def junit_xml(report: Report, cases: Sequence[CaseResult] | None = None) -> str:
    """The report as JUnit XML: one testcase per case, classname = command ID."""
    rows = list(report.cases if cases is None else cases)
    kinds = [_element(c, report.status(c), report) for c in rows]
    suite = ET.Element(
        "testsuite",
        name="fairino-conformance",
        tests=str(len(rows)),
        failures=str(kinds.count("failure")),
        errors=str(kinds.count("error")),
        skipped=str(kinds.count("skipped")),
        time=_seconds(sum(c.duration for c in rows)),
    )
    props = ET.SubElement(suite, "properties")
    for k, v in (
        ("totals", f"{report.totals_line('cases')}; {report.totals_line()}"),
        ("target", report.target),
        ("seed", report.seed),
        ("reference", report.reference),
        ("spec_version", report.spec_version),
        ("spec", spec_label(report)),
    ):
        ET.SubElement(props, "property", name=k, value=str(v))
    firmware = report.meta.get("dialects", {}).get("firmware")
    if firmware:  # the firmware version that selected the field dialects
        ET.SubElement(props, "property", name="dialects_firmware", value=str(firmware))
    for c in rows:
        suite.append(_testcase(c, report))
    root = ET.Element("testsuites")
    root.append(suite)
    return ET.tostring(root, encoding="unicode", xml_declaration=True) + "\n"


def write_junit(report: Report, path: str) -> None:
    Path(path).write_text(junit_xml(report), encoding="utf-8")
