"""Results, reported per command ID (floor 4 of docs/ARCHITECTURE.md).

:mod:`.model` holds the cases, their statuses (XFAIL, XPASS, NOT-RUN and STOPPED
beside the outcomes) and every total, the per-command summaries, the terminal table and
the JSON document; :mod:`.html` the HTML pages, built from the Jinja2 templates of
:mod:`.pages` with the charts of :mod:`.charts`; :mod:`.matrix` reports side by side;
:mod:`.junit` JUnit XML; :mod:`.baseline` the baseline ``--expected-failures`` reads;
and :mod:`.write` the one :func:`write_reports` every front-end writes them with, and
the one check of their paths before a run.  Whether an outcome fails is
:mod:`conformance.judge.verdict`'s, asked through :meth:`Report.fails`.

Names are imported from their modules when first asked for (``conformance/_lazy.py``):
``decode`` and ``check`` print with the model and never load the HTML or JUnit writer.
"""
