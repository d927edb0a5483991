"""Monte Carlo's normals (``pgtjax._random``): JAX's threefry bits and uniforms bit for bit, an erfinv and a
logarithm checked against SciPy and NumPy, and blocks equal to ``jax.random.normal`` to rounding."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import special

from pgtjax import _random


def _keys(n, seed=3):
    return jax.vmap(lambda i: jax.random.key_data(jax.random.fold_in(jax.random.key(seed), i)))(jnp.arange(n))


def test_uniforms_are_jax_uniforms_bit_for_bit():
    key = jax.random.fold_in(jax.random.key(11), 5)
    words = jax.random.key_data(key)
    counter = jax.lax.iota(jnp.uint32, 21).reshape(7, 3)
    ours = np.asarray(_random._uniform(words[0], words[1], counter))
    theirs = np.asarray(
        jax.random.uniform(key, (7, 3), jnp.float64, minval=np.nextafter(-1.0, 0.0), maxval=1.0)
    )
    assert ours.dtype == np.float64
    np.testing.assert_array_equal(ours, theirs)


def test_logarithm_within_two_ulp_of_numpy():
    rng = np.random.default_rng(0)
    y = np.concatenate(
        [
            rng.uniform(0.0, 1.0, 50_000),
            2.0 ** rng.uniform(-60.0, 0.0, 50_000),
            [2.0**-53, 0.5, np.sqrt(0.5), 1.0],
        ]
    )
    ours = np.asarray(jax.jit(_random._log)(y))
    exact = np.log(y)
    ulp = np.abs(ours - exact) / np.spacing(np.maximum(np.abs(exact), np.finfo(float).tiny))
    assert ours.dtype == np.float64 and np.max(ulp[exact != 0.0]) <= 2.0
    assert ours[-1] == 0.0


def test_erfinv_matches_scipy_near_zero_and_near_one():
    rng = np.random.default_rng(1)
    near_one = 1.0 - 2.0 ** -np.arange(1.0, 53.0)  # where -log1p(-x^2) loses digits
    x = np.concatenate([rng.uniform(-1.0, 1.0, 20_000), near_one, -near_one, [1e-300, -1e-12, 0.0]])
    ours = np.asarray(jax.jit(_random.erfinv)(x))
    exact = special.erfinv(x)
    scale = np.maximum(np.abs(exact), 1e-300)
    assert np.max(np.abs(ours - exact) / scale) < 2e-15
    assert ours[-1] == 0.0


@pytest.mark.slow
@pytest.mark.parametrize("width", [1, 2, 3])
def test_block_normals_are_each_keys_normals(width):
    keys = _keys(5)
    block = np.asarray(_random.block_normals(keys, 7, width))
    assert block.shape == (7, 5, width) and block.dtype == np.float64
    per_key = np.stack(
        [np.asarray(_random.normal(jax.random.wrap_key_data(k), (7, width))) for k in keys], axis=1
    )
    np.testing.assert_array_equal(block, per_key)
    theirs = np.stack(
        [np.asarray(jax.random.normal(jax.random.wrap_key_data(k), (7, width))) for k in keys], axis=1
    )
    np.testing.assert_allclose(block, theirs, rtol=0.0, atol=1e-14)
    assert np.mean(block == theirs) > 0.3  # most are the same double: only the last bits may differ


@pytest.mark.slow
@pytest.mark.parametrize("width", [1, 3])
def test_part_of_a_block_is_that_part_of_the_whole_block(width):
    """Rows drawn a part at a time (Monte Carlo's long saved blocks) are the whole block's rows, double for
    double, for a first row given as a number or, compiled, as a traced integer. (Compiled and op-by-op
    normals may differ in the last bit: XLA may contract a compiled loop's products and sums.)"""
    keys = _keys(4)
    whole = np.asarray(_random.block_normals(keys, 12, width))
    whole_compiled = np.asarray(jax.jit(lambda: _random.block_normals(keys, 12, width))())
    for first, rows in [(0, 5), (5, 5), (10, 2), (3, 1)]:
        part = np.asarray(_random.block_normals(keys, rows, width, first, 12))
        traced = np.asarray(
            jax.jit(lambda f, rows=rows: _random.block_normals(keys, rows, width, f, 12))(jnp.int32(first))
        )
        np.testing.assert_array_equal(part, whole[first : first + rows])
        np.testing.assert_array_equal(traced, whole_compiled[first : first + rows])


def test_only_threefry_keys_draw_part_of_a_block_and_only_rows_of_the_block():
    keys = jax.random.split(jax.random.key(0, impl="rbg"), 3)
    with pytest.raises(ValueError, match="only threefry keys"):
        _random.block_normals(keys, 2, 1, 0, 4)
    with pytest.raises(ValueError, match="rows 3 to 4 are not in a block of 4"):
        _random.block_normals(_keys(2), 2, 1, 3, 4)
    with pytest.raises(ValueError, match="rows -1 to 0"):
        _random.block_normals(_keys(2), 2, 1, -1, 4)


def test_a_million_normals_have_the_normal_moments():
    """Sample moments within 5 standard errors of N(0, 1)'s (a gross check; exactness is the tests above)."""
    z = np.asarray(_random.block_normals(_keys(1000), 500, 2)).ravel()
    n = z.size
    assert abs(z.mean()) < 5.0 / np.sqrt(n)
    assert abs(z.var() - 1.0) < 5.0 * np.sqrt(2.0 / n)
    assert abs(np.mean(z**4) - 3.0) < 5.0 * np.sqrt(96.0 / n)
    assert abs(np.mean(np.abs(z) > 3.0) - 2.0 * special.ndtr(-3.0)) < 5.0 * np.sqrt(0.0027 / n)


def test_normal_refuses_more_values_than_counters():
    with pytest.raises(ValueError, match="shape"):
        _random.normal(jax.random.key(0), (2**16, 2**16))


def test_keys_of_another_generator_draw_jax_normals_exactly():
    """The stream is written for threefry keys; an ``rbg`` key gets JAX's own normals, drawn as Monte Carlo drew
    them before ``pgtjax._random`` (under ``vmap``, which changes rbg's numbers against per-key calls)."""
    key = jax.random.key(4, impl="rbg")
    np.testing.assert_array_equal(
        np.asarray(_random.normal(key, (6, 2))), np.asarray(jax.random.normal(key, (6, 2), jnp.float64))
    )
    keys = jax.vmap(lambda i: jax.random.fold_in(key, i))(jnp.arange(3))
    block = np.asarray(_random.block_normals(keys, 5, 2))
    expected = np.swapaxes(jax.vmap(lambda k: jax.random.normal(k, (5, 2), jnp.float64))(keys), 0, 1)
    np.testing.assert_array_equal(block, expected)
    assert _random.stream(key) == "jax.random.normal" and _random.stream(jax.random.key(4)) == _random.STREAM


@pytest.mark.slow
def test_monte_carlo_with_an_rbg_key_agrees_with_a_threefry_key_within_sampling_error():
    import pgtjax as pg
    from pgtjax.models import gear_pair as gp

    system = gp.build()

    def run(key):
        return pg.monte_carlo(
            system, n_samples=400, key=key, dt=1e-5, n_steps=200, save_every=50, progress=False
        )

    a, b = run(jax.random.key(1)), run(jax.random.key(1, impl="rbg"))
    std_a, std_b = np.asarray(a.std_u)[-1], np.asarray(b.std_u)[-1]
    assert std_b.dtype == np.float64 and np.all(np.isfinite(std_b))
    assert not np.array_equal(std_a, std_b)  # other draws
    # the standard deviation's sampling error is about std / sqrt(2 n): 3.5 % at n = 400; allow 5 of each run's
    np.testing.assert_allclose(std_b, std_a, rtol=5 * np.sqrt(2) * 0.035)


def test_refuses_key_batches_and_blocks_beyond_the_counters():
    keys = jax.random.split(jax.random.key(0), 3)
    with pytest.raises(ValueError, match="one PRNG key"):
        _random.normal(keys, (4,))
    with pytest.raises(ValueError, match="a block of 65536 x 65536"):
        _random.block_normals(_keys(2), 2**16, 2**16)


def test_without_partitionable_threefry_the_normals_are_jax_normals():
    """With ``jax_threefry_partitionable`` off JAX draws another threefry stream; Monte Carlo then keeps JAX's."""
    key = jax.random.key(9)
    previous = jax.config.jax_threefry_partitionable
    jax.config.update("jax_threefry_partitionable", False)
    try:
        np.testing.assert_array_equal(
            np.asarray(_random.normal(key, (5, 2))), np.asarray(jax.random.normal(key, (5, 2), jnp.float64))
        )
        assert _random.stream(key) == "jax.random.normal"
    finally:
        jax.config.update("jax_threefry_partitionable", previous)
    assert _random.stream(key) == _random.STREAM


def test_materialized_returns_its_input_exactly():
    """The division that keeps the normals' uniforms (and Monte Carlo's step inputs) in a loop of their own
    returns every normal double and signed zero unchanged, under jit as eagerly. Subnormals come back
    unchanged or, where the backend flushes them (XLA's CPU code, whose arithmetic treats them as zero
    anyway), as zeros of their sign."""
    from pgtjax._numerics import materialized

    x = np.array([0.0, -0.0, 2.3e-308, 1.0, -1.0 + 2**-52, 0.3, 1.7976931348623157e308, -3.5e12])
    subnormal = np.array([5e-324, -2.2e-308])
    for f in (materialized, jax.jit(materialized)):
        out = np.asarray(f(jnp.asarray(x)))
        assert out.dtype == np.float64
        np.testing.assert_array_equal(out.view(np.int64), x.view(np.int64))
        flushed = np.asarray(f(jnp.asarray(subnormal)))
        zeros = np.copysign(0.0, subnormal)
        for got, kept, zero in zip(flushed.view(np.int64), subnormal.view(np.int64), zeros.view(np.int64)):
            assert got in (kept, zero)
