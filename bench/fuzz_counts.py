"""Counts of the property-based suite by reader / command and outcome (issue 29's acceptance: "the counts by reader
and command in the closing note: 0 tracebacks, 0 silent wrong answers").

Runs ``pytest -m fuzz`` (the long profile: hundreds of generated examples per reader; or any pytest arguments
given after ``--``) with a plugin that wraps every ``@hypothesis.given`` test body, and sorts each generated example
into one of four classes:

``refused``
    the body returned and a :class:`skyrig.errors.SkyrigError` was raised while it ran (the reader or command
    refused the input in words; the suite's own rules check the words: file / line / field named);
``accepted``
    the body returned and no SkyrigError was raised: the input was read (or the command exited 0) and the suite's
    comparison with the undamaged run held (within its tolerance);
``traceback``
    the body raised anything else than an AssertionError (an exception that is no SkyrigError escaped);
``silent-wrong``
    the body raised an AssertionError: the suite's rule (same records as the undamaged file, same result within
    tolerance, exit status, words) failed.

A test without ``@given`` (``test_every_bad_option_value``: one bad option value per case, whose rule is a
refusal naming the option within 5 s) counts as one example: passed is ``refused``; failed with a traceback is
``traceback``; failed otherwise (an exit status, words or the time limit) is ``other-fail``.

Rows are the test's node id (one per reader or command: the suites are parametrized by them); the option cases
``[COMMAND--OPTION=VALUE]`` are summed per command.  A SkyrigError
raised and caught inside skyrig (a fallback) would count an accepted example as refused: a stated limit.
Hypothesis replays failing examples while it shrinks them, so the counts of a failing run overstate the failures.

Usage::

    PYTHONPATH=src python bench/fuzz_counts.py                    # pytest -m fuzz tests/test_fuzz_*.py
    PYTHONPATH=src python bench/fuzz_counts.py --max-examples 40   # the same, at most 40 examples per test
    PYTHONPATH=src python bench/fuzz_counts.py --json out.json -- -m fuzz tests/test_fuzz_trust.py -k eo
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from collections import defaultdict
from pathlib import Path

CLASSES = ("refused", "accepted", "traceback", "silent-wrong", "other-fail")


class FuzzCounter:
    """A pytest plugin: per test node id, the count of examples in each class."""

    def __init__(self) -> None:
        self.counts: dict[str, dict[str, int]] = defaultdict(lambda: dict.fromkeys(CLASSES, 0))
        self.node = "?"
        self.raised = 0
        self._before = 0

    # --------------------------------------------------------------------------------------------- patching
    def install(self, max_examples: int | None = None) -> None:
        """Wrap ``hypothesis.given`` and count SkyrigError instances; before the test modules are imported.
        ``max_examples``: cap every test's number of examples (a shorter run of the long profile)."""
        import hypothesis

        if max_examples is not None:
            apply = hypothesis.settings.__call__

            def capped(self_, test):
                if self_.max_examples > max_examples:
                    return apply(hypothesis.settings(self_, max_examples=max_examples), test)
                return apply(self_, test)

            hypothesis.settings.__call__ = capped  # type: ignore[method-assign]

        from skyrig.errors import SkyrigError

        counter = self
        original_new = SkyrigError.__new__

        def counted_new(cls, *args, **kwargs):  # every SkyrigError and subclass goes through here
            counter.raised += 1
            return original_new(cls) if original_new is object.__new__ else original_new(cls, *args, **kwargs)

        SkyrigError.__new__ = counted_new  # type: ignore[method-assign]
        given = hypothesis.given

        def counted_given(*gargs, **gkwargs):
            decorate = given(*gargs, **gkwargs)

            def deco(body):
                @functools.wraps(body)
                def wrapped(*a, **kw):
                    before = counter.raised
                    row = counter.counts[counter.node]
                    try:
                        out = body(*a, **kw)
                    except AssertionError:
                        row["silent-wrong"] += 1
                        raise
                    except Exception as exc:
                        # a refusal the body did not expect fails the test (pytest's exit says so); anything else
                        # escaping is a traceback
                        row["refused" if isinstance(exc, SkyrigError) else "traceback"] += 1
                        raise
                    row["refused" if counter.raised > before else "accepted"] += 1
                    return out

                return decorate(wrapped)

            return deco

        hypothesis.given = counted_given

    # ---------------------------------------------------------------------------------------------- hooks
    @staticmethod
    def row_of(nodeid: str) -> str:
        """The row of a test: its node id, option cases ``[cmd--option=value]`` summed per command."""
        if "[" in nodeid and "--" in nodeid.split("[", 1)[1]:
            head, param = nodeid.split("[", 1)
            return f"{head}[{param.split('--', 1)[0]}]"
        return nodeid

    def pytest_runtest_call(self, item) -> None:  # noqa: D102 - pytest hook
        self.node = self.row_of(item.nodeid)
        self._before = sum(self.counts[self.node].values())

    def pytest_runtest_makereport(self, item, call) -> None:  # noqa: D102 - pytest hook
        if call.when != "call" or sum(self.counts[self.node].values()) != self._before:
            return  # a hypothesis test: its examples were counted one by one
        row = self.counts[self.node]
        if call.excinfo is None:
            row["refused"] += 1
        elif call.excinfo.errisinstance(AssertionError):
            row["other-fail"] += 1
        elif not call.excinfo.errisinstance(BaseException) or call.excinfo.errisinstance(Exception):
            row["traceback"] += 1

    # --------------------------------------------------------------------------------------------- output
    def table(self) -> str:
        rows = [f"| {'reader / command (test)':<70} | " + " | ".join(f"{c:>12}" for c in CLASSES) + " |",
                "|" + "-" * 72 + "|" + "|".join("-" * 14 for _ in CLASSES) + "|"]  # markdown
        total = dict.fromkeys(CLASSES, 0)
        for node in sorted(self.counts):
            c = self.counts[node]
            if not sum(c.values()):
                continue
            for k in CLASSES:
                total[k] += c[k]
            rows.append(f"| {node:<70} | " + " | ".join(f"{c[k]:>12}" for k in CLASSES) + " |")
        rows.append(f"| {'total':<70} | " + " | ".join(f"{total[k]:>12}" for k in CLASSES) + " |")
        return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    import pytest

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path, default=None, help="also write the counts as JSON here")
    ap.add_argument("--max-examples", type=int, default=None,
                    help="cap the examples per test (the long profile asks for 300-400; default: as the tests say)")
    ap.add_argument("pytest_args", nargs="*", help="pytest arguments (after --); default: -m fuzz the fuzz suites")
    ns = ap.parse_args(argv)
    root = Path(__file__).resolve().parent.parent
    args = ns.pytest_args or ["-m", "fuzz", *sorted(str(p) for p in (root / "tests").glob("test_fuzz_*.py"))]
    counter = FuzzCounter()
    counter.install(ns.max_examples)
    t0 = time.perf_counter()
    rc = pytest.main(["-q", "-n", "0", "-p", "no:cacheprovider", *args], plugins=[counter])
    print(f"\nfuzz counts ({time.perf_counter() - t0:.0f} s, pytest exit {int(rc)}):\n{counter.table()}")
    if ns.json:
        ns.json.write_text(json.dumps({"pytest_exit": int(rc), "counts": counter.counts}, indent=1))
    return int(rc)


if __name__ == "__main__":
    sys.exit(main())
