"""A Monte Carlo run in a process of its own, for tests/test_scale_out.py: forced host devices, one process of a
two-process ``jax.distributed`` run (a design batch too), or a run that kills itself right after its second checkpoint.

Usage: python3 _mc_worker.py sharded OUT
       python3 _mc_worker.py process PROCESS_ID N_PROCESSES PORT OUT [CHUNK_SIZE [CHECKPOINT_TO_RESUME]]
       python3 _mc_worker.py designs-differ PROCESS_ID PORT count|nan|group
       python3 _mc_worker.py fails-midway PROCESS_ID PORT CHECKPOINT mc|designs
       python3 _mc_worker.py killed CHECKPOINT
       python3 _mc_worker.py killed-designs CHECKPOINT
       python3 _mc_worker.py cores N OUT
"""

import os
import signal
import sys

if __name__ == "__main__" and sys.argv[1:2] == [
    "sharded"
]:  # before JAX starts: four CPU devices in this process
    os.environ["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=4"

import jax  # noqa: E402
import numpy as np  # noqa: E402

jax.config.update("jax_enable_x64", True)

import pgtjax as pg  # noqa: E402
import pgtjax._montecarlo as montecarlo_module  # noqa: E402
import pgtjax.design._problem as design_problem_module  # noqa: E402
from pgtjax import design as pd  # noqa: E402
from pgtjax.models import gear_pair  # noqa: E402

DESIGNS = np.array([[0.0, 0.0], [0.5, -0.3], [-1.0, 1.2], [0.2, 0.9], [1.1, -0.7]])  # chain_problem's z
DESIGN_FIELDS = ("value", "response", "costs", "converged")
FIELDS = (
    "mean_u",
    "std_u",
    "mean_v",
    "std_v",
    "force_mean",
    "force_std",
    "contact_loss_probability",
    "covariance",
)


def run(key=None, **kw):
    """The gear pair with backlash (about 2 % of samples out of contact at the saved times); ``kw`` chooses
    devices, processes, chunks and checkpoints (and may replace the peaks)."""
    system = gear_pair.build()
    kw.setdefault("peaks", {"delta:mesh": np.linspace(2e-5, 8e-5, 17)})
    return pg.monte_carlo(
        system,
        n_samples=203,
        key=jax.random.key(17) if key is None else key,
        dt=1e-5,
        n_steps=200,
        save_every=50,
        histograms={"delta:mesh": np.linspace(1.5e-5, 4.5e-5, 17)},
        histogram_times=[0.002],
        covariance_dofs="all",
        progress=False,
        **kw,
    )


def arrays(result) -> dict:
    out = {f: np.asarray(getattr(result, f)) for f in FIELDS}
    out["histogram"] = np.asarray(result.histograms["delta:mesh"])
    out["peak_histogram"] = np.asarray(result.peak_histograms["delta:mesh"])
    assert out["peak_histogram"].sum() > 0
    out["n_samples"] = np.asarray(result.n_samples)
    return out


def main():
    mode = sys.argv[1]
    if mode == "sharded":
        assert len(jax.local_devices()) == 4
        one = run(chunk_size=64, devices=jax.local_devices()[:1])
        four = run(chunk_size=16)  # 4 devices x 16 samples per round: 4 rounds, the last one partly padding
        from test_design import chain_problem

        problem = chain_problem(0.01)
        designs_one = pd.evaluate(problem, DESIGNS, devices=jax.local_devices()[:1])
        designs_four = pd.evaluate(problem, DESIGNS)  # 2 designs per device, the last 3 rows padding
        np.savez(
            sys.argv[2],
            **{f"one_{k}": v for k, v in arrays(one).items()},
            **{f"four_{k}": v for k, v in arrays(four).items()},
            designs_one=np.asarray(designs_one.value),
            designs_four=np.asarray(designs_four.value),
        )
    elif mode == "cores":  # pgtjax.use_cpu_cores before any computation: N devices (0: one per core)
        n = int(sys.argv[2]) or None
        in_force = pg.use_cpu_cores(n)
        assert len(jax.local_devices()) == in_force and jax.local_devices()[0].platform == "cpu"
        assert in_force == (n or len(os.sched_getaffinity(0)))
        np.savez(sys.argv[3], devices=in_force, **arrays(run(chunk_size=40)))
    elif mode == "process":
        process_id, n_processes, port, out = int(sys.argv[2]), int(sys.argv[3]), sys.argv[4], sys.argv[5]
        jax.distributed.initialize(
            f"127.0.0.1:{port}", num_processes=n_processes, process_id=process_id, initialization_timeout=120
        )
        chunk_size = int(sys.argv[6]) if len(sys.argv) > 6 else 40
        resume = dict(checkpoint=sys.argv[7], resume=True) if len(sys.argv) > 7 else {}
        try:
            result = run(chunk_size=chunk_size, **resume)
        except (
            ValueError,
            pg.ProcessFailedError,
        ) as err:  # refused here or elsewhere: say why, leave cleanly
            print(f"{type(err).__name__}: {err}", file=sys.stderr)
            jax.distributed.shutdown()
            sys.exit(3)
        from test_design import chain_problem

        # the five designs split 3 + 2 over the processes, every design's terms gathered in each
        checkpoint = os.path.join(os.path.dirname(out), "designs.npz")  # each process writes its own file
        designs = pd.evaluate(chain_problem(0.01), DESIGNS, checkpoint=checkpoint)
        np.savez(
            out, **arrays(result), **{f"designs_{f}": np.asarray(getattr(designs, f)) for f in DESIGN_FIELDS}
        )
        jax.distributed.shutdown()
    elif mode == "designs-differ":  # process 1 is given other designs or a bad option: both must refuse
        process_id, port, variant = int(sys.argv[2]), sys.argv[3], sys.argv[4]
        jax.distributed.initialize(f"127.0.0.1:{port}", num_processes=2, process_id=process_id)
        from test_design import chain_problem

        designs, options = DESIGNS.copy(), {}
        if process_id == 1:
            if variant == "count":  # 6 designs against process 0's 5
                designs = np.concatenate([DESIGNS, DESIGNS[:1]])
            elif variant == "nan":
                designs[0, 0] = np.nan
            elif variant == "group":
                options = dict(group_size=0)
        try:
            pd.evaluate(chain_problem(0.01), designs, **options)
        except ValueError as err:
            print(err, file=sys.stderr)
            jax.distributed.shutdown()
            sys.exit(3)
    elif mode == "fails-midway":  # process 1's second checkpoint write fails (a full node-local disk)
        process_id, port, checkpoint, job = int(sys.argv[2]), sys.argv[3], sys.argv[4], sys.argv[5]
        jax.distributed.initialize(f"127.0.0.1:{port}", num_processes=2, process_id=process_id)
        module = montecarlo_module if job == "mc" else design_problem_module
        if process_id == 1:
            save, written = module.save_checkpoint, []

            def save_until_the_disk_is_full(*args, **kwargs):
                written.append(1)
                if len(written) == 2:
                    raise OSError(28, "No space left on device (injected by the test)")
                return save(*args, **kwargs)

            module.save_checkpoint = save_until_the_disk_is_full
        try:
            if job == "mc":
                run(chunk_size=20, checkpoint=checkpoint)
            else:
                from test_design import chain_problem

                pd.evaluate(chain_problem(0.01), DESIGNS, checkpoint=checkpoint)
        except (OSError, pg.ProcessFailedError) as err:
            print(f"{type(err).__name__}: {err}", file=sys.stderr)
            jax.distributed.shutdown()
            sys.exit(4)
        jax.distributed.shutdown()
    elif mode in ("killed", "killed-designs"):
        module = montecarlo_module if mode == "killed" else design_problem_module
        save = module.save_checkpoint
        written = []

        def save_then_die(*args, **kwargs):
            path = save(*args, **kwargs)
            written.append(path)
            if len(written) == 2:  # killed (no cleanup, no exception handling) right after the 2nd checkpoint
                os.kill(os.getpid(), signal.SIGKILL)
            return path

        module.save_checkpoint = save_then_die
        if mode == "killed":
            run(chunk_size=40, checkpoint=sys.argv[2])
        else:
            from test_design import chain_problem

            pd.evaluate(chain_problem(0.01), DESIGNS, checkpoint=sys.argv[2])
    else:
        raise SystemExit(f"unknown mode {mode!r}")


if __name__ == "__main__":
    main()
