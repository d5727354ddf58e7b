"""Checks that hold for every test.

With ``PERCVER_TEST_INSTALLED`` set (as ``.ci/run`` does), the tests must exercise the installed
wheel, not the source tree: stop at once if ``percver`` was imported from anywhere but this
interpreter's environment.

Every PNG a test makes the package write (in this process) must show data in each of its axes
(:mod:`figures`): a blank figure fails the test that wrote it.
"""

import os
import sys
from pathlib import Path

import pytest


def pytest_sessionstart(session):
    if os.environ.get("PERCVER_TEST_INSTALLED"):
        import percver

        where = Path(percver.__file__).resolve()
        if not where.is_relative_to(Path(sys.prefix).resolve()):
            raise RuntimeError(
                f"PERCVER_TEST_INSTALLED is set but percver was imported from {where}, not from the environment {sys.prefix}"
            )


@pytest.fixture(autouse=True)
def figures_are_drawn(monkeypatch):
    try:
        from matplotlib.figure import Figure
    except ImportError:  # the [plot] extra is not installed: no figure can be written
        yield
        return
    from figures import blank_axes, is_png_path

    save = Figure.savefig

    def checked(self, target, *args, **kwargs):
        out = save(self, target, *args, **kwargs)
        if is_png_path(target):
            blank = blank_axes(self, target)
            assert not blank, f"{target}: nothing drawn in {blank}"
        return out

    monkeypatch.setattr(Figure, "savefig", checked)
    yield
