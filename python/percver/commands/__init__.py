"""One module per ``percver`` sub-command (registered in ``percver.cli.COMMANDS``)."""

# Exit status of every command that ends in a verdict (``percver verify``, ``demo``, ``cases ... verify``):
# scripts and CI can tell a proof from an open question from a counterexample without parsing text.
# 1 is bad input (one line on stderr), 2 bad usage (argparse).
EXIT = {"verified": 0, "unknown": 3, "falsified": 4}


def unknown_lines(reasons) -> list[str]:
    """One line per group of unknown cells, from ``(cause, first step, last step, cells)`` groups
    (``percver.cases.mountain_car.verification.reasons``)."""
    return [f"unknown: {n} cell{'s' * (n != 1)} at steps {first}-{last}: {what}" for what, first, last, n in reasons]
