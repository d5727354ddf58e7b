"""``percver selftest``: the verifier attacks itself.

Random closed loops (:mod:`~percver.selftest.generator`) described as plain data
(:mod:`~percver.selftest.program`) are verified by percver and checked against an independent float
oracle (:mod:`~percver.selftest.oracle`: numpy, onnxruntime, scipy) by a campaign
(:mod:`~percver.selftest.campaign`); a violation is shrunk (:mod:`~percver.selftest.shrink`) to a
runnable reproducer. See docs/selftest.md.
"""

from percver.selftest.campaign import Finding, Tally, reproducer, run, run_campaign
from percver.selftest.generator import generate

__all__ = ["Finding", "Tally", "generate", "reproducer", "run", "run_campaign"]
