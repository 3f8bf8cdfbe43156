"""Checkpoint round trip and every bad-checkpoint case as one InputError line."""
from __future__ import annotations

import json

import numpy as np
import pytest
from safetensors.numpy import load_file, save_file

from toffe_deploy.checkpoint import init_checkpoint, load_checkpoint, save_checkpoint
from toffe_deploy.config import ToffeConfig
from toffe_deploy.errors import InputError

CFG = ToffeConfig(sensor_size=(48, 32))


@pytest.fixture
def ckpt(tmp_path):
    return init_checkpoint(tmp_path / "ck", CFG, seed=3)


def test_round_trip_preserves_everything(tmp_path, ckpt):
    ck = load_checkpoint(ckpt)
    assert ck.config == CFG
    ofs = [dict(weight=p["weight"] * (k + 1), threshold=p["threshold"] + k, leak=0.1 * k) for k, p in enumerate(ck.ofs)]
    state = {k: v + 1.0 for k, v in ck.ofpd_state.items()}
    save_checkpoint(tmp_path / "ck2", CFG, ofs, state)
    ck2 = load_checkpoint(tmp_path / "ck2")
    for a, b in zip(ofs, ck2.ofs):
        np.testing.assert_array_equal(a["weight"], b["weight"])
        assert b["threshold"] == pytest.approx(a["threshold"]) and b["leak"] == pytest.approx(a["leak"], abs=1e-7)
    for k, v in state.items():
        np.testing.assert_array_equal(v, ck2.ofpd_state[k])


def test_untrained_checkpoint_is_dotie(ckpt):
    ck = load_checkpoint(ckpt)
    w = ck.ofs[0]["weight"]
    assert w.shape == (1, 2, 3, 3) and w[0, 0, 1, 1] == pytest.approx(0.2) and w[0, 1, 0, 0] == pytest.approx(0.15)
    assert [p["threshold"] for p in ck.ofs] == [1.0, 1.5, 2.0, 2.5] and ck.ofs[0]["leak"] == pytest.approx(0.3)


def _expect(path, match):
    with pytest.raises(InputError, match=match) as ei:
        load_checkpoint(path)
    assert "\n" not in str(ei.value)


def test_missing_file(ckpt):
    (ckpt / "ofpd.safetensors").unlink()
    _expect(ckpt, r"ofpd.safetensors: missing file")


def test_missing_directory(tmp_path):
    _expect(tmp_path / "nope", "does not exist")


def test_a_directory_without_a_checkpoint_or_a_bundle_says_what_it_is(tmp_path):
    """An empty or unrelated directory is "not a checkpoint directory", a deploy bundle is named as
    one (both said "config.json: missing file" or "ofs.safetensors: missing file")."""
    _expect(tmp_path, r"not a checkpoint directory \(expected config.json, ofs.safetensors, ofpd.safetensors\)")
    (tmp_path / "manifest.json").write_text("{}")
    (tmp_path / "config.json").write_text("{}")
    _expect(tmp_path, r"a deploy bundle \(export's output\), not a checkpoint")


def test_a_json_error_names_its_line_once(tmp_path):
    from toffe_deploy.fileio import read_json

    p = tmp_path / "index.json"
    p.write_text('{"a": "x\ny"}')
    with pytest.raises(InputError, match=r"not valid JSON \(Invalid control character at line 1\)$"):
        read_json(p)


def test_corrupt_safetensors(ckpt):
    (ckpt / "ofs.safetensors").write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{garbage")
    _expect(ckpt, r"ofs.safetensors: not a valid safetensors file")


def test_shape_contradicting_config(ckpt):
    t = load_file(str(ckpt / "ofs.safetensors"))
    t["stage2.weight"] = np.zeros((1, 2, 5, 5), np.float32)
    save_file(t, str(ckpt / "ofs.safetensors"))
    _expect(ckpt, r"stage2.weight has shape \[1, 2, 5, 5\], config.json implies \[1, 2, 3, 3\]")


def test_ofpd_shape_contradicting_config(ckpt):
    cfg = json.loads((ckpt / "config.json").read_text())
    cfg["ofpd"]["hidden"] = 32
    (ckpt / "config.json").write_text(json.dumps(cfg))
    _expect(ckpt, r"ofpd.safetensors: tensor .* has shape")


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_nan_or_inf_weight(ckpt, bad):
    t = load_file(str(ckpt / "ofpd.safetensors"))
    t["fc.weight"][0, 0] = bad
    save_file(t, str(ckpt / "ofpd.safetensors"))
    _expect(ckpt, r"fc.weight holds NaN or infinite values")


def test_bad_config_json(ckpt):
    good = json.loads((ckpt / "config.json").read_text())
    (ckpt / "config.json").write_text('{"sensor_size": [48, 32],')
    _expect(ckpt, r"config.json: not valid JSON")
    (ckpt / "config.json").write_text(json.dumps({**good, "n_bins": 0}))
    _expect(ckpt, r"config.json: n_bins must be >= 1")
    (ckpt / "config.json").write_text(json.dumps({k: v for k, v in good.items() if k not in ("n_bins", "speed_bins")}))
    _expect(ckpt, r"config.json: config lacks n_bins, speed_bins")


def test_deeply_nested_config_json(ckpt):
    """JSON nested deeper than the parser's stack raised RecursionError (fileio.read_json)."""
    (ckpt / "config.json").write_text("[" * 3000 + "]" * 3000)
    _expect(ckpt, r"config.json: not valid JSON \(nested too deeply\)")


def test_cli_reports_bad_checkpoint_in_one_line(ckpt, tmp_path, capsys):
    from toffe_deploy.cli import main

    (ckpt / "ofs.safetensors").unlink()
    rc = main(["eval", str(ckpt), "--data", str(tmp_path)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.count("\n") == 0 and err.startswith("toffe-deploy: error: ") and "ofs.safetensors: missing file" in err


def test_a_save_stopped_between_its_two_renames_puts_the_old_checkpoint_back(ckpt, monkeypatch):
    """fileio.atomic_dir moves the old directory aside, then the new one in: Ctrl-C (or an
    error) between the two renames leaves the old checkpoint where it was, not nothing."""
    import os

    import toffe_deploy.fileio as fileio

    before = {p.name: p.read_bytes() for p in ckpt.iterdir() if p.is_file()}
    ck = load_checkpoint(ckpt)
    real, calls = os.replace, []

    def replace(a, b):
        calls.append((a, b))
        if len(calls) == 2:
            raise KeyboardInterrupt              # after the old one moved aside, before the new one moved in
        return real(a, b)
    monkeypatch.setattr(fileio.os, "replace", replace)
    with pytest.raises(KeyboardInterrupt):
        save_checkpoint(ckpt, CFG, [dict(p, threshold=p["threshold"] + 1) for p in ck.ofs], ck.ofpd_state)
    monkeypatch.setattr(fileio.os, "replace", real)
    assert {p.name: p.read_bytes() for p in ckpt.iterdir() if p.is_file()} == before
    assert sorted(p.name for p in ckpt.parent.iterdir()) == [ckpt.name]     # no temp or old directory left
