"""Monte Carlo beyond one device and one process, and across interruptions: the statistics of a run sharded over
four (forced) CPU devices, split over two ``jax.distributed`` processes, or killed after its second checkpoint and
resumed, against the same run on one device in one go. Each case runs in fresh processes (tests/_mc_worker.py):
the device count is fixed when JAX starts, and a killed process must really die."""

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest
from _mc_worker import DESIGN_FIELDS, DESIGNS, FIELDS, arrays, run
from test_design import chain_problem

from pgtjax import design as pd
from pgtjax._parallel import lapack_batches_wait_on_pool

WORKER = str(Path(__file__).with_name("_mc_worker.py"))
TIMEOUT_S = 600


def _env():
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    # on a GPU the test process already holds 75 % of its memory: the workers must allocate as they go
    env.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).parent), env.get("PYTHONPATH", "")])
    return env


def _worker(*args):
    return subprocess.Popen(
        [sys.executable, WORKER, *map(str, args)], env=_env(), stderr=subprocess.PIPE, text=True
    )


def _finish(proc, timeout=TIMEOUT_S):
    try:
        _, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
        pytest.fail(f"worker still running after {timeout} s (waiting for another process?): {err[-3000:]}")
    return proc.returncode, err


def _assert_same(got: dict, ref: dict, rtol: float):
    for name in FIELDS:
        a, b = np.asarray(got[name]), np.asarray(ref[name])
        assert a.shape == b.shape and a.dtype == np.float64, name
        scale = np.max(np.abs(b))
        assert np.max(np.abs(a - b)) <= rtol * scale, (name, np.max(np.abs(a - b)) / scale)
    np.testing.assert_array_equal(got["histogram"], ref["histogram"])
    np.testing.assert_array_equal(got["peak_histogram"], ref["peak_histogram"])
    assert int(got["n_samples"]) == int(ref["n_samples"]) == 203


@pytest.fixture(scope="module")
def reference():
    """The run on this process's one CPU device, all 203 samples in one batch."""
    assert len(jax.local_devices()) == 1
    return arrays(run(chunk_size=203))


@pytest.mark.slow
def test_sharded_over_four_devices_equals_one_device(tmp_path, reference):
    out = tmp_path / "sharded.npz"
    code, err = _finish(_worker("sharded", out))
    assert code == 0, err
    data = np.load(out)
    one = {k[4:]: data[k] for k in data.files if k.startswith("one_")}
    four = {k[5:]: data[k] for k in data.files if k.startswith("four_")}
    _assert_same(four, one, 1e-12)
    _assert_same(four, reference, 1e-12)
    assert np.any(four["std_u"] > 0)
    # design batches: 5 designs over 4 devices (2 per device) against one device
    np.testing.assert_allclose(data["designs_four"], data["designs_one"], rtol=1e-12)
    assert data["designs_four"].shape == (5,)


@pytest.mark.slow
def test_use_cpu_cores_shards_over_one_device_per_core_with_the_same_statistics(tmp_path, reference):
    """``pg.use_cpu_cores()`` (what ``pgtjax --cpu-devices`` calls) makes one CPU device per available core; the
    run is split over them and its statistics equal the one-device run's."""
    out = tmp_path / "cores.npz"
    code, err = _finish(_worker("cores", 0, out))
    assert code == 0, err
    data = dict(np.load(out))
    assert int(data["devices"]) == len(os.sched_getaffinity(0))
    _assert_same(data, reference, 1e-12)
    # several devices on a jaxlib whose batched LAPACK calls wait on XLA's pool: the user is warned
    affected = lapack_batches_wait_on_pool() and int(data["devices"]) > 1  # devices: one per core
    assert ("RuntimeWarning" in err and "can hang" in err) == affected, err


@pytest.mark.parametrize(
    "version, affected",
    [
        ("0.9.2", False),
        ("0.10.0", True),
        ("0.10.2", True),
        ("0.11.0", True),
        ("0.11.1", False),
        ("0.12.0.1", False),
    ],
)
def test_jaxlib_versions_whose_lapack_batches_wait_on_the_thread_pool(version, affected):
    """jax commit bfd9e1fbd3 (in 0.10.0) split batched LAPACK calls over XLA's intra-op pool; 859992407d
    (after the 0.11.0 tag) turned it off in open-source builds (docs/performance.md)."""
    assert lapack_batches_wait_on_pool(version) is affected


