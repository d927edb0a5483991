"""Checkpoint fingerprints and atomic writes: a resumed run must recognise a different computation, and an
interrupted write must leave nothing that a later run mistakes for its own."""

import functools
import os
import subprocess
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pgtjax._checkpoint import tree_digest
from pgtjax._files import ABANDONED_AFTER_S, write_atomic
from pgtjax.models import gear_pair as gp


def _scaled_load(t, scale):
    return scale * jnp.sin(t)


def _closure(scale):
    def load(t):
        return scale * jnp.sin(t)

    return load


def _with_load(system, load):
    return eqx.tree_at(lambda s: s.load, system, load)


def test_digest_sees_the_values_a_time_function_carries():
    system = gp.build()
    digest = lambda load: tree_digest(_with_load(system, load))  # noqa: E731
    # partial arguments and closure cells are part of the computation
    assert digest(functools.partial(_scaled_load, scale=1.0)) != digest(
        functools.partial(_scaled_load, scale=3.0)
    )
    assert digest(_closure(1.0)) != digest(_closure(3.0))
    assert digest(_closure(jnp.ones(3))) != digest(_closure(jnp.full(3, 2.0)))
    # and so is the body: two lambdas of one name computing different things
    assert digest(lambda t: jnp.sin(t)) != digest(lambda t: jnp.cos(t))
    # the same computation built twice has the same fingerprint
    assert digest(functools.partial(_scaled_load, scale=2.0)) == digest(
        functools.partial(_scaled_load, scale=2.0)
    )
    assert digest(_closure(2.0)) == digest(_closure(2.0))
    assert tree_digest(gp.build()) == tree_digest(gp.build())
    # wrapped, or held by objects
    assert digest(jax.jit(_closure(1.0))) != digest(jax.jit(_closure(3.0)))
    assert digest(jax.tree_util.Partial(_closure(1.0))) != digest(jax.tree_util.Partial(_closure(3.0)))
    assert digest(_Scaled(1.0)) != digest(_Scaled(3.0)) and digest(_Scaled(2.0)) == digest(_Scaled(2.0))
    assert digest(_Scaled(1.0).load) != digest(_Scaled(3.0).load)


class _Scaled:  # a plain object whose method, or itself, is the time function
    def __init__(self, scale):
        self.scale = scale

    def __call__(self, t):
        return self.scale * jnp.sin(t)

    def load(self, t):
        return self.scale * jnp.sin(t)


def test_digest_of_a_recursive_closure_or_a_cyclic_object_terminates():
    def outer():
        def f(n):
            return 1 if n <= 0 else f(n - 1)

        return f

    assert tree_digest(outer()) == tree_digest(outer())
    cyclic = [1.0]
    cyclic.append(cyclic)
    assert tree_digest(_closure(cyclic)) == tree_digest(_closure(cyclic))
    assert tree_digest(_closure([1.0, [2.0]])) != tree_digest(_closure([1.0, [3.0]]))


@pytest.mark.slow
def test_digest_is_the_same_in_another_process():
    """A resumed run is a new process, with another string hash seed, which orders sets and frozensets: in
    a function's constants or in what it carries."""
    code = (
        "import jax.numpy as jnp\n"
        "from pgtjax._checkpoint import tree_digest\n"
        "f = lambda x: x in {'alpha', 'beta', 'gamma', 'delta'}\n"
        "def carry(names):\n"
        "    return lambda t: t if 'alpha' in names else -t\n"
        "g = carry({'alpha', 'beta', 'gamma', 'delta', 'epsilon'})\n"
        "print(tree_digest(f, g, jnp.arange(3.0)))\n"
    )
    outs = {
        subprocess.run(
            [sys.executable, "-c", code],
            env={**os.environ, "PYTHONHASHSEED": seed},
            capture_output=True,
            text=True,
        ).stdout.strip()
        for seed in ("1", "2", "3")
    }
    assert len(outs) == 1 and len(next(iter(outs))) == 24


def test_interrupted_write_leaves_the_previous_file_and_later_writes_clear_its_debris(tmp_path):
    target = tmp_path / "run.npz"
    write_atomic(target, lambda p: np.savez(p, x=np.zeros(2)))

    def dies(p):
        p.write_bytes(b"half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_atomic(target, dies)
    with np.load(target) as data:
        np.testing.assert_array_equal(data["x"], np.zeros(2))
    # a process killed outright cannot clean up: its partial file stays until a later write of the target
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    hours_ago = time.time() - 2 * ABANDONED_AFTER_S

    def left(name, age=hours_ago):
        path = tmp_path / name
        path.write_bytes(b"half")
        os.utime(path, (age, age))
        return path

    debris = left(f".run.partial-{dead.pid}.npz")
    alive = left(f".run.partial-{os.getppid()}.npz")  # a live process's write is left alone
    recent = left(f".run.partial-{dead.pid}0.npz", age=time.time())  # maybe another host's: too recent
    other = left(f".other.partial-{dead.pid}.npz")  # another target's is not this write's to judge
    absurd = left(f".run.partial-{10**30}.npz")  # no process has such a number
    write_atomic(target, lambda p: np.savez(p, x=np.ones(2)))
    assert not debris.exists() and not absurd.exists()
    assert alive.exists() and recent.exists() and other.exists()
    with np.load(target) as data:
        np.testing.assert_array_equal(data["x"], np.ones(2))
    assert jax.numpy.asarray(1.0).dtype == jnp.float64
