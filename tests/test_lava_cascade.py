"""The Lava cascade (lava_procs + toffe_deploy.runtime.loihi) against the numpy reference.

Small sizes (32x24, B=5, 3 stages, a few windows): each network start costs about a second.
Reset "zero" stages build from stock Lava processes (Conv + LIFReset): tested at the end.
"""
import dataclasses
import itertools
import os
import signal
import subprocess
import sys
import textwrap
import time
from types import SimpleNamespace

import numpy as np
import pytest

from toffe_deploy.cascade import run_cascade
from toffe_deploy.errors import ToffeError
from toffe_deploy.fixed_point import quantize_ofs, run_ofs_fixed

lava = pytest.importorskip("lava.magma.core.run_configs")
from toffe_deploy.runtime.cpu import CpuCascade  # noqa: E402
from toffe_deploy.runtime.loihi import HW_MISSING, HW_SUBTRACT, LavaCascade, run_ofs_lava  # noqa: E402
from toffe_deploy.runtime.spikes import SpikeVolume  # noqa: E402

H, W, B = 24, 32, 5


def dotie_params():
    """DOTIE-like kernels; thresholds rising with the stage so each stage picks its own blob."""
    w = np.full((1, 2, 3, 3), 0.15)
    w[..., 1, 1] = 0.2
    return [quantize_ofs(w, th, 0.3) for th in (0.5, 1.2, 2.2)]


def blob_window(rng):
    """Three blobs of decreasing event density (fast, medium, slow object) plus counts > 1."""
    x = np.zeros((B, 2, H, W), np.uint16)
    x[:, :, 2:10, 2:12] = rng.random((B, 2, 8, 10)) < 0.8
    x[:, :, 12:20, 4:14] = rng.random((B, 2, 8, 10)) < 0.4
    x[:, :, 4:20, 18:30] = rng.random((B, 2, 16, 12)) < 0.12
    return x * rng.integers(1, 4, x.shape).astype(np.uint16)


def assert_same(ref, res):
    for field in ("inputs", "spikes", "closed", "frames"):
        a, b = getattr(ref, field), getattr(res, field)
        assert len(a) == len(b)
        for k, (ra, rb) in enumerate(zip(a, b), start=1):
            assert ra.shape == rb.shape, (field, k)
            assert np.array_equal(ra, rb), f"{field} of stage {k} differs in {int((ra != rb).sum())} places"


