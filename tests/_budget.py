"""Cost budgets for HS-SLAM runs (:class:`hsmap.slam.Costs`): a reference run's counts, and how far each may grow
before a test fails (a change doubling the work fails it)."""

from __future__ import annotations

import math

#: How much a count may grow before the test fails.
MARGIN = 1.3
#: A count this small may grow by this much however small it is (a search or an optimisation more).
SLACK = 2


def budget(reference: dict[str, int]) -> dict[str, int]:
    """The most each count of ``reference`` may reach."""
    return {k: max(math.ceil(MARGIN * v), v + SLACK) for k, v in reference.items()}


def over_budget(costs: dict[str, int], reference: dict[str, int]) -> dict[str, str]:
    """The counts of ``costs`` beyond their budget, each with its budget and reference."""
    limit = budget(reference)
    return {k: f"{costs[k]} > {limit[k]} (reference {reference[k]} x {MARGIN})" for k in limit if costs[k] > limit[k]}
