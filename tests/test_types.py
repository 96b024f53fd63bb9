"""The type check (mypy over `vslam_core` and `vslam`, configured in pyproject.toml) as a test. In a whole session
it runs in the background from the session's start at the lowest priority, on the CPU the workers leave idle
(tests/type_check.py); this test waits for its result."""

from __future__ import annotations

from type_check import result


def test_the_code_type_checks() -> None:
    check = result()
    assert check.exit_code == 0, check.output
    assert check.output.startswith("Success: no issues found in "), check.output
