"""The plugin's fixtures honour the suite's options (``fairino_client`` waited a hard-coded 5 s)."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize("timeout", ["0.25", "7.5"])
def test_fairino_client_waits_the_reply_timeout(pytester: pytest.Pytester, timeout: str) -> None:
    pytester.makepyfile(
        f"""
        def test_it(fairino_client, fairino_target):
            assert fairino_target.reply_timeout == {float(timeout)!r}
            assert fairino_client.timeout == {float(timeout)!r}
        """
    )
    result = pytester.runpytest("-p", "no:cacheprovider", "--reply-timeout", timeout)
    result.assert_outcomes(passed=1)


def test_the_ini_key_sets_it_too(pytester: pytest.Pytester) -> None:
    pytester.makeini("[pytest]\nfairino_reply_timeout = 3\n")
    pytester.makepyfile(
        """
        def test_it(fairino_client):
            assert fairino_client.timeout == 3.0
        """
    )
    pytester.runpytest("-p", "no:cacheprovider").assert_outcomes(passed=1)


def test_item_3_an_interrupted_session_says_so_and_lists_the_cases_not_run(
    pytester: pytest.Pytester,
) -> None:
    """Ctrl-C in the third case: the report says after how many cases the session stopped and
    lists the rest as not run, as ``run``'s does (it wrote ``stopped: null`` and read like a
    pass)."""
    pytester.makeconftest(
        """
        import pytest

        seen = []

        @pytest.hookimpl(hookwrapper=True)
        def pytest_runtest_call(item):
            seen.append(item)
            if len(seen) == 3:
                raise KeyboardInterrupt
            yield
        """
    )
    rj = pytester.path / "r.json"
    # no_reraise_ctrlc: the KeyboardInterrupt ends the inner session, not this one.
    result = pytester.inline_run(
        "-p", "no:cacheprovider", "--conformance",
        "--commands", "229", "--groups", "framing,examples,valid",
        "--report-json", str(rj), no_reraise_ctrlc=True,
    )  # fmt: skip
    assert result.ret == pytest.ExitCode.INTERRUPTED
    import json

    doc = json.loads(rj.read_text(encoding="utf-8"))
    cases = [c for cmd in doc["commands"].values() for c in cmd["cases"]]
    not_run = [c for c in cases if c.get("not_run")]
    assert doc["stopped"] is not None and doc["stopped"].startswith("interrupted after 2 of ")
    assert len(cases) >= 3 and len(not_run) == len(cases) - 2 >= 1
    assert doc["exit_code"] == 130 and doc["interrupted"] is True  # pytest itself exits 2
    assert all(c["outcome"] == "ERROR" for c in not_run)