def gone(pid):
    """True when pid is neither running nor an unreaped child of ours."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except FileNotFoundError:
        return True
    return int(fields[1]) != os.getpid()


def test_cascade_stream_is_bit_exact_to_numpy_reference_and_stops_cleanly(rng):
    params = dotie_params()
    wins = [blob_window(rng) for _ in range(4)]
    # one window as a sparse volume (idx + shape), as the cpu target's SpikeVolume carries it
    wins[2] = SimpleNamespace(idx=np.flatnonzero(wins[2]), shape=wins[2].shape, dense=wins[2])
    with LavaCascade(params, n_bins=B, mask_kernel=5, sensor_size=(W, H)) as lc:
        assert lc.startup_s is not None and lc.child_pids and lc.shm_names
        results = list(lc.cascade_stream(wins))
        # a second stream on the same running network: the pipeline state must not leak in
        again = list(lc.cascade_stream(wins[:1]))
        pids, shm = lc.child_pids, lc.shm_names
    assert len(results) == 4 and len(again) == 1
    for x, res in zip(wins + wins[:1], results + again):
        x = getattr(x, "dense", x)
        ref = run_cascade(x, lambda k, inp: run_ofs_fixed(inp, params[k - 1]), 3, 5)
        assert all(s.any() for s in ref.spikes)         # every stage fires: masking is exercised
        assert_same(ref, res)
    assert all(gone(p) for p in pids)
    assert not [n for n in shm if os.path.exists(os.path.join("/dev/shm", n))]


def test_run_ofs_lava_matches_run_ofs_fixed_and_float_model_agrees(rng):
    params = quantize_ofs(rng.normal(size=(1, 2, 3, 3)) + 0.25, threshold=0.6, leak=0.6)
    wins = [(rng.random((B, 2, H, W)) < 0.2).astype(np.uint8) for _ in range(3)]
    wins[1] = wins[1][:, :, :16, :20]                     # crops of another size go too
    fixed = run_ofs_lava(wins, params)
    refs = [run_ofs_fixed(x, params) for x in wins]
    assert sum(int(r.sum()) for r in refs) > 0
    for got, ref in zip(fixed, refs):
        assert got.shape == ref.shape and np.array_equal(got, ref)
    flt = run_ofs_lava(wins, params, tag="floating_pt")
    agree = np.mean([np.mean(a == b) for a, b in zip(flt, refs)])
    assert agree > 0.98        # float eq. (1)-(2): no decay truncation, may flip borderline neurons


def test_failing_input_stops_runtime_without_orphans_or_shm(rng):
    params = dotie_params()

    def windows():
        yield blob_window(rng)
        yield blob_window(rng)
        raise OSError("disk went away")

    lc = LavaCascade(params, n_bins=B, mask_kernel=5, sensor_size=(W, H), timeout_s=30)
    seen = 0
    with pytest.raises(OSError, match="disk went away"):
        with lc:
            for _ in lc.cascade_stream(windows()):
                seen += 1
    assert seen == 0                  # 3 stages: the first result needed a third period
    assert all(gone(p) for p in lc.child_pids)
    assert not [n for n in lc.shm_names if os.path.exists(os.path.join("/dev/shm", n))]


def test_killed_lava_process_is_reported_and_cleaned_up(rng):
    params = dotie_params()
    x = blob_window(rng)
    lc = LavaCascade(params, n_bins=B, mask_kernel=5, sensor_size=(W, H), timeout_s=20)
    t0 = time.monotonic()
    with pytest.raises(ToffeError, match="Lava process stopped"):
        with lc:
            for i, _ in enumerate(lc.cascade_stream(itertools.repeat(x))):
                if i == 1:
                    os.kill(lc.child_pids[2], signal.SIGKILL)      # e.g. the OOM killer
    assert time.monotonic() - t0 < 20
    assert all(gone(p) for p in lc.child_pids)
    assert not [n for n in lc.shm_names if os.path.exists(os.path.join("/dev/shm", n))]


def test_bad_windows_and_settings_are_one_line_errors(rng):
    params = dotie_params()
    with pytest.raises(ToffeError, match="lava-loihi"):
        with LavaCascade(zero_params(), n_bins=B, mask_kernel=5, sensor_size=(W, H), hardware=True) as lc:
            pass
    assert HW_MISSING.endswith("use --target loihi-sim")
    with pytest.raises(ToffeError, match="tag"):
        LavaCascade(params, n_bins=B, mask_kernel=5, sensor_size=(W, H), tag="int4")
    lc = LavaCascade(params, n_bins=B, mask_kernel=5, sensor_size=(W, H))
    with pytest.raises(ToffeError, match="does not match"):
        with lc:
            list(lc.cascade_stream([np.zeros((B, 2, H + 1, W))]))
    assert all(gone(p) for p in lc.child_pids)


CTRL_C_SCRIPT = textwrap.dedent("""
    import itertools, sys
    import numpy as np
    from toffe_deploy.fixed_point import quantize_ofs
    from toffe_deploy.runtime.loihi import LavaCascade
    p = [quantize_ofs(np.full((1, 2, 3, 3), 0.15), th, 0.3) for th in (0.5, 1.2)]
    x = (np.random.default_rng(0).random((5, 2, 24, 32)) < 0.3).astype(np.uint8)
    with LavaCascade(p, n_bins=5, mask_kernel=5, sensor_size=(32, 24)) as lc:
        print(" ".join(map(str, lc.child_pids)), flush=True)
        print(" ".join(lc.shm_names), flush=True)
        for i, _ in enumerate(lc.cascade_stream(itertools.repeat(x))):
            if i == 3:
                print("streaming", flush=True)
