"""The Lava cascade (lava_procs + toffe_deploy.runtime.loihi) against the numpy reference.

Small sizes (32x24, B=5, 3 stages, a few windows): each network start costs about a second.
"""
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
from toffe_deploy.runtime.loihi import HW_MISSING, LavaCascade, run_ofs_lava  # noqa: E402

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
        with LavaCascade(params, n_bins=B, mask_kernel=5, sensor_size=(W, H), hardware=True) as lc:
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
