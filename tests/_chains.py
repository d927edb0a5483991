"""Test systems shared by several test modules."""

import numpy as np

import pgtjax as pg


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


def backlash_oscillator(**fields):
    """The README's oscillator: a mass on a backlash spring (k = 100 N/m, b = 0.01 m) under a static load and
    white noise; ``fields`` replace System arguments."""
    spring = pg.Contacts(direction=[[1.0]], stiffness=[100.0], clearance=[0.01], names=["spring"])
    args = dict(mass=[[1.0]], stiffness=[[0.0]], damping=[[1.0]], load=[0.6], noise_input=[[1.0]])
    args.update(spectral_density=3.2e-3, contacts=spring, dof_names=["x"])
    return pg.System(**{**args, **fields})
