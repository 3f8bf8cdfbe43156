"""`toffe-deploy export` end to end at small size, and every bad input: one line, exit 2,
nothing written (no output directory, no temporary directory left beside it)."""
try:   # Lava sets the multiprocessing start method at import: do it before any tqdm lock exists
    import lava.magma.core.process.process  # noqa: F401
except ImportError:
    pass

import json

import numpy as np
import pytest

from toffe_deploy.checkpoint import dotie_ofs, init_checkpoint, random_ofpd_state, save_checkpoint
from toffe_deploy.cli import main
from toffe_deploy.config import ToffeConfig
from toffe_deploy.deploy.bundle import load_bundle

CFG = ToffeConfig(sensor_size=(48, 32), ofpd={"crop_px": 16, "pool": 2})


@pytest.fixture
def ckpt(tmp_path):
    return init_checkpoint(tmp_path / "ck", CFG)


def run_cli(*argv):
    return main(["export", *map(str, argv), "--quiet"])


def test_full_export_with_all_checks_and_variants(tmp_path, ckpt, capsys):
    out = tmp_path / "bundle"
    rc = run_cli(ckpt, "-o", out, "--variants", "fp16,int8", "--windows", "4", "--lava-windows", "1")
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert "wrote bundle" in cap.out and "parity on 4 held-out windows" in cap.out
    for name in ("fixed_vs_float", "lava_vs_fixed", "onnx_vs_torch", "end_to_end"):
        assert name in cap.out
    b = load_bundle(out)
    assert set(b.ofpd_variants) == {"fp16", "int8"}
    assert {"parity.json", "ofs.nir", "netx/ofs_stage4.net", "ofpd_int8.onnx"} <= set(b.manifest["files"])
    par = json.loads((out / "parity.json").read_text())
    assert par["windows"]["kind"] == "generated" and par["windows"]["seed"] == 0
    assert par["checks"]["lava_vs_fixed"]["status"] in ("pass", "fail") or \
        par["checks"]["lava_vs_fixed"]["status"].startswith("skipped")
    variants = par["checks"]["onnx_vs_torch"]["variants"]
    assert set(variants) == {"fp16", "int8"} and all(v["non_finite_outputs"] == 0 for v in variants.values())
    assert "max_abs_diff_vs_torch" in b.manifest["ofpd"]["variants"]["int8"]
    assert b.manifest["parity"]["onnx_vs_torch"]["status"] == par["checks"]["onnx_vs_torch"]["status"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bundle", "ck"]     # no staging dirs left


def test_reexport_replaces_a_bundle_but_not_other_dirs(tmp_path, ckpt, capsys):
    out = tmp_path / "out"
    assert run_cli(ckpt, "-o", out, "--checks", "none") == 0
    assert run_cli(ckpt, "-o", out, "--checks", "none") == 0        # a bundle: replaced
    (out / "object_flow.jsonl").write_text("{}\n")                  # a run's --out in it (make demo's, once)
    capsys.readouterr()
    assert run_cli(ckpt, "-o", out, "--checks", "none") == 2        # ... is not deleted with the bundle
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "object_flow.jsonl" in err and "--force" in err, err
    assert (out / "object_flow.jsonl").read_text() == "{}\n"
    load_bundle(out)
    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("keep me")
    capsys.readouterr()
    assert run_cli(ckpt, "-o", other, "--checks", "none") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--force" in err and (other / "notes.txt").read_text() == "keep me"
    assert run_cli(ckpt, "-o", other, "--checks", "none", "--force") == 0
    assert not (other / "notes.txt").exists()
    load_bundle(other)
    (tmp_path / "d").mkdir()
    capsys.readouterr()
    assert run_cli(ckpt, "-o", tmp_path / "b2", "--checks", "none", "--data", tmp_path / "d") == 0
    assert "warning: --data " in capsys.readouterr().err                # not read without checks or variants


def _break_missing(ck):
    (ck / "ofs.safetensors").unlink()
    return "ofs.safetensors: missing file"


def _break_corrupt(ck):
    (ck / "ofpd.safetensors").write_bytes(b"\x00garbage" * 10)
    return "ofpd.safetensors: not a valid safetensors file"


def _break_config(ck):
    (ck / "config.json").write_text('{"n_bins": 5,')
    return "config.json: not valid JSON"


def _break_shape(ck):
    from safetensors.numpy import load_file, save_file

    t = load_file(str(ck / "ofs.safetensors"))
    t["stage2.weight"] = np.zeros((1, 2, 5, 5), np.float32)
    save_file(t, str(ck / "ofs.safetensors"))
    return "stage2.weight has shape [1, 2, 5, 5]"


def _save_stages(ck, edit):
    ofs = dotie_ofs(CFG)
    edit(ofs)
    save_checkpoint(ck, CFG, ofs, random_ofpd_state(CFG))


def _break_nan(ck):
    _save_stages(ck, lambda ofs: ofs[2]["weight"].__setitem__((0, 1, 1, 1), np.nan))
    return "stage3.weight holds NaN"


def _break_inf_threshold(ck):
    _save_stages(ck, lambda ofs: ofs[0].__setitem__("threshold", np.inf))
    return "stage1.threshold holds NaN or infinite"


def _break_tiny_threshold(ck):
    _save_stages(ck, lambda ofs: ofs[3].__setitem__("threshold", 1e-7))
    return "stage4.threshold 1e-07 is too small"


def _break_leak(ck):
    _save_stages(ck, lambda ofs: ofs[1].__setitem__("leak", 1.5))
    return "stage2.leak must be in [0, 1]"


@pytest.mark.parametrize("breaker", [_break_missing, _break_corrupt, _break_config, _break_shape, _break_nan,
                                     _break_inf_threshold, _break_tiny_threshold, _break_leak])
def test_bad_checkpoint_is_one_line_exit_2_and_writes_nothing(tmp_path, ckpt, capsys, breaker):
    expected = breaker(ckpt)
    before = sorted(p.name for p in tmp_path.iterdir())
    rc = run_cli(ckpt, "-o", tmp_path / "out")
    err = capsys.readouterr().err
    assert rc == 2
    assert err.startswith("toffe-deploy: error: ") and err.count("\n") == 1, err
    assert expected in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_missing_checkpoint_dir_and_bad_options(tmp_path, capsys):
    assert run_cli(tmp_path / "nope", "-o", tmp_path / "out") == 2
    assert "checkpoint directory does not exist" in capsys.readouterr().err
    init_checkpoint(tmp_path / "ck", CFG)
    assert run_cli(tmp_path / "ck", "-o", tmp_path / "out", "--variants", "fp8") == 2
    assert "unknown ONNX variant 'fp8'" in capsys.readouterr().err
    assert run_cli(tmp_path / "ck", "-o", tmp_path / "out", "--checks", "vibes") == 2
    assert "unknown parity check" in capsys.readouterr().err
    assert run_cli(tmp_path / "ck", "-o", tmp_path / "out", "--data", tmp_path / "nodata") == 2
    assert "data directory does not exist" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_negative_seed_and_empty_out_are_refused_before_any_work(tmp_path, ckpt, capsys):
    """--seed -1 ended in numpy's SeedSequence traceback; -o "" was named as an empty path."""
    with pytest.raises(SystemExit) as exc:
        run_cli(ckpt, "-o", tmp_path / "out", "--checks", "end_to_end", "--windows", "2", "--seed", "-1")
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1 and "argument --seed: must be >= 0, got -1" in err
    assert run_cli(ckpt, "-o", "", "--checks", "none") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "-o is empty: name the bundle directory to write" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ck"]
