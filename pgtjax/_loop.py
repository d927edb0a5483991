"""The time loop every solver shares: ``n_blocks`` saved blocks of ``save_every`` steps, each a ``lax.scan``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp


def saved_scan(
    step: Callable[[Any, jax.Array, Any], tuple[Any, Any]],
    record: Callable[[Any, Any, jax.Array], Any],
    carry,
    first,
    *,
    n_blocks: int,
    save_every: int,
    block_inputs: Callable[[jax.Array], Any] | None = None,
    remat_policy=None,
    blocks_per_checkpoint: int = 1,
):
    """Advance ``carry`` by ``n_blocks * save_every`` steps, recording after every block.

    ``step(carry, step_number, x) -> (carry, info)`` takes the step that ends at ``t0 + step_number * dt``
    (``step_number`` = 1, 2, ...); ``x`` is the step's slice of ``block_inputs(block_index)`` (leading axis
    ``save_every``; e.g. the block's random draws) or None. ``record(carry, infos, block_index)`` is what is
    saved at the block's end, with ``infos`` the block's step infos stacked. ``first`` (the record at ``t0``)
    is prepended, so every saved leaf has a leading axis of ``n_blocks + 1``. With ``remat_policy`` each block
    is rematerialized in reverse mode under that ``jax.checkpoint`` policy; with ``blocks_per_checkpoint`` k > 1
    too, so is each group of k blocks, so that reverse mode keeps the carry once per group (and the k carries of
    the group it transposes) rather than once per block. Returns ``(carry, saved)``.
    """

    def block(carry, block_index):
        inputs = None if block_inputs is None else block_inputs(block_index)

        def inner(c, xs):
            j, x = xs
            return step(c, block_index * save_every + j + 1, x)

        carry, infos = jax.lax.scan(inner, carry, (jnp.arange(save_every), inputs))
        return carry, record(carry, infos, block_index)

    if blocks_per_checkpoint > 1 and remat_policy is None:
        raise ValueError(
            "saved_scan: `blocks_per_checkpoint` > 1 groups rematerialized blocks: it needs a remat_policy"
        )
    if remat_policy is not None:
        block = jax.checkpoint(block, policy=remat_policy)
    group = blocks_per_checkpoint
    n_groups = n_blocks // group
    if group == 1 or n_groups == 0:
        carry, saved = jax.lax.scan(block, carry, jnp.arange(n_blocks))
    else:
        # the state kept once per group of blocks: reverse mode recomputes a group's blocks (keeping their
        # start states) before it transposes them block by block
        def grouped(carry, group_index):
            return jax.lax.scan(block, carry, group_index * group + jnp.arange(group))

        grouped = jax.checkpoint(grouped, policy=remat_policy)
        carry, saved = jax.lax.scan(grouped, carry, jnp.arange(n_groups))
        saved = jax.tree.map(lambda a: a.reshape((n_groups * group,) + a.shape[2:]), saved)
        if n_blocks > n_groups * group:  # the blocks left over, each kept as without groups
            carry, rest = jax.lax.scan(block, carry, jnp.arange(n_groups * group, n_blocks))
            saved = jax.tree.map(lambda a, b: jnp.concatenate([a, b], axis=0), saved, rest)
    saved = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b], axis=0), first, saved)
    return carry, saved