def test_use_cpu_cores_after_jax_started_keeps_the_devices_or_says_why():
    import pgtjax as pg

    assert len(jax.devices("cpu")) == 1  # JAX started here first (this test alone, too): one device
    assert pg.use_cpu_cores() == 1  # started: left as it is
    assert pg.use_cpu_cores(1) == 1
    with pytest.raises(ValueError, match="before any JAX computation"):
        pg.use_cpu_cores(2)
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ValueError, match="`n`"):
            pg.use_cpu_cores(bad)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_two_processes_equal_one_process(tmp_path, reference):
    port = _free_port()
    procs = [_worker("process", p, 2, port, tmp_path / f"p{p}.npz") for p in range(2)]
    results = [_finish(p) for p in procs]
    for code, err in results:
        assert code == 0, err
    designs = pd.evaluate(chain_problem(0.01), DESIGNS)  # one process evaluates all five
    for p in range(2):  # every process holds the merged statistics of all 203 samples
        got = dict(np.load(tmp_path / f"p{p}.npz"))
        _assert_same(got, reference, 1e-12)
        for f in DESIGN_FIELDS:  # and the terms of every design, 3 evaluated by process 0, 2 by process 1
            want = np.asarray(getattr(designs, f))
            assert got[f"designs_{f}"].shape == want.shape and got[f"designs_{f}"].dtype == want.dtype, f
            np.testing.assert_allclose(got[f"designs_{f}"], want, rtol=1e-12, err_msg=f)
    shares = sorted(p.name for p in tmp_path.glob("designs*"))  # each process checkpointed its own share
    assert shares == ["designs.process-0-of-2.npz", "designs.process-1-of-2.npz"], shares
    for p, rows in ((0, [0, 1, 2]), (1, [3, 4, 4])):  # equal shares: the last design repeated to fill
        with np.load(tmp_path / shares[p]) as saved:
            np.testing.assert_allclose(saved["value"], np.asarray(designs.value)[rows], rtol=1e-12)


@pytest.mark.slow
def test_processes_that_would_split_the_samples_differently_are_refused(tmp_path):
    """Each process derives every process's sample ids from its own batch size: unequal ones would skip some
    samples and repeat others, so the run stops in every process before computing anything."""
    port = _free_port()
    procs = [
        _worker("process", p, 2, port, tmp_path / f"p{p}.npz", chunk) for p, chunk in enumerate((40, 30))
    ]
    for code, err in [_finish(p) for p in procs]:
        assert code == 3, err
        assert "must have the same number of devices and `chunk_size`" in err
        assert "process 0: 1 device(s), 40 samples per device; process 1: 1 device(s), 30 samples" in err
    assert not list(tmp_path.iterdir())


@pytest.mark.slow
def test_processes_given_different_designs_or_a_bad_option_all_refuse():
    """A design batch is split by position: processes holding different designs would mix two batches. And
    an option that one process alone refuses must stop the other too, not leave it waiting in a collective."""
    expected = {
        "count": ["same `designs` (process 0: 5 designs; process 1: 6 designs"] * 2,
        "nan": ["process(es) 1 refused this run's options", "`designs` must be finite"],
        "group": ["process(es) 1 refused this run's options", "`group_size`"],
    }
    for variant, messages in expected.items():
        port = _free_port()
        procs = [_worker("designs-differ", p, port, variant) for p in range(2)]
        for (code, err), message in zip([_finish(p) for p in procs], messages):
            assert code == 3 and message in err, (variant, code, err)


@pytest.mark.slow
def test_one_process_refusing_its_options_stops_every_process(tmp_path):
    """A resume where one node lacks its checkpoint file: that process refuses, and the other stops too
    instead of waiting for it at the end of the run."""
    from pgtjax._checkpoint import save_checkpoint

    checkpoint = tmp_path / "mc.npz"
    ours = dict(n_samples=203, samples_per_device=40, devices=1, processes=2, process=0, key=[0, 17])
    save_checkpoint(tmp_path / "mc.process-0-of-2.npz", {"count": 0.0}, ours, what="monte_carlo")
    port = _free_port()
    procs = [_worker("process", p, 2, port, tmp_path / f"p{p}.npz", 40, checkpoint) for p in range(2)]
    (code0, err0), (code1, err1) = [_finish(p) for p in procs]
    assert code1 == 3 and "no checkpoint at" in err1 and "mc.process-1-of-2.npz" in err1, err1
    assert code0 == 3 and "process(es) 1 refused this run's options" in err0, err0


