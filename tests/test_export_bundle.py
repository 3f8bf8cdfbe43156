"""Deploy bundle on disk: round trip, sha256 verification, output-dir safety, the file formats
(netx HDF5 loaded by lava-dl, NIR loaded by nir.read, ONNX checked and run by onnxruntime)."""
import json
import shutil

import numpy as np
import pytest

from toffe_deploy.checkpoint import init_checkpoint
from toffe_deploy.config import ToffeConfig
from toffe_deploy.deploy.bundle import (OFS_FILE, check_output_dir, is_bundle_dir, load_bundle, ofs_from_json,
                                        ofs_to_json, write_bundle)
from toffe_deploy.errors import InputError
from toffe_deploy.fixed_point import quantize_ofs

CFG = ToffeConfig(sensor_size=(40, 24), ofpd={"crop_px": 16, "pool": 2})


def params(n=4, seed=0):
    rng = np.random.default_rng(seed)
    return [quantize_ofs(rng.normal(0, 0.2, (1, 2, 3, 3)), 0.5 + 0.25 * k, 0.3) for k in range(n)]


@pytest.fixture
def bundle_dir(tmp_path):
    p = tmp_path / "b"
    write_bundle(p, CFG, params(), b"not really onnx", files={"extra/x.bin": b"123"})
    return p


def test_round_trip_and_manifest(bundle_dir):
    b = load_bundle(bundle_dir)
    for got, want in zip(b.ofs, params()):
        assert np.array_equal(got.weight, want.weight) and got.weight.dtype == np.int32
        assert (got.vth_mant, got.dv, got.du) == (want.vth_mant, want.dv, want.du)
        assert got.weight_scale == want.weight_scale
    assert b.config == CFG and b.ofpd_onnx.read_bytes() == b"not really onnx"
    m = b.manifest
    assert m["format"] == "toffe-deploy-bundle" and m["format_version"] == 1
    assert set(m["files"]) == {"config.json", OFS_FILE, "ofpd.onnx", "README.md", "extra/x.bin"}
    assert m["config_summary"]["n_bins"] == 5 and m["dependencies"]["numpy"]
    assert (bundle_dir / "README.md").read_text().startswith("# toffe-deploy bundle")


@pytest.mark.parametrize("victim", ["ofpd.onnx", OFS_FILE, "config.json", "extra/x.bin"])
def test_any_modified_file_is_refused(bundle_dir, victim):
    f = bundle_dir / victim
    data = bytearray(f.read_bytes())
    data[len(data) // 2] ^= 1
    f.write_bytes(bytes(data))
    with pytest.raises(InputError, match="sha256 mismatch") as ei:
        load_bundle(bundle_dir)
    assert str(ei.value).startswith(str(f)) and "\n" not in str(ei.value)
    if not victim.endswith(".json"):
        load_bundle(bundle_dir, verify=False)   # still readable on request (debugging)


def test_missing_file_and_broken_manifest(bundle_dir, tmp_path):
    (bundle_dir / "extra/x.bin").unlink()
    with pytest.raises(InputError, match="x.bin: missing file"):
        load_bundle(bundle_dir)
    (bundle_dir / "manifest.json").write_text("{ not json")
    with pytest.raises(InputError, match="not valid JSON"):
        load_bundle(bundle_dir)
    with pytest.raises(InputError, match="does not exist"):
        load_bundle(tmp_path / "nowhere")
    (tmp_path / "plain").mkdir()
    with pytest.raises(InputError, match="no manifest.json"):
        load_bundle(tmp_path / "plain")


def test_unlisted_files_are_tolerated(bundle_dir):
    """A run's --out or a user's notes beside the bundle's files do not break loading it."""
    (bundle_dir / "object_flow.jsonl").write_text("{}\n")
    load_bundle(bundle_dir)


@pytest.mark.parametrize("edit,msg", [
    (lambda s: s.update(vth_mant=0), "vth_mant = 0"),
    (lambda s: s.update(dv=4096), "dv = 4096"),
    (lambda s: s.update(weight=[[[[128] * 3] * 3] * 2]), "integers in"),
    (lambda s: s.update(weight=[[[[1] * 5] * 5] * 2]), "kernel 5"),
    (lambda s: s.pop("du"), "malformed"),
])
def test_ofs_json_ranges(edit, msg):
    d = json.loads(json.dumps(ofs_to_json(params())))
    edit(d["stages"][1])
    with pytest.raises(InputError, match=msg) as ei:
        ofs_from_json(d, "o.json", expect_channels=2, expect_kernel=3, expect_stages=4)
    assert "stage 2" in str(ei.value)


def test_output_dir_rules(tmp_path, bundle_dir):
    check_output_dir(tmp_path / "new")                       # missing: fine
    (tmp_path / "empty").mkdir()
    check_output_dir(tmp_path / "empty")                     # empty: fine
    check_output_dir(bundle_dir)                             # a bundle: replaced
    (bundle_dir / "object_flow.jsonl").write_text("{}\n")   # ... but not a bundle with files of others in it
    (bundle_dir / "extra" / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match=r"also holds 2 file\(s\) that are not the bundle's \(extra/notes.txt, "
                                         r"object_flow.jsonl\).*--force"):
        check_output_dir(bundle_dir)
    check_output_dir(bundle_dir, force=True)
    readme_only = tmp_path / "export"
    readme_only.mkdir()
    shutil.copy(bundle_dir / "README.md", readme_only / "README.md")
    check_output_dir(readme_only)                            # the repo's export/ with its README
    other = tmp_path / "other"
    other.mkdir()
    (other / "thesis.tex").write_text("precious")
    with pytest.raises(InputError, match=r"not a toffe-deploy bundle \(holds thesis.tex\).*--force"):
        check_output_dir(other)          # the files named, as for a bundle with others beside it
    for name in ("a.txt", "b.txt", "c.txt"):
        (other / name).write_text("x")
    (other / "notes").mkdir()
    with pytest.raises(InputError, match=r"holds a.txt, b.txt, c.txt and 2 more\)"):
        check_output_dir(other)
    check_output_dir(other, force=True)
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="not a directory"):
        check_output_dir(tmp_path / "file", force=True)


