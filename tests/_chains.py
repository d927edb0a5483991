"""Test systems shared by several test modules."""

import numpy as np


def grounded_spring_chain(n, spring, seed, *, ground_both_ends=False):
    """``(M, K)`` of a chain of ``n`` random masses (0.5-2 kg) joined by springs of ``spring`` N/m, grounded
    at the first mass (and at the last one with ``ground_both_ends``)."""
    m = np.diag(np.random.default_rng(seed).uniform(0.5, 2.0, n))
    k = np.zeros((n, n))
    for i in range(n - 1):
        k[i : i + 2, i : i + 2] += spring * np.array([[1, -1], [-1, 1]])
    k[0, 0] += spring
    if ground_both_ends:
        k[-1, -1] += spring
    return m, k