@pytest.mark.slow
def test_a_process_failing_mid_run_stops_every_process_and_the_run_resumes(tmp_path, reference):
    """Process 1's second checkpoint write fails (a full disk, injected by the worker) after every check has
    passed: both processes stop with a message instead of process 0 waiting for it in the final exchange
    (before, process 0 hung until the coordination service aborted process 1). Process 0 has saved its whole
    share; resuming both finishes process 1's and gives the statistics of the uninterrupted run. A resume where
    one node holds another run's file (refused only when loaded, after the start-up exchange) stops both."""
    from pgtjax._checkpoint import save_checkpoint

    for job, what in (("mc", "monte_carlo"), ("designs", "evaluate")):
        port = _free_port()
        procs = [_worker("fails-midway", p, port, tmp_path / f"{job}.npz", job) for p in range(2)]
        (code0, err0), (code1, err1) = [_finish(p, timeout=300) for p in procs]
        assert code1 == 4 and "OSError: [Errno 28] No space left on device" in err1, err1
        assert code0 == 4 and f"ProcessFailedError: {what}: process(es) 1 failed during the run" in err0, err0
    # 203 samples, 20 per round and process: 6 rounds; process 1 failed writing after its second round
    for p, rounds in ((0, 6), (1, 1)):
        with np.load(tmp_path / f"mc.process-{p}-of-2.npz") as saved:
            assert int(saved["next_round"]) == rounds, p
    (tmp_path / "resumed").mkdir()
    # process 1's node holds a file that the start-up check accepts (same sizes and key) but whose description
    # lacks the rest of this run's: process 1 refuses it when loading it, and process 0 stops too
    good = (tmp_path / "mc.process-1-of-2.npz").read_bytes()
    stale = dict(n_samples=203, samples_per_device=20, devices=1, processes=2, process=1, key=[0, 17])
    save_checkpoint(tmp_path / "mc.process-1-of-2.npz", {"count": 0.0}, stale, what="monte_carlo")
    port = _free_port()
    procs = [
        _worker("process", p, 2, port, tmp_path / "resumed" / f"p{p}.npz", 20, tmp_path / "mc.npz")
        for p in range(2)
    ]
    (code0, err0), (code1, err1) = [_finish(p, timeout=300) for p in procs]
    assert code1 == 3 and "ValueError: cannot resume monte_carlo from" in err1, err1
    assert code0 == 3 and "monte_carlo: process(es) 1 failed before the run" in err0, err0
    (tmp_path / "mc.process-1-of-2.npz").write_bytes(good)
    port = _free_port()
    procs = [
        _worker("process", p, 2, port, tmp_path / "resumed" / f"p{p}.npz", 20, tmp_path / "mc.npz")
        for p in range(2)
    ]
    for code, err in [_finish(p) for p in procs]:
        assert code == 0, err
    for p in range(2):
        _assert_same(dict(np.load(tmp_path / "resumed" / f"p{p}.npz")), reference, 1e-12)


@pytest.mark.slow
def test_killed_after_second_checkpoint_resumes_to_the_uninterrupted_run(tmp_path):
    checkpoint = tmp_path / "mc.npz"
    code, err = _finish(_worker("killed", checkpoint))
    assert code == -9, err  # SIGKILL right after the second checkpoint was written
    with np.load(checkpoint) as saved:
        assert int(saved["next_round"]) == 2 and float(saved["count"]) == 80.0  # 2 rounds of 40 of 203
    resumed = arrays(run(chunk_size=40, checkpoint=checkpoint, resume=True))
    uninterrupted = arrays(run(chunk_size=40))
    _assert_same(resumed, uninterrupted, 0.0)  # the same merges in the same order: equal, not just close
    with np.load(checkpoint) as final:
        assert int(final["next_round"]) == 6 and float(final["count"]) == 203.0
    again = arrays(run(chunk_size=40, checkpoint=checkpoint, resume=True))  # complete: nothing left to run
    _assert_same(again, uninterrupted, 0.0)


