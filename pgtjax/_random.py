"""Monte Carlo's standard normals: JAX's threefry stream, with a transform that compiles to one cheap loop.

A sample's normals in block ``j`` are ``normal(fold_in(fold_in(key, sample), j), (save_every, n))``, the stream
of ``jax.random.normal`` with JAX's default (partitionable) threefry: element ``i`` of the flattened block
is built from the 64 random bits ``threefry2x32(block key, (0, i))``, made into a uniform ``u`` in (-1, 1) as
``jax.random.uniform`` does, and ``sqrt(2) erfinv(u)``. The bits and the uniforms are JAX's, bit for bit; the
normals agree with ``jax.random.normal`` to rounding (docs/performance.md, "The normals"). Two things differ,
both for speed on a CPU, where XLA's versions cost most of a gear-pair sample-step:

- threefry is written out round by round (:func:`threefry2x32`). JAX lowers it on a CPU as a loop of five
  iterations over the whole array, which XLA cannot fuse with what follows;
- erfinv is M. Giles's approximation (the one XLA uses, "Approximating the erfinv function", GPU Computing
  Gems Jade Edition, 2011) with ``w = -log((1 - |x|)(1 + |x|))`` through a vectorizable logarithm
  (:func:`_log`) instead of XLA's ``-log1p(-x^2)``. Besides being cheaper, the product is exact where
  ``x^2`` rounds: near |x| = 1 XLA's erfinv is off by up to 1.1e-10 relative, this one by 5e-16.

A batch's block of normals is drawn in one elementwise loop (:func:`block_normals`). Keys of another JAX
generator (``rbg``), and any key while ``jax_threefry_partitionable`` is off (JAX then draws another stream),
draw with ``jax.random.normal``, as Monte Carlo did before this module.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from ._numerics import materialized

#: names this stream in Monte Carlo checkpoints: one drawn with ``jax.random.normal`` (before this module) differs
#: in the last bits, and a run resumed across the change would not equal an uninterrupted one exactly
STREAM = "threefry2x32 bits, erfinv via log((1 - |x|)(1 + |x|))"

_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))
_KEY_PARITY = np.uint32(0x1BD11BDA)


def threefry2x32(k1, k2, x1, x2):
    """Threefry-2x32 with 20 rounds (Salmon et al., "Parallel random numbers: as easy as 1, 2, 3", SC 2011)
    of the counters ``(x1, x2)`` under the key ``(k1, k2)``, all uint32 and broadcastable; JAX's
    ``threefry2x32_p``, unrolled."""
    keys = (k1, k2, k1 ^ k2 ^ _KEY_PARITY)
    x1, x2 = x1 + keys[0], x2 + keys[1]
    for i in range(5):
        for r in _ROTATIONS[i % 2]:
            x1 = x1 + x2
            x2 = ((x2 << np.uint32(r)) | (x2 >> np.uint32(32 - r))) ^ x1
        x1 = x1 + keys[(i + 1) % 3]
        x2 = x2 + keys[(i + 2) % 3] + np.uint32(i + 1)
    return x1, x2


def _uniform(k1, k2, counter):
    """The uniform in [nextafter(-1, 0), 1) of ``jax.random.uniform(key, ..., minval=nextafter(-1, 0))``
    at flat index ``counter`` (uint32 < 2**32) of its array, for the key with words ``(k1, k2)`` (uint32,
    broadcastable against ``counter``)."""
    hi, lo = threefry2x32(k1, k2, jnp.zeros_like(counter), counter)
    bits = (hi.astype(jnp.uint64) << np.uint64(32)) | lo.astype(jnp.uint64)
    one_to_two = lax.bitcast_convert_type(
        (bits >> np.uint64(12)) | np.uint64(0x3FF0000000000000), jnp.float64
    )
    low = np.nextafter(-1.0, 0.0)
    return jnp.maximum(low, (one_to_two - 1.0) * (1.0 - low) + low)


def _log(y):
    """Natural logarithm of positive normal float64 ``y``, within 2 ulp: ``y = 2^e m`` with m in
    [sqrt(1/2), sqrt(2)), ``log m = 2 atanh(s)``, ``s = (m - 1) / (m + 1)``, the series to ``s^19`` (|s| <=
    0.172: the first omitted term is below 3e-17 relative). Elementwise operations only, so XLA vectorizes it;
    its own float64 log costs about three times as much on the CPU (docs/performance.md)."""
    bits = lax.bitcast_convert_type(y, jnp.int64)
    exponent = (bits >> 52) - 1023
    m = lax.bitcast_convert_type((bits & 0x000FFFFFFFFFFFFF) | 0x3FF0000000000000, jnp.float64)
    high = m > np.sqrt(2.0)
    m = jnp.where(high, 0.5 * m, m)
    exponent = jnp.where(high, exponent + 1, exponent).astype(jnp.float64)
    s = (m - 1.0) / (m + 1.0)
    z = s * s
    series = 2.0 / 19.0
    for k in range(8, 0, -1):
        series = series * z + 2.0 / (2 * k + 1)
    return exponent * np.log(2.0) + (2.0 * s + s * (z * series))


# Giles's coefficients, highest power first, as XLA's ErfInv has them: |x| central (w < 6.25), middle
# (w < 16) and tail
_ERFINV_CENTRAL = (
    -3.64441206401782e-21, -1.6850591381820166e-19, 1.28584807152564e-18, 1.1157877678025181e-17,
    -1.3331716628546209e-16, 2.0972767875968562e-17, 6.6376381343583238e-15, -4.0545662729752069e-14,
    -8.1519341976054722e-14, 2.6335093153082323e-12, -1.2975133253453532e-11, -5.4154120542946279e-11,
    1.0512122733215323e-09, -4.1126339803469837e-09, -2.9070369957882005e-08, 4.2347877827932404e-07,
    -1.3654692000834679e-06, -1.3882523362786469e-05, 0.00018673420803405714, -0.000740702534166267,
    -0.0060336708714301491, 0.24015818242558962, 1.6536545626831027,
)  # fmt: skip
_ERFINV_MIDDLE = (
    2.2137376921775787e-09, 9.0756561938885391e-08, -2.7517406297064545e-07, 1.8239629214389228e-08,
    1.5027403968909828e-06, -4.013867526981546e-06, 2.9234449089955446e-06, 1.2475304481671779e-05,
    -4.7318229009055734e-05, 6.8284851459573175e-05, 2.4031110387097894e-05, -0.00035503752036284748,
    0.0009532893797373805, -0.0016882755560235047, 0.0024914420961078508, -0.0037512085075692412,
    0.0053709145535900636, 1.0052589676941592, 3.0838856104922208,
)  # fmt: skip
_ERFINV_TAIL = (
    -2.7109920616438573e-11, -2.5556418169965252e-10, 1.5076572693500548e-09, -3.789465440126737e-09,
    7.61570120807834e-09, -1.496002662714924e-08, 2.9147953450901081e-08, -6.7711997758452339e-08,
    2.2900482228026655e-07, -9.9298272942317e-07, 4.5260625972231537e-06, -1.9681778105531671e-05,
    7.5995277030017761e-05, -0.00021503011930044477, -0.00013871931833623122, 1.0103004648645344,
    4.8499064014085844,
)  # fmt: skip


def erfinv(x):
    """Inverse error function of float64 ``x`` in the open interval (-1, 1) only (at +-1 it is finite, not
    infinite), within about 5e-16 relative (module docstring).
    The three polynomials are evaluated as one Horner scheme whose coefficients each element selects, the
    shorter ones padded with leading zeros."""
    w = -_log((1.0 - jnp.abs(x)) * (1.0 + jnp.abs(x)))
    central, middle = w < 6.25, w < 16.0
    t = jnp.where(central, w - 3.125, jnp.sqrt(w) - jnp.where(middle, 3.25, 5.0))
    n = len(_ERFINV_CENTRAL)
    middle_terms = (0.0,) * (n - len(_ERFINV_MIDDLE)) + _ERFINV_MIDDLE
    tail_terms = (0.0,) * (n - len(_ERFINV_TAIL)) + _ERFINV_TAIL
    p = None
    for a, b, c in zip(_ERFINV_CENTRAL, middle_terms, tail_terms):
        coefficient = jnp.where(central, a, jnp.where(middle, b, c))
        p = coefficient if p is None else p * t + coefficient
    return p * x


def _is_typed(keys) -> bool:
    return jnp.issubdtype(keys.dtype, jax.dtypes.prng_key)


def is_threefry(keys) -> bool:
    """Whether ``keys`` (typed, or raw key data read with JAX's default implementation) are threefry-2x32
    keys and JAX draws their partitionable stream, the only one this module computes (otherwise normals come
    from ``jax.random.normal``)."""
    if not jax.config.jax_threefry_partitionable:
        return False
    if _is_typed(keys):
        return str(jax.random.key_impl(keys)) == "threefry2x32"
    return keys.shape[-1] == 2 and str(jax.config.jax_default_prng_impl) == "threefry2x32"


def _check_count(size: int, what: str) -> int:
    """``size`` if a key's uint32 counters cover it, else ``ValueError`` (JAX would use the counters' high
    word there, which this module does not)."""
    if size >= 2**32:
        raise ValueError(f"{what} holds {size} values; at most 2**32 - 1 are drawn from one key")
    return size


def stream(key) -> str:
    """The name of the normals ``key`` draws (:data:`STREAM` for threefry keys), for checkpoints."""
    return STREAM if is_threefry(key) else "jax.random.normal"


def _typed(keys):
    return keys if _is_typed(keys) else jax.random.wrap_key_data(keys)


def normal(key, shape: tuple[int, ...]) -> jax.Array:
    """Standard normals of ``shape`` (float64) for one ``key``: ``jax.random.normal(key, shape)`` to
    rounding for a threefry key (module docstring), exactly for another."""
    if key.ndim != (0 if _is_typed(key) else 1):
        raise ValueError(f"`key` must be one PRNG key, got an array of keys of shape {key.shape}")
    if not is_threefry(key):
        return jax.random.normal(_typed(key), shape, jnp.float64)
    size = _check_count(int(np.prod(shape, dtype=np.int64)), f"`shape` {shape}")
    counter = lax.iota(jnp.uint32, size).reshape(shape)
    words = jax.random.key_data(key)
    return np.sqrt(2.0) * erfinv(_uniform(words[0], words[1], counter))


def block_normals(keys, rows: int, width: int, first_row=0, block_rows: int | None = None) -> jax.Array:
    """Rows ``first_row`` to ``first_row + rows - 1`` of ``normal(key, (block_rows, width))`` (``block_rows``:
    default ``rows``) for each of a batch of ``keys``, laid out (rows, batch, width) for a scan over the rows.
    ``first_row`` (an integer, or an integer scalar array) must be 0 for keys this module does not draw
    (:func:`is_threefry`). They are drawn as (rows, width, batch), the samples innermost, and transposed:
    drawn per key, or with the counters flattened over (sample, column), XLA:CPU did not vectorize the loop
    for some widths and a normal cost 2-3 times as much (docs/performance.md)."""
    block_rows = rows if block_rows is None else block_rows
    if isinstance(first_row, int) and not 0 <= first_row <= block_rows - rows:
        raise ValueError(
            f"block_normals: rows {first_row} to {first_row + rows - 1} are not in a block of {block_rows}"
        )
    if not is_threefry(keys):
        if rows != block_rows:
            raise ValueError("block_normals: only threefry keys draw part of a block")
        return jnp.swapaxes(jax.vmap(lambda k: normal(k, (rows, width)))(keys), 0, 1)
    _check_count(block_rows * width, f"a block of {block_rows} x {width}")
    words = jax.random.key_data(keys)  # (batch, 2)
    row = jnp.asarray(first_row).astype(jnp.uint32) + lax.iota(jnp.uint32, rows)
    counter = row[:, None, None] * np.uint32(width) + lax.iota(jnp.uint32, width)[None, :, None]
    counter = jnp.broadcast_to(counter, (rows, width, keys.shape[0]))
    uniforms = _uniform(words[None, None, :, 0], words[None, None, :, 1], counter)
    # the uniforms stored by their own loop: fused with the erfinv, threefry ran twice and the loop at about
    # two thirds of the speed of the two (docs/performance.md)
    normals = np.sqrt(2.0) * erfinv(materialized(uniforms))
    if width == 1:  # the same array; XLA copied it for the transpose
        return normals.reshape(rows, keys.shape[0], 1)
    return jnp.transpose(normals, (0, 2, 1))
