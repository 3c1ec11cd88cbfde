"""Results per firmware, side by side (``report matrix A.json B.json …``).

One row per command ID, one column per report (its target, and the spec set and firmware it
was judged against); a cell is the command's outcome in that report, ``absent in 3.8.2``
where the report's spec set has no such command (so a command new in v3.9.8 is not a
failure of a v3.8.2 controller), or ``-`` where the report has no case for it.  The rows
whose cells differ come first (the worst outcome first among them, then the ID), then the
rest: a seeded fault and the differences between versions are at the top, as
Autobahn|Testsuite shows implementations side by side.

The HTML page is :func:`conformance.report.html.render_html`'s (``report merge``'s matrix),
given this row order, the absent cells and the differing rows; the Markdown and terminal
tables are drawn here from the same :class:`Matrix`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from ..errors import SpecError
from .html import render_html
from .model import STATUS_ORDER, CommandSummary, Report, Status, spec_label

__all__ = ["ABSENT", "Cell", "Matrix", "Row", "build_matrix", "spec_cmd_ids"]

#: A cell's status where the report's spec set lacks the command.
ABSENT = "ABSENT"
#: A cell's status where the report has no case for a command its spec set has.
NONE = "-"


@functools.lru_cache(maxsize=8)
def spec_cmd_ids(version: str) -> frozenset[int] | None:
    """The command IDs of a shipped spec set (its alternative IDs too), or None when no
    spec set of that version is shipped (then nothing is called absent)."""
    from ..spec.commands import load_spec_version

    try:
        return frozenset(load_spec_version(version).cmd_ids)
    except SpecError:
        return None


@dataclass(frozen=True, kw_only=True)
class Cell:
    #: A status' value (report/model.py's Status), :data:`ABSENT` or :data:`NONE`.
    status: str
    #: What the cell says (``FAIL 2/14``, ``absent in 3.8.2``, ``-``).
    text: str
    #: The command's status where the report has it (None: absent, or no case).
    outcome: Status | None = None


@dataclass(frozen=True, kw_only=True)
class Row:
    cmd_id: int
    name: str
    cells: tuple[Cell, ...]

    @property
    def differs(self) -> bool:
        return len({c.status for c in self.cells}) > 1

    @property
    def worst(self) -> Status | None:
        outs = [c.outcome for c in self.cells if c.outcome is not None]
        return min(outs, key=STATUS_ORDER.__getitem__) if outs else None


@dataclass(frozen=True, kw_only=True)
class Column:
    target: str
    spec: str
    #: The firmware the report names (its target's 905 reply, or the spec version).
    firmware: str


@dataclass(frozen=True, kw_only=True)
class Matrix:
    reports: tuple[Report, ...]
    columns: tuple[Column, ...]
    #: Differing rows first (worst outcome, then ID), then the others (likewise).
    rows: tuple[Row, ...]

    @property
    def differing(self) -> tuple[Row, ...]:
        return tuple(r for r in self.rows if r.differs)

    # ------------------------------------------------------------------ renderings

    def html(self, *, title: str = "FAIRINO conformance per firmware") -> str:
        """The self-contained page: ``report merge``'s matrix in this row order."""
        by_id = {r.cmd_id: r for r in self.rows}

        def missing(col: int, cmd_id: int) -> str | None:
            cell = by_id[cmd_id].cells[col]
            return cell.text if cell.status == ABSENT else None

        return render_html(
            list(self.reports),
            title=title,
            order=[r.cmd_id for r in self.rows],
            missing=missing,
            differs={r.cmd_id for r in self.differing},
            heads=[_head(n, c) for n, c in enumerate(self.columns, 1)],
        )

    def markdown(self, *, all_rows: bool = False) -> str:
        """A Markdown table (the differing rows; ``all_rows``: every row), its columns
        explained above it."""
        lines = [f"{n}. {_head(n, c, plain=True)}" for n, c in enumerate(self.columns, 1)]
        lines.append("")
        heads = " | ".join(f"{n}" for n in range(1, len(self.columns) + 1))
        lines += [f"| ID | command | {heads} |", "|---|---|" + "---|" * len(self.columns)]
        rows = self.rows if all_rows else self.differing
        for r in rows:
            cells = " | ".join(_md_cell(c) for c in r.cells)
            lines.append(f"| {r.cmd_id} | {_md_escape(r.name)} | {cells} |")
        lines.append("")
        lines.append(self._summary(shown=len(rows)))
        return "\n".join(lines) + "\n"

    def terminal(self, *, width: int = 100, all_rows: bool = False) -> str:
        """A plain table (the differing rows; ``all_rows``: every row), a legend of the
        columns above it and a count of the rows below it."""
        lines = [f"[{n}] {_head(n, c, plain=True)}" for n, c in enumerate(self.columns, 1)]
        rows = self.rows if all_rows else self.differing
        if rows:
            name_w = min(max(len(r.name) for r in rows), 36)
            cell_w = max(8, min(18, max(len(c.text) for r in rows for c in r.cells)), len("[9]"))
            head = " ".join(f"{f'[{n}]':<{cell_w}}" for n in range(1, len(self.columns) + 1))
            lines.append(f"{'ID':>5}  {'command':<{name_w}} {head}")
            for r in rows:
                cells = " ".join(f"{_fit(c.text, cell_w):<{cell_w}}" for c in r.cells)
                line = f"{r.cmd_id:>5}  {_fit(r.name, name_w):<{name_w}} {cells}"
                lines.append(_fit(line.rstrip(), max(width, 40)))
        lines.append(self._summary(shown=len(rows)))
        return "\n".join(lines)

    def _summary(self, *, shown: int) -> str:
        n, d = len(self.rows), len(self.differing)
        rest = f"; {n - shown} not shown (--all lists every row)" if shown < n else ""
        return f"{n} commands, {d} differ between the {len(self.columns)} reports{rest}"


