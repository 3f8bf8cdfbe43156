"""benchmarks/noise_ablation.py at tiny size: real bundle, generated recording with ground truth."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _load():
    spec = importlib.util.spec_from_file_location("noise_ablation", ROOT / "benchmarks" / "noise_ablation.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_noise_ablation_scores_both_models_per_setting(tmp_path, make_bundle, make_recording, capsys):
    bundle = make_bundle(tmp_path / "b")
    rec = make_recording(tmp_path / "rec.h5")
    mod = _load()
    out = tmp_path / "out"
    rc = mod.main(["--bundle", str(bundle.root), "--events", str(rec), "--windows", "4", "--noise", "0,100",
                   "--hot", "0.05", "--out", str(out)])
    assert rc == 0
    res = json.loads((out / "noise_ablation.json").read_text())
    rows = res["rows"]
    assert [(r["noise_hz"], r["hot_fraction"], r["model"]) for r in rows] == [
        (0.0, 0.0, "toffe"), (0.0, 0.0, "dotie_cluster"), (100.0, 0.0, "toffe"), (100.0, 0.0, "dotie_cluster"),
        (0.0, 0.05, "toffe"), (0.0, 0.05, "dotie_cluster")]
    ev = {(r["noise_hz"], r["hot_fraction"]): r["events_per_window"] for r in rows}
    # 100 Hz on 64x48 px for 500 us adds ~154 events per window; 5 % hot pixels at 1 kHz ~77
    assert ev[(100.0, 0.0)] - ev[(0.0, 0.0)] > 100 and ev[(0.0, 0.05)] - ev[(0.0, 0.0)] > 40
    for r in rows:
        assert r["windows"] == 4 and r["n_gt"] > 0 and 0 <= r["recall"] <= 1 and len(r["recall_by_bin"]) == 4
        assert r["model"] == "toffe" or r["dirE"] is None               # DOTIE reports no direction (strict JSON: null)
    assert "DOTIE + DBSCAN" in (out / "noise_ablation.md").read_text()


def test_noise_ablation_bad_input_is_one_line(tmp_path, capsys):
    rc = _load().main(["--bundle", str(tmp_path / "none"), "--quick", "--out", str(tmp_path / "o")])
    assert rc == 2 and "toffe-deploy export" in capsys.readouterr().err.strip().splitlines()[-1]
    assert not (tmp_path / "o").exists()