""")


@pytest.mark.parametrize("how", ["ctrl-c", "sigterm"])
def test_ctrl_c_or_kill_stops_runtime_without_orphans_or_shm(tmp_path, how):
    script = tmp_path / "ctrl_c.py"
    script.write_text(CTRL_C_SCRIPT)
    # own process group, signalled as a whole: a terminal's Ctrl-C reaches Lava's children too
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=os.path.dirname(os.path.dirname(__file__)), start_new_session=True)
    try:
        pids = [int(p) for p in proc.stdout.readline().split()]
        shm = proc.stdout.readline().split()
        assert proc.stdout.readline().strip() == "streaming"
        if how == "ctrl-c":
            os.killpg(proc.pid, signal.SIGINT)       # a terminal's Ctrl-C: the whole group
        else:
            os.kill(proc.pid, signal.SIGTERM)        # `timeout` or `kill`: the host only
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    if how == "ctrl-c":
        assert proc.returncode != 0 and "KeyboardInterrupt" in err
    else:
        assert proc.returncode == 128 + signal.SIGTERM, err
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and any(os.path.exists(f"/proc/{p}") for p in pids):
        time.sleep(0.1)
    assert pids and all(not os.path.exists(f"/proc/{p}") for p in pids)
    assert shm and not [n for n in shm if os.path.exists(os.path.join("/dev/shm", n))]


# ---------------------------------------------------------------- reset "zero": stock Lava processes
HOST_PROCESSES = {"EventBinSource", "CascadeBridge"}     # host side of the hybrid (lava_procs)


def zero_params():
    return [dataclasses.replace(p, reset="zero") for p in dotie_params()]


def reference(x, params):
    return run_cascade(x, lambda k, inp: run_ofs_fixed(inp, params[k - 1]), len(params), 5)


def test_stock_network_is_bit_exact_to_reference_and_cpu_target_and_differs_from_subtract(rng):
    params = zero_params()
    wins = [blob_window(rng) for _ in range(4)]
    with LavaCascade(params, n_bins=B, mask_kernel=5, sensor_size=(W, H)) as lc:
        results = list(lc.cascade_stream(wins))
        again = list(lc.cascade_stream(wins[:1]))       # a second stream: no state leaks across
        pids, shm = lc.child_pids, lc.shm_names
    assert len(results) == 4 and len(again) == 1
    cpu = CpuCascade(params, B, 5, (W, H))
    n_diff_subtract = 0
    for x, res in zip(wins + wins[:1], results + again):
        ref = reference(x, params)
        assert all(s.any() for s in ref.spikes)
        assert_same(ref, res)
        sparse = cpu.cascade_sparse(SpikeVolume.from_dense(x > 0))
        for k in range(3):          # the cpu target's compiled loop, reset zero, on the same window
            want = ref.frames[k].reshape(-1)[SpikeVolume.from_dense(x > 0).idx]
            assert np.array_equal(np.asarray(sparse.frames[k]), want)
        sub = reference(x, dotie_params())
        n_diff_subtract += sum(int((a != b).sum()) for a, b in zip(sub.spikes, ref.spikes))
    assert n_diff_subtract > 0              # the two resets really differ on these windows
    assert all(gone(p) for p in pids)
    assert shm and not [n for n in shm if os.path.exists(os.path.join("/dev/shm", n))]


def test_stock_network_runs_only_stock_processes_besides_the_host_bridges():
    with LavaCascade(zero_params(), n_bins=B, mask_kernel=5, sensor_size=(W, H)) as lc:
        kinds = [(type(p).__module__, type(p).__name__) for p in lc.processes]
    chip = [(m, n) for m, n in kinds if n not in HOST_PROCESSES]
    assert sorted(n for _, n in chip) == ["Conv"] * 3 + ["LIFReset"] * 3
    assert all(m.startswith(("lava.proc.conv.", "lava.proc.lif.")) for m, _ in chip)
    host = [m for m, n in kinds if n in HOST_PROCESSES]
    assert len(host) == 4 and all(m.startswith("lava_procs.") for m in host)
    # the subtract network is the other way round: our own neuron process per stage
    with LavaCascade(dotie_params(), n_bins=B, mask_kernel=5, sensor_size=(W, H)) as lc:
        assert sum(type(p).__name__ == "OFSNeuron" for p in lc.processes) == 3


def test_loihi2_refuses_subtract_bundle_before_anything_else():
    with pytest.raises(ToffeError) as e:
        LavaCascade(dotie_params(), n_bins=B, mask_kernel=5, sensor_size=(W, H), hardware=True)
    assert str(e.value) == HW_SUBTRACT and "\n" not in HW_SUBTRACT
    with pytest.raises(ToffeError, match="lava-loihi"):    # zero: gets as far as the hardware check
        LavaCascade(zero_params(), n_bins=B, mask_kernel=5, sensor_size=(W, H), hardware=True)


def test_run_ofs_lava_stock_fixed_is_bit_exact_and_stock_float_agrees(rng):
    params = quantize_ofs(rng.normal(size=(1, 2, 3, 3)) + 0.25, threshold=0.6, leak=0.6, reset="zero")
    wins = [(rng.random((B, 2, H, W)) < 0.2).astype(np.uint8) for _ in range(3)]
    refs = [run_ofs_fixed(x, params) for x in wins]
    assert sum(int(r.sum()) for r in refs) > 0
    assert all(np.array_equal(a, b) for a, b in zip(run_ofs_lava(wins, params), refs))
    flt = run_ofs_lava(wins, params, tag="floating_pt")     # LIFReset's float model, float W, vth
    assert np.mean([np.mean(a == b) for a, b in zip(flt, refs)]) > 0.98
