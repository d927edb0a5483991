"""Where batched work runs: the local devices a batch is sharded over (one mesh axis), for Monte Carlo samples
and design batches alike."""

from __future__ import annotations

import jax
import numpy as np


def local_devices(devices=None) -> list:
    """The devices of this process a batch is sharded over: ``None`` for all of ``jax.local_devices()``;
    ``ValueError`` for an empty list, a repeated device or another process's device."""
    if devices is None:
        return list(jax.local_devices())
    devices = list(devices)
    if not devices or not all(isinstance(d, jax.Device) for d in devices):
        raise ValueError(
            "`devices` must be None or a non-empty sequence of jax devices (e.g. jax.local_devices())"
        )
    if len(set(devices)) != len(devices):
        raise ValueError("`devices` lists a device twice")
    foreign = [d for d in devices if d.process_index != jax.process_index()]
    if foreign:
        raise ValueError(f"`devices` must belong to this process (jax.local_devices()); {foreign} do not")
    return devices


def device_mesh(devices, axis: str) -> jax.sharding.Mesh:
    """A one-axis mesh over ``devices``."""
    return jax.sharding.Mesh(np.array(devices), (axis,))
