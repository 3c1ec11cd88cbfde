"""The kit's HTML pages, built from the Jinja2 templates beside this module
(``conformance/report/templates/``): a run's report, several reports' sections, the
side-by-side matrix, and the fleet's page.  Every page is one self-contained file: its
style and its few lines of script inline, its charts inline SVG (:mod:`.charts`), nothing
fetched when it is viewed.  Jinja2 escapes every value a template prints.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Any

from .model import Status

if TYPE_CHECKING:
    import jinja2

__all__ = ["STATUS_COLOURS", "STATUS_MEANING", "render"]

#: Each status' colour, in the charts and the badges alike (worst first, as Status is).
STATUS_COLOURS: dict[str, str] = {
    Status.ERROR.value: "#212121",
    Status.FAIL.value: "#c62828",
    Status.XPASS.value: "#ad1457",
    Status.XFAIL.value: "#8d6e63",
    Status.STOPPED.value: "#616161",
    Status.DIALECT.value: "#1565c0",
    Status.NON_STRICT.value: "#ef6c00",
    Status.UNIMPLEMENTED.value: "#6a1b9a",
    Status.PASS.value: "#2e7d32",
    Status.SKIPPED.value: "#9e9e9e",
    Status.NOT_RUN.value: "#bdbdbd",
}

#: What each status means, for the legend of every page.
STATUS_MEANING: dict[str, str] = {
    Status.ERROR.value: "the kit or the connection failed",
    Status.FAIL.value: "a definite violation of the protocol",
    Status.XPASS.value: "listed in the baseline but passed: remove it from the baseline",
    Status.XFAIL.value: "expected failure: a failure the baseline lists (does not fail the run)",
    Status.STOPPED.value: "the run stopped in the middle of this command",
    Status.DIALECT.value: "follows a recorded field dialect, not the manual",
    Status.NON_STRICT.value: "lenient framing the manual does not allow",
    Status.UNIMPLEMENTED.value: "the target refuses the command as unknown",
    Status.PASS.value: "follows the manual",
    Status.SKIPPED.value: "not sent (safety profile or selection)",
    Status.NOT_RUN.value: "the run never reached it",
}


@functools.cache
def _environment() -> jinja2.Environment:
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.PackageLoader("conformance.report", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.globals.update(colours=STATUS_COLOURS, meaning=STATUS_MEANING)
    return env


def render(template: str, **context: Any) -> str:
    """The page ``template`` (a file of ``templates/``) filled with ``context``."""
    return _environment().get_template(template).render(**context)