@pytest.mark.slow
def test_design_batch_killed_after_second_checkpoint_resumes(tmp_path):
    checkpoint = tmp_path / "designs.npz"
    code, err = _finish(_worker("killed-designs", checkpoint))
    assert code == -9, err
    with np.load(checkpoint) as saved:
        assert int(saved["next_group"]) == 2 and saved["value"].shape == (2,)  # one design per group
    problem = chain_problem(0.01)
    resumed = pd.evaluate(problem, DESIGNS, checkpoint=checkpoint, resume=True)
    straight = pd.evaluate(problem, DESIGNS)
    for field in ("value", "response", "costs", "converged"):
        np.testing.assert_array_equal(getattr(resumed, field), getattr(straight, field))
    assert resumed.value.shape == (5,) and resumed.value.dtype == np.float64
    with pytest.raises(ValueError, match="designs: checkpoint"):  # other designs: refused
        pd.evaluate(problem, DESIGNS[:4], checkpoint=checkpoint, resume=True)
    with pytest.raises(ValueError, match="batch_size: checkpoint None, this run 1"):  # vmap-ed: other digits
        pd.evaluate(problem, DESIGNS, checkpoint=checkpoint, resume=True, batch_size=1)


@pytest.mark.slow
def test_resume_refuses_another_run_and_bad_paths(tmp_path):
    checkpoint = tmp_path / "mc.npz"
    run(chunk_size=100, checkpoint=checkpoint)
    with pytest.raises(ValueError, match="samples_per_device.*--chunk-size"):  # and how to match it
        run(chunk_size=50, checkpoint=checkpoint, resume=True)
    with pytest.raises(ValueError, match=r"\(key: checkpoint \[0, 17\], this run \[0, 18\]\)") as err:
        run(chunk_size=100, checkpoint=checkpoint, resume=True, key=jax.random.key(18))  # named, nothing else
    assert "--chunk-size" not in str(err.value)  # the hint only where sizes differ
    with pytest.raises(ValueError, match="no checkpoint"):
        run(checkpoint=tmp_path / "missing.npz", resume=True)
    with pytest.raises(ValueError, match="needs a `checkpoint`"):
        run(resume=True)
    with pytest.raises(ValueError, match="ending in .npz"):
        run(checkpoint=tmp_path / "mc.ckpt")
    with pytest.raises(ValueError, match="does not exist"):
        run(checkpoint=tmp_path / "nowhere" / "mc.npz")
    (tmp_path / "foreign.npz").write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match="not a readable"):
        run(checkpoint=tmp_path / "foreign.npz", resume=True)
    from pgtjax._checkpoint import save_checkpoint

    save_checkpoint(
        tmp_path / "old.npz",
        {"count": np.asarray(3.0)},
        {"seed": "0123", "n_samples": 203},
        what="monte_carlo",
    )
    with pytest.raises(
        ValueError, match="another version of pgtjax .it records seed that this version does not"
    ):
        run(checkpoint=tmp_path / "old.npz", resume=True)
    save_checkpoint(tmp_path / "design.npz", {"count": np.asarray(3.0)}, {"n_samples": 203}, what="evaluate")
    with pytest.raises(ValueError, match="it is a checkpoint of evaluate, not of monte_carlo"):
        run(checkpoint=tmp_path / "design.npz", resume=True)
    with pytest.raises(ValueError, match=r"`checkpoint` must be a path \(str or pathlib.Path\).*got int"):
        run(checkpoint=5)
    # one written before Monte Carlo drew its normals with pgtjax._random (they differ in the last bits)
    with np.load(checkpoint) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays.pop("__checkpoint__")))
    del meta["normals"], meta["format"], meta["run"]
    save_checkpoint(tmp_path / "before_normals.npz", arrays, meta, what="monte_carlo")
    with pytest.raises(
        ValueError,
        match="another version of pgtjax .it records nothing that this version does not, and lacks normals",
    ):
        run(chunk_size=100, checkpoint=tmp_path / "before_normals.npz", resume=True, key=jax.random.key(17))
    # one of an eigen-coordinate run written before the steps' inputs were formed per saved block
    with np.load(checkpoint) as data:
        meta = json.loads(str(data["__checkpoint__"]))
    assert meta["propagation"] == "eigen" and meta["step_inputs"] == "per block"
    del meta["step_inputs"], meta["format"], meta["run"]
    save_checkpoint(tmp_path / "before_block_inputs.npz", arrays, meta, what="monte_carlo")
    with pytest.raises(
        ValueError, match="it records nothing that this version does not, and lacks step_inputs"
    ):
        run(chunk_size=100, checkpoint=tmp_path / "before_block_inputs.npz", resume=True)
    # peaks from another start: named as the entry that differs
    with pytest.raises(ValueError, match=r"peak_start_step: checkpoint 0, this run 100"):
        run(chunk_size=100, checkpoint=checkpoint, resume=True, peak_start=1e-3)
    # other peaks: named as the entry that differs
    with pytest.raises(ValueError, match=r"peaks: checkpoint \['delta:mesh'\], this run \[\]"):
        run(chunk_size=100, checkpoint=checkpoint, resume=True, peaks={})
    # one written before `peaks` existed (no such entry) resumes a run without peaks, to the same statistics
    plain = run(chunk_size=100, peaks={}, checkpoint=tmp_path / "plain.npz")
    with np.load(tmp_path / "plain.npz") as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays.pop("__checkpoint__")))
    assert meta["peaks"] == [] and meta["peak_updates"] == "every step"
    del meta["peaks"], meta["peak_updates"], meta["format"], meta["run"]
    save_checkpoint(tmp_path / "before_peaks.npz", arrays, meta, what="monte_carlo")
    resumed = run(chunk_size=100, peaks={}, checkpoint=tmp_path / "before_peaks.npz", resume=True)
    np.testing.assert_array_equal(np.asarray(resumed.std_u), np.asarray(plain.std_u))
    assert resumed.peak_histograms == {} and float(np.max(np.asarray(plain.std_u))) > 0
    # one with a deflection's peak, written while only contact forces' peaks followed every step (and the
    # others' the saves; no `peak_updates` entry), is refused rather than resumed with other peaks
    with np.load(checkpoint) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays.pop("__checkpoint__")))
    del meta["peak_updates"], meta["format"], meta["run"]
    save_checkpoint(tmp_path / "saved_peaks.npz", arrays, meta, what="monte_carlo")
    with pytest.raises(ValueError, match="peak_updates: checkpoint 'saves', this run 'every step'"):
        run(chunk_size=100, checkpoint=tmp_path / "saved_peaks.npz", resume=True)
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(ValueError, match="not a pgtjax checkpoint"):
        run(checkpoint=tmp_path / "other.npz", resume=True)
    with pytest.raises(ValueError, match="devices"):
        run(devices=[])


