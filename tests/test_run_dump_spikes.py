"""`run --dump-spikes`: every window's OFS stage inputs and outputs, the same on every target."""
import numpy as np
import pytest

from toffe_deploy.cascade import close_binary
from toffe_deploy.cli import main


@pytest.fixture(scope="module", params=["subtract", "zero"])
def env(request, tmp_path_factory, make_bundle, make_recording):
    root = tmp_path_factory.mktemp("dump")
    return {"root": root, "bundle": make_bundle(root, sensor=(32, 24), reset=request.param),
            "rec": make_recording(root / "rec.h5", sensor=(32, 24), duration=0.006)}


def _dump(env, capsys, target, name, *extra):
    path = env["root"] / name
    rc = main(["run", str(env["bundle"].root), "--events", str(env["rec"]), "--target", target, "--no-progress",
               "--out", str(env["root"] / f"{name}.jsonl"), "--dump-spikes", str(path), *extra])
    capsys.readouterr()
    assert rc == 0
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def test_dump_holds_the_cascade_of_every_window_the_same_on_cpu_and_loihi_sim(env, capsys):
    cpu = _dump(env, capsys, "cpu", "cpu.npz", "--max-windows", "6")
    cfg = env["bundle"].config
    n, k, b = 6, cfg.n_speed_bins, cfg.n_bins
    assert cpu["t0_us"].tolist() == [i * cfg.dt_us for i in range(n)]
    assert cpu["stage_input"].shape == (n, k, b, 2, 24, 32) and cpu["stage_input"].dtype == bool
    assert cpu["stage_output"].shape == (n, k, b, 24, 32) and cpu["stage_output"].dtype == bool
    assert cpu["stage_output"].any() and cpu["stage_input"].any()
    for w in range(n):                       # eq. 3-4: OFS_k-1 sees OFS_k's input minus OFS_k's closed output
        for i in range(k - 1, 0, -1):
            closed = close_binary(cpu["stage_output"][w, i].any(axis=0), cfg.mask_kernel)
            assert np.array_equal(cpu["stage_input"][w, i - 1], cpu["stage_input"][w, i] & ~closed[None, None])
    sim = _dump(env, capsys, "loihi-sim", "sim.npz", "--max-windows", "6")
    for key in cpu:
        assert np.array_equal(cpu[key], sim[key]), key


def test_dump_needs_max_windows_and_refuses_what_does_not_fit(tmp_path, make_bundle, make_recording, capsys):
    bundle, rec, path = make_bundle(tmp_path, sensor=(32, 24)), make_recording(tmp_path / "r.h5", sensor=(32, 24)), tmp_path / "d.npz"
    rc = main(["run", str(bundle.root), "--events", str(rec), "--no-progress", "--dump-spikes", str(path)])
    err = capsys.readouterr().err
    assert rc == 2 and "--max-windows" in err and not path.exists()
    rc = main(["run", str(bundle.root), "--synthetic", "multi,duration=0.05,sensor=1280x720", "--no-progress",
               "--max-windows", "100", "--dump-spikes", str(path)])
    err = capsys.readouterr().err
    assert rc == 2 and "GiB" in err and not path.exists()
