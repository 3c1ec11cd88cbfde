"""The cases, by group, built from the specs (no per-command logic: see conformance.spec.knowledge).

Case IDs are derived from content, never position:
``{cmd_id}/{name}/{group}/{what}`` (``what`` names the variant table, the
example, the malformed-input kind...).  Cases that concern no single command
(malformed headers, concurrency) use command ID 0, name ``protocol``.

One module per group (:mod:`.framing`, :mod:`.examples`, :mod:`.valid`,
:mod:`.invalid`, :mod:`.robustness`, :mod:`.transport`, :mod:`.stateful`), what they
share in :mod:`.shared`, and :func:`build_cases` in :mod:`.build`.
"""
