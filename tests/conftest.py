"""Hypothesis profiles for the whole test suite.

``ci`` (the default) is derandomized: every run draws the same examples, so CI is
deterministic and a failure reproduces anywhere. ``explore`` searches with fresh
randomness and more examples; use it locally to hunt for new counterexamples:

    HYPOTHESIS_PROFILE=explore PYTHONPATH=. python -m pytest tests -q
"""

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, database=None, deadline=None)
settings.register_profile("explore", max_examples=2000, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))
