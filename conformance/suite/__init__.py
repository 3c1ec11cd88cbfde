"""The packaged conformance suite that ``pytest --target`` (or ``fairino-conformance run``) runs.

Cases are built from the specs (:mod:`conformance.suite.cases`), run against a
target through :class:`conformance.net.client.Client`, and reported per command ID
(:mod:`conformance.report`).  The pytest plugin (:mod:`conformance.pytest_plugin`)
turns each case into one test item.
"""
