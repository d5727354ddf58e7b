"""With ``PERCVER_TEST_INSTALLED`` set (as ``.ci/run`` does), the tests must exercise the installed
wheel, not the source tree: stop at once if ``percver`` was imported from anywhere but this
interpreter's environment."""

import os
import sys
from pathlib import Path


def pytest_sessionstart(session):
    if os.environ.get("PERCVER_TEST_INSTALLED"):
        import percver

        where = Path(percver.__file__).resolve()
        if not where.is_relative_to(Path(sys.prefix).resolve()):
            raise RuntimeError(f"PERCVER_TEST_INSTALLED is set but percver was imported from {where}, "
                               f"not from the environment {sys.prefix}")