@pytest.mark.slow
def test_cli_resume_after_an_interruption_gives_the_same_outputs(tmp_path, monkeypatch, capsys):
    import json

    import pgtjax._montecarlo as montecarlo_module
    from pgtjax.cli import main

    argv = ["run", "--samples", "60", "--chunk-size", "10", "--periods", "0.01", "--saves", "5"]
    argv += ["--no-sweeps", "--no-sensitivities", "--quiet"]
    assert main([*argv, "--out", str(tmp_path / "straight")]) == 0
    save, calls = montecarlo_module.save_checkpoint, []

    def interrupted_after_two(*args, **kwargs):
        save(*args, **kwargs)
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(montecarlo_module, "save_checkpoint", interrupted_after_two)
    out = tmp_path / "resumed"
    with pytest.raises(KeyboardInterrupt):
        main([*argv, "--out", str(out)])
    assert not (out / "summary.json").exists()
    monkeypatch.setattr(montecarlo_module, "save_checkpoint", save)
    capsys.readouterr()
    assert main([*argv, "--out", str(out), "--resume"]) == 0
    # two batches of 10 were checkpointed before the interrupt: the console says where it resumes
    assert "(resuming: the checkpoint holds 20 of 60 samples)" in capsys.readouterr().out
    straight = json.loads((tmp_path / "straight" / "summary.json").read_text())
    resumed = json.loads((out / "summary.json").read_text())
    assert resumed == straight and resumed["settings"]["n_samples"] == 60
    capsys.readouterr()
    assert main(["run", "--samples", "0", "--resume", "--out", str(tmp_path / "x")]) == 2
    assert "--resume" in capsys.readouterr().err
    assert main(["run", "--coordinator", "127.0.0.1:1", "--out", str(tmp_path / "x")]) == 2
    assert "--processes" in capsys.readouterr().err
    assert main(["run", *"--coordinator 127.0.0.1:1 --processes 2 --process-id 2".split()]) == 2
    assert "--process-id" in capsys.readouterr().err


