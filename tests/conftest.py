"""Learning tests judge counts over seeds, never one seed's draw (docs/determinism.md).

XLA compiles for the host's instruction set, so every learning run is another
draw on another machine. A learning test therefore trains several seeds (vmapped
in one program where the path allows it) and asserts that at least a share of
them reach the claim, at a budget where the claim was measured on at least 9 of
10 seeds. Each count is printed at the end of the session ("learning margins"),
so a run of the slow tests under ``XLA_FLAGS=--xla_cpu_max_isa=...`` measures
the margins of that instruction set; ``TPO_TEST_SEEDS=10`` trains ten seeds per
test instead of the default to measure a budget.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable

import pytest

_MARGINS: list[str] = []


def _seed_count(default: int) -> int:
    text = os.environ.get("TPO_TEST_SEEDS")
    if text is None:
        return default
    if not text.isdigit() or int(text) < 1:
        raise pytest.UsageError(f"TPO_TEST_SEEDS must be a positive integer, got {text!r}")
    return int(text)


@pytest.fixture
def seeds() -> Callable[[int], list[int]]:
    """``seeds(n)``: the seeds a learning test trains (``n``, or ``TPO_TEST_SEEDS``)."""
    return lambda default: list(range(_seed_count(default)))


@pytest.fixture
def at_least(request: pytest.FixtureRequest) -> Callable[..., None]:
    """``at_least(share, outcomes, detail)``: assert that ``ceil(share * n)`` of the
    ``n`` per-seed outcomes hold, and record the count for the session's summary."""

    def check(share: float, outcomes: Iterable[bool], detail: object = "") -> None:
        outcomes = [bool(o) for o in outcomes]
        needed = math.ceil(share * len(outcomes) - 1e-9)
        passed = sum(outcomes)
        _MARGINS.append(f"{request.node.name}: {passed}/{len(outcomes)} seeds "
                        f"(needs {needed})")
        assert passed >= needed, (f"{passed} of {len(outcomes)} seeds hold the claim, "
                                  f"{needed} needed; per seed {outcomes}; {detail}")

    return check


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if _MARGINS:
        flags = os.environ.get("XLA_FLAGS", "") or "native"
        terminalreporter.section(f"learning margins (XLA_FLAGS: {flags})")
        for line in _MARGINS:
            terminalreporter.write_line(line)
