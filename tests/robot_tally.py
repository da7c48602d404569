"""How many random robots the property tests run, and through which stages.

Every property test over random robots takes its hypothesis settings from :func:`robots` and
wraps each stage it checks in :func:`stage`. Two environment variables turn the suite into a
count (``benchmarks/bench_robots.py`` sets them):

- ``SPACEID_ROBOTS``: a factor on every such test's number of examples (unset: the suite as it
  is, the fast subset's single examples included). When set, the tests draw only fresh random
  robots: no stored failures replayed, no ``@example`` regressions (the plain suite runs those),
  no shrinking (a failure's seed is what is kept, and shrinking would run more robots than drawn).
- ``SPACEID_ROBOT_TALLY``: a file to which every stage a robot went through is appended as one
  JSON line: the test, the stage, the robot's case (its seed and how it was drawn), and the
  failure's first line or null.
"""

from __future__ import annotations

import json
import os
from contextlib import contextmanager

from hypothesis import HealthCheck, Phase, settings
from hypothesis.errors import UnsatisfiedAssumption

SCALE = "SPACEID_ROBOTS"
TALLY = "SPACEID_ROBOT_TALLY"


def scale() -> float | None:
    """The factor on the examples, None when the suite runs as it is."""
    text = os.environ.get(SCALE)
    return None if text is None else float(text)


def robots(examples: int, fast: int | None = None, **options) -> settings:
    """Hypothesis settings for a property test over ``examples`` random robots (scaled by
    ``SPACEID_ROBOTS``), without a deadline or health checks (an example takes seconds); ``fast``
    of them in the fast subset (``-m "not slow"``: :func:`conftest.examples`), when given."""
    from conftest import examples as fast_or_full

    examples = examples if fast is None else fast_or_full(examples, fast)
    options = {"deadline": None, "suppress_health_check": list(HealthCheck), **options}
    factor = scale()
    if factor is None:
        return settings(max_examples=examples, **options)
    return settings(**{**options, "max_examples": max(1, round(examples * factor)), "database": None,
                       "phases": [Phase.generate]})


@contextmanager
def stage(name: str, **case):
    """Record in the tally that the robot of ``case`` went through stage ``name``: passed, or
    failed with the exception's first line (a hypothesis ``assume`` that rejects it is not
    recorded: it did not run)."""
    try:
        yield
    except UnsatisfiedAssumption:
        raise
    except BaseException as error:
        _record(name, case, f"{type(error).__name__}: {str(error).strip().splitlines()[0] if str(error).strip() else ''}"[:300])
        raise
    _record(name, case, None)


def _record(name, case, failure):
    path = os.environ.get(TALLY)
    if not path:
        return
    test = os.environ.get("PYTEST_CURRENT_TEST", "?").split(" ")[0]
    line = json.dumps({"test": test, "stage": name, "case": {k: _plain(v) for k, v in case.items()}, "failure": failure})
    with open(path, "a") as out:
        out.write(line + "\n")


def _plain(value):
    return value if isinstance(value, (bool, int, float, str, type(None))) else repr(value)