def test_cli_reports_another_process_failing_in_one_line(tmp_path, monkeypatch, capsys):
    import pgtjax as pg
    from pgtjax.cli import main
    from pgtjax.studies import planetary as study

    def another_process_failed(*args, **kwargs):
        raise pg.ProcessFailedError(
            "monte_carlo: process(es) 1 failed during the run (their messages say why)"
        )

    monkeypatch.setattr(study, "run_study", another_process_failed)
    out = tmp_path / "run"
    assert (
        main(["run", "--samples", "10", "--no-sweeps", "--no-sensitivities", "--quiet", "--out", str(out)])
        == 1
    )
    err = capsys.readouterr().err
    assert err.splitlines() == [
        "pgtjax: error: monte_carlo: process(es) 1 failed during the run (their messages say why)"
    ]
    assert not out.exists()  # the output folder it created was empty, and removed


def test_cli_cpu_devices_option(capsys):
    """``pgtjax --cpu-devices N`` is applied before any JAX computation; in a process where JAX has started
    (as here) a different count is refused with one line, and the count in force is accepted."""
    from pgtjax.cli import main

    assert len(jax.devices("cpu")) == 1  # JAX started here first (this test alone, too)
    assert main(["--cpu-devices", "2", "gear-pair-modal"]) == 2
    assert "cannot make JAX's CPU platform 2 devices" in capsys.readouterr().err
    assert main(["--cpu-devices", "1", "gear-pair-modal", "--json"]) == 0


@pytest.mark.slow
def test_cli_cpu_devices_warns_in_one_line_on_an_affected_jaxlib():
    """In a fresh process ``pgtjax --cpu-devices 2`` starts two devices; on a jaxlib whose batched LAPACK calls
    wait on XLA's pool the user gets one warning line (not a Python traceback-style warning)."""
    proc = subprocess.run(
        [sys.executable, "-m", "pgtjax.cli", "--cpu-devices", "2", "gear-pair-modal", "--json"],
        env=_env(),
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if "can hang" in line]
    if lapack_batches_wait_on_pool() and len(os.sched_getaffinity(0)) > 1:  # one core: one pool thread
        assert len(lines) == 1 and lines[0].startswith("pgtjax: warning: jaxlib "), proc.stderr
    else:
        assert not lines, proc.stderr


@pytest.mark.slow
@pytest.mark.parametrize("affected", [False, True])
def test_cli_uses_every_core_by_default_unless_the_jaxlib_can_hang(affected):
    """Without ``--cpu-devices`` the CLI starts one CPU device per available core on a jaxlib whose batched
    LAPACK calls cannot hang (0.11.1 and later: simulated here by replacing the version test), and JAX's one
    device on an affected jaxlib (0.10.0-0.11.0). Each case in a fresh process: the count is fixed at start."""
    code = (
        "import sys, jax, pgtjax._parallel as par, pgtjax.cli as cli\n"
        f"par.lapack_batches_wait_on_pool = cli.lapack_batches_wait_on_pool = lambda version=None: {affected}\n"
        "rc = cli.main(['gear-pair-modal', '--json'])\n"
        "print('CPU DEVICES', len(jax.devices('cpu')), file=sys.stderr)\n"
        "sys.exit(rc)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], env=_env(), capture_output=True, text=True, timeout=TIMEOUT_S
    )
    assert proc.returncode == 0, proc.stderr
    expected = 1 if affected else len(os.sched_getaffinity(0))
    assert f"CPU DEVICES {expected}" in proc.stderr, proc.stderr
    assert "can hang" not in proc.stderr, proc.stderr


