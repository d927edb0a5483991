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
    block_inputs: Callable[[jax.Array, jax.Array, int], Any] | None = None,
    rows_per_input: int | None = None,
    remat_policy=None,
    blocks_per_checkpoint: int = 1,
    record_updates_carry: bool = False,
):
    """Advance ``carry`` by ``n_blocks * save_every`` steps, recording after every block.

    ``step(carry, step_number, x) -> (carry, info)`` takes the step that ends at ``t0 + step_number * dt``
    (``step_number`` = 1, 2, ...); ``x`` is the step's slice of ``block_inputs(block_index, first_row, rows)``
    (the inputs of the block's steps ``first_row`` to ``first_row + rows - 1``, leading axis ``rows``; e.g. their
    random draws) or None. They are formed ``rows_per_input`` steps at a time (default ``save_every``: the whole
    block), the rest of the block last. ``record(carry, infos, block_index)`` is what is
    saved at the block's end, with ``infos`` the block's step infos stacked. ``first`` (the record at ``t0``)
    is prepended, so every saved leaf has a leading axis of ``n_blocks + 1``. With ``remat_policy`` each block
    is rematerialized in reverse mode under that ``jax.checkpoint`` policy; with ``blocks_per_checkpoint`` k > 1
    too, so is each group of k blocks, so that reverse mode keeps the carry once per group (and the k carries of
    the group it transposes) rather than once per block. With ``record_updates_carry``, ``record`` returns
    ``(carry, saved)``: what it keeps across blocks (a running maximum over the saved times, say) goes on in the
    carry. Returns ``(carry, saved)``.
    """

    rows = save_every if rows_per_input is None else rows_per_input
    if not 1 <= rows <= save_every:
        raise ValueError(
            f"saved_scan: `rows_per_input` must be in [1, save_every = {save_every}], got {rows}"
        )
    n_parts, rest_rows = divmod(save_every, rows)

    def block(carry, block_index):
        def steps(carry, first_row, n_rows: int):
            inputs = None if block_inputs is None else block_inputs(block_index, first_row, n_rows)

            def inner(c, xs):
                j, x = xs
                return step(c, block_index * save_every + first_row + j + 1, x)

            return jax.lax.scan(inner, carry, (jnp.arange(n_rows), inputs))

        if n_parts == 1 and not rest_rows:
            carry, infos = steps(carry, 0, save_every)
        else:  # the block's inputs formed a part at a time
            carry, infos = jax.lax.scan(lambda c, p: steps(c, p * rows, rows), carry, jnp.arange(n_parts))
            infos = jax.tree.map(lambda a: a.reshape((n_parts * rows,) + a.shape[2:]), infos)
            if rest_rows:
                carry, rest = steps(carry, n_parts * rows, rest_rows)
                infos = jax.tree.map(lambda a, b: jnp.concatenate([a, b], axis=0), infos, rest)
        if record_updates_carry:
            return record(carry, infos, block_index)
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
