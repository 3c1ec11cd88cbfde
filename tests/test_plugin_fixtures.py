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