def _head(n: int, c: Column, *, plain: bool = False) -> str:
    """A column's head: its number, target and firmware (the HTML adds the report's spec
    line, seed, reference and faults beneath it)."""
    if not plain:
        return f"[{n}] {c.target} (firmware {c.firmware})"
    return f"{c.target}, firmware {c.firmware}, spec {c.spec}"


def _fit(text: str, width: int) -> str:
    return text if len(text) <= width else text[: width - 1] + "…"


def _md_escape(text: str) -> str:
    return text.replace("|", "\\|")


def _md_cell(c: Cell) -> str:
    if c.outcome is not None and c.outcome in (Status.FAIL, Status.ERROR, Status.XPASS):
        return f"**{_md_escape(c.text)}**"
    if c.status == ABSENT:
        return f"_{_md_escape(c.text)}_"
    return _md_escape(c.text)


def _column(r: Report) -> Column:
    spec = r.meta.get("spec")
    reported = spec.get("reported") if isinstance(spec, dict) else None
    web = reported.get("web") if isinstance(reported, dict) else None
    faults = r.meta.get("emulator_faults")
    target = r.target + (f" + faults {', '.join(map(str, faults))}" if faults else "")
    return Column(target=target, spec=spec_label(r), firmware=str(web or r.spec_version))


def _cell(
    r: Report, cmd_id: int, summary: CommandSummary | None, ids: frozenset[int] | None
) -> Cell:
    if summary is not None:
        st = summary.status
        counts = summary.counts()
        n = sum(counts.values())
        if st in (Status.PASS, Status.SKIPPED, Status.NOT_RUN):
            text = st.value
        elif st in (Status.XFAIL, Status.STOPPED):  # how many expected; how many never ran
            text = f"{st.value} {counts.get(st.value if st is Status.XFAIL else 'NOT-RUN', 0)}/{n}"
        else:
            passed = ("PASS", "SKIPPED", "XFAIL", "NOT-RUN")
            text = f"{st.value} {sum(v for k, v in counts.items() if k not in passed)}/{n}"
        return Cell(status=st.value, text=text, outcome=st if summary.ran else None)
    if ids is not None and cmd_id not in ids:
        return Cell(status=ABSENT, text=f"absent in {r.spec_version}")
    return Cell(status=NONE, text=NONE)


def build_matrix(
    reports: Sequence[Report],
    *,
    spec_ids: Callable[[str], frozenset[int] | None] = spec_cmd_ids,
) -> Matrix:
    """The matrix of ``reports`` (at least one): a row per command ID any of them has."""
    if not reports:
        raise ValueError("no report to put in a matrix")
    per = [r.commands() for r in reports]
    names: dict[int, str] = {}
    for p in per:
        for i, s in p.items():
            names.setdefault(i, s.name)
    ids = [spec_ids(r.spec_version) for r in reports]
    rows = [
        Row(
            cmd_id=i,
            name=names[i],
            cells=tuple(
                _cell(r, i, p.get(i), known) for r, p, known in zip(reports, per, ids, strict=True)
            ),
        )
        for i in names
    ]

    def order(row: Row) -> tuple[int, int, int]:
        w = row.worst
        return (
            0 if row.differs else 1,
            len(STATUS_ORDER) if w is None else STATUS_ORDER[w],
            row.cmd_id,
        )

    return Matrix(
        reports=tuple(reports),
        columns=tuple(_column(r) for r in reports),
        rows=tuple(sorted(rows, key=order)),
    )
