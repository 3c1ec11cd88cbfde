"""Results, reported per command ID (floor 4 of docs/ARCHITECTURE.md).

:mod:`.model` holds the cases, the per-command summaries, the terminal table and
the JSON document; :mod:`.html` the HTML page; :mod:`.junit` JUnit XML; and
:mod:`.write` the one :func:`write_reports` every front-end writes them with.
Whether an outcome fails is :mod:`conformance.judge.verdict`'s, asked through
:meth:`Report.fails`.

Names are imported from their modules when first asked for (``conformance/_lazy.py``):
``decode`` and ``check`` print with the model and never load the HTML or JUnit writer.
"""
