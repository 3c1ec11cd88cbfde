"""The report as JUnit XML: one testcase per case, classname = command ID; a case fails
(``failure``) when the run's reference and ``--strict`` say its outcome fails."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

from ..judge.verdict import Outcome
from .model import CaseResult, Report, spec_label

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
    if c.expected:
        ET.SubElement(tc, "skipped", message=f"expected failure: {c.detail}"[:500])
    elif c.outcome is Outcome.ERROR:
        ET.SubElement(tc, "error", message=c.detail[:500]).text = text
    elif report.failing(c):  # FAIL, and NON-STRICT / DIALECT where the run says so
        ET.SubElement(tc, "failure", message=f"{c.outcome.value}: {c.detail}"[:500]).text = text
    elif c.outcome in (Outcome.SKIPPED, Outcome.UNIMPLEMENTED):
        ET.SubElement(tc, "skipped", message=f"{c.outcome.value}: {c.detail}"[:500])
    return tc


def _seconds(duration: float) -> str:
    """A case's time as JUnit writes it: seconds (to the microsecond: a case against the
    built-in emulator may take less than a millisecond)."""
    return f"{duration:.6f}"


def junit_xml(report: Report, cases: Sequence[CaseResult] | None = None) -> str:
    """The report as JUnit XML: one testcase per case, classname = command ID."""
    rows = list(report.cases if cases is None else cases)
    suite = ET.Element(
        "testsuite",
        name="fairino-conformance",
        tests=str(len(rows)),
        failures=str(sum(report.failing(c) and c.outcome is not Outcome.ERROR for c in rows)),
        errors=str(sum(c.outcome is Outcome.ERROR and not c.expected for c in rows)),
        skipped=str(
            sum(c.expected or c.outcome in (Outcome.SKIPPED, Outcome.UNIMPLEMENTED) for c in rows)
        ),
        time=_seconds(sum(c.duration for c in rows)),
    )
    props = ET.SubElement(suite, "properties")
    for k, v in (
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