def test_a_deeply_nested_manifest_is_no_bundle_and_one_line_to_load(tmp_path, bundle_dir):
    """JSON nested deeper than the parser's stack raised RecursionError, past is_bundle_dir's
    (OSError, ValueError) and read_json's JSONDecodeError."""
    (bundle_dir / "manifest.json").write_text("[" * 3000 + "]" * 3000)
    assert not is_bundle_dir(bundle_dir)
    with pytest.raises(InputError, match=r"manifest.json: not valid JSON \(nested too deeply\)"):
        load_bundle(bundle_dir)


def test_failed_write_leaves_nothing(tmp_path, bundle_dir):
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(ValueError):
        write_bundle(tmp_path / "c", CFG, params(), b"x", files={"../escape": b"1"})
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    # a failing rewrite of an existing bundle keeps the old one intact
    with pytest.raises(ValueError):
        write_bundle(bundle_dir, CFG, params(seed=1), b"x", files={"../escape": b"1"})
    assert is_bundle_dir(bundle_dir) and load_bundle(bundle_dir).ofpd_onnx.read_bytes() == b"not really onnx"


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """A real bundle (ONNX, variants need windows so only fp32; netx; NIR), no parity checks."""
    from toffe_deploy.deploy.exporter import export_bundle

    root = tmp_path_factory.mktemp("exp")
    init_checkpoint(root / "ck", CFG)
    return export_bundle(root / "ck", root / "bundle", checks=(), progress=False, log=None).bundle


def test_nir_graph_loads_with_nir_read(exported):
    import nir

    g = nir.read(str(exported.root / "ofs.nir"))
    dt = float(g.metadata["time_step_s"])
    assert dt == CFG.dt_us / CFG.n_bins * 1e-6
    for k, p in enumerate(exported.ofs, start=1):
        conv, lif = g.nodes[f"stage{k}_conv"], g.nodes[f"stage{k}_lif"]
        lam = 1 - p.dv / 4096
        assert np.allclose(1 - dt / lif.tau, lam) and np.allclose(lif.r, 1.0)       # tau in seconds, r = 1
        assert np.allclose(conv.weight, p.weight / p.weight_scale / (1 - lam))       # the gain tau / dt
        # half a state unit (1 / (64 s)) above vth: ties fall the way Loihi's integers do
        assert np.allclose(lif.v_threshold, (p.vth_mant + 1 / 128) / p.weight_scale) and np.allclose(lif.v_reset, 0)
        assert ("input", f"stage{k}_conv") in g.edges and (f"stage{k}_lif", f"stage{k}_output") in g.edges
    assert "cannot express" in str(g.metadata["reset"]) and not exported.manifest["nir"]["reproduces_bundle"]