def test_default_chunk_size_is_larger_on_an_accelerator_and_gives_the_same_statistics(reference):
    """With no ``chunk_size``, a CPU batch is 5,000 samples (all 203 here: one batch, as the reference) and a
    GPU batch 100,000 (measured: a GPU runs small batches several times slower per sample)."""
    from types import SimpleNamespace

    from pgtjax._parallel import default_chunk_size

    cpu = jax.devices("cpu")
    assert default_chunk_size(cpu) == 5000 and default_chunk_size(cpu, cpu=10_000) == 10_000
    assert default_chunk_size([SimpleNamespace(platform="gpu")]) == 100_000
    assert default_chunk_size([*cpu, SimpleNamespace(platform="gpu")]) == 100_000
    _assert_same(arrays(run(chunk_size=None)), reference, rtol=0.0)


def test_interrupt_message_says_whether_there_is_anything_to_resume(tmp_path):
    """Ctrl-C in a resumable command: the message names the checkpoint this run wrote (or resumed from), and
    says that there is nothing to resume when it had not written one yet, even if an older run's is there."""
    import time

    from pgtjax._files import interrupted_message
    from pgtjax.cli import _resume_files, build_parser

    out = tmp_path / "out"
    out.mkdir()
    args = build_parser().parse_args(["run", "--out", str(out)])
    started = time.time()
    assert _resume_files(args, started) == []
    assert "nothing to resume" in interrupted_message(True, [])
    checkpoint = out / "monte_carlo.checkpoint.npz"
    checkpoint.write_bytes(b"")
    shares = [out / f"monte_carlo.checkpoint.process-{p}-of-2.npz" for p in (0, 1)]
    for path in shares:
        path.write_bytes(b"")
    assert _resume_files(args, started) == [checkpoint, *shares]
    message = interrupted_message(True, [checkpoint])
    assert repr(str(checkpoint)) in message and "--resume continues" in message
    for path in (checkpoint, *shares):  # written by an earlier run
        os.utime(path, (started - 60.0, started - 60.0))
    assert _resume_files(args, started) == []
    resuming = build_parser().parse_args(["run", "--out", str(out), "--resume"])
    assert _resume_files(resuming, started) == [checkpoint, *shares]
    optimize = build_parser().parse_args(["optimize", "--out", str(out)])
    (out / "history.json").write_text("{}")
    assert _resume_files(optimize, started) == [out / "history.json"]
    assert (
        interrupted_message(False, []) == "interrupted: no output files written (earlier outputs unchanged)"
    )


def test_output_manifest_lists_every_process_checkpoint_this_run_wrote(tmp_path):
    """Process 0 writes the outputs of a distributed run: its manifest lists each process's checkpoint file in
    the folder, and not one an earlier run left there."""
    import time

    from pgtjax.cli._scale import checkpoints_of_run as _checkpoints_written

    base = tmp_path / "monte_carlo.checkpoint.npz"
    old = tmp_path / "monte_carlo.checkpoint.process-0-of-3.npz"
    old.write_bytes(b"earlier run")
    os.utime(old, (time.time() - 3600, time.time() - 3600))
    started = time.time()
    ours = [tmp_path / f"monte_carlo.checkpoint.process-{p}-of-2.npz" for p in range(2)]
    for path in ours:
        path.write_bytes(b"this run")
    assert _checkpoints_written(base, since=started, resumed=False, processes=2) == ours
    assert _checkpoints_written(base, since=started, resumed=False, processes=3) == []  # all older or missing
    assert _checkpoints_written(base, since=started, resumed=True, processes=3) == [old]  # resumed: older too
    assert _checkpoints_written(base, since=started, resumed=False, processes=1) == []  # its own file only
    base.write_bytes(b"this run")
    assert _checkpoints_written(base, since=started, resumed=False, processes=1) == [base]
    # any process count (the interrupt message, before JAX says how many): this run's files of every kind
    assert _checkpoints_written(base, since=started, resumed=False) == [base, *ours]
    assert _checkpoints_written(None, since=started, resumed=False) == []