def test_nir_graph_of_a_reset_zero_bundle_reproduces_it_under_nir_semantics(tmp_path, rng):
    """A NIR reader's arithmetic (nir.read, forward Euler with the graph's dt, reset to v_reset)
    against the bundle's own fixed-point stages. The stages are exactly representable (weights
    and thresholds n / 128 with max |w| = 127 / 128, leak 0.5: the gain is 2 and Loihi's decay
    truncates nothing within a window), so float and integers must agree spike for spike: any
    wrong tau, dt, gain, kernel layout or reset timing shows."""
    import dataclasses

    import nir

    from toffe_deploy.checkpoint import load_checkpoint, save_checkpoint
    from toffe_deploy.deploy.exporter import export_bundle
    from toffe_deploy.deploy.nir_graph import simulate_nir_stage
    from toffe_deploy.fixed_point import run_ofs_fixed

    zcfg = dataclasses.replace(CFG, reset="zero")
    ofs = []
    for k in range(4):
        w = rng.integers(-20, 90, (1, 2, 3, 3)).astype(np.float32)
        w[0, 0, 0, 2] = 127                                   # asymmetric: a flipped kernel shows
        ofs.append(dict(weight=w / 128, threshold=(100 + 60 * k) / 128, leak=0.5))
    init_checkpoint(tmp_path / "ck0", zcfg)
    save_checkpoint(tmp_path / "ck", zcfg, ofs, load_checkpoint(tmp_path / "ck0").ofpd_state)
    b = export_bundle(tmp_path / "ck", tmp_path / "b", checks=(), progress=False, log=None).bundle
    g = nir.read(str(b.root / "ofs.nir"))
    assert b.manifest["nir"]["reproduces_bundle"] and g.metadata["reset_mode"] == "zero"
    wins = [(rng.random((CFG.n_bins, 2, CFG.height, CFG.width)) < 0.15).astype(np.uint8) for _ in range(3)]
    n_ref = n_diff = 0
    for k, p in enumerate(b.ofs, start=1):
        assert p.weight_scale == 128 and p.dv == 2048
        for x in wins:
            a, r = simulate_nir_stage(g, k, x), run_ofs_fixed(x, p)
            n_ref, n_diff = n_ref + int(r.sum()), n_diff + int((a != r).sum())
    assert n_ref > 100 and n_diff == 0


def test_netx_loads_with_lava_dl(exported):
    from toffe_deploy.deploy.netx_h5 import load_netx

    p = exported.ofs[1]
    net = load_netx(exported.root / "netx" / "ofs_stage2.net")
    layer = net.layers[0]
    assert net.inp.shape == (CFG.width, CFG.height, 2) and net.out.shape == (CFG.width, CFG.height, 1)
    assert int(layer.neuron.vth.init) == p.vth_mant and int(layer.neuron.dv.init) == p.dv
    assert int(layer.neuron.du.init) == p.du
    # Lava's Conv is a true convolution in (O, W, H, I): netx flips our cross-correlation kernel
    w = layer.synapse.weight.init
    assert np.array_equal(w, p.weight[:, :, ::-1, ::-1].transpose(0, 3, 2, 1))
    assert "zero" in exported.manifest["netx"]["reset_note"]
    assert exported.manifest["ofs"]["loihi2_footprint"]["cores"] == 4 * -(-CFG.width * CFG.height // 8192)


def test_onnx_named_io_dynamic_batch(exported):
    import onnx

    from toffe_deploy.deploy.onnx_export import ort_session, run_onnx
    from toffe_deploy.ofpd_io import input_shape

    onnx.checker.check_model(str(exported.ofpd_onnx), full_check=True)
    info = exported.manifest["ofpd"]
    assert info["opset"] >= 17 and list(info["inputs"]) == ["events"]
    assert list(info["outputs"]) == ["pose", "direction", "speed"] and info["inputs"]["events"]["shape"][0] == "N"
    s = ort_session(exported.ofpd_onnx)
    for n in (1, 3):
        pose, direction, speed = run_onnx(s, np.zeros((n,) + input_shape(CFG), np.float32))
        assert pose.shape == (n, 2) and direction.shape == (n, 2) and speed.shape == (n, 1)


def test_repository_export_readme_is_the_generated_one():
    """export/README.md is what every bundle gets (deploy/readme.py): edit it there, not here."""
    from pathlib import Path

    from toffe_deploy.deploy.readme import bundle_readme

    assert (Path(__file__).resolve().parent.parent / "export" / "README.md").read_text() == bundle_readme()


def test_reset_mode_round_trips_and_older_files_load_as_subtract():
    import dataclasses

    from toffe_deploy.config import ToffeConfig

    zero = [dataclasses.replace(p, reset="zero") for p in params()]
    d = json.loads(json.dumps(ofs_to_json(zero)))
    assert d["reset_mode"] == "zero" and "LIFReset" in d["reset"]
    assert all(p.reset == "zero" for p in ofs_from_json(d, "o.json", expect_reset="zero"))
    with pytest.raises(InputError, match="config.json says reset 'subtract'"):
        ofs_from_json(d, "o.json", expect_reset="subtract")
    old = json.loads(json.dumps(ofs_to_json(params())))
    del old["reset_mode"]                                   # written before the key existed
    assert all(p.reset == "subtract" for p in ofs_from_json(old, "o.json", expect_reset="subtract"))
    cfg = ToffeConfig().to_dict()
    del cfg["reset"]
    assert ToffeConfig.from_dict(cfg).reset == "subtract"
    with pytest.raises(InputError, match="reset must be one of"):
        ToffeConfig.from_dict({**cfg, "reset": "soft"})
    with pytest.raises(ValueError, match="disagree"):
        ofs_to_json([zero[0], params()[1]])
