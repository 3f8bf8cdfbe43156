"""The benchmark scripts refuse bad input with one line and a non-zero exit, before any work
(benchmarks/_args.py and each script's main); the shared argparse types accept and refuse what
they should."""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"


def _load(name: str):
    if str(BENCH) not in sys.path:
        sys.path.insert(0, str(BENCH))
    spec = importlib.util.spec_from_file_location(f"bench_{name}", BENCH / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod              # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def args_mod():
    return _load("_args")


def _one_line_error(capsys, rc_or_exc) -> str:
    err = capsys.readouterr().err.strip()
    assert rc_or_exc not in (0, None), err
    assert err and len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


def _main_rc(mod, argv):
    try:
        return mod.main(argv)
    except SystemExit as exc:         # argparse's error exit (2)
        return exc.code


# ----------------------------------------------------------------------------- the shared types
def test_number_types(args_mod):
    a = args_mod
    assert a.positive_int("3") == 3 and a.nonneg_int("0") == 0 and a.positive_float("0.5") == 0.5
    assert a.nonneg_float("0") == 0.0 and a.share("1") == 1.0 and a.int_in(0, 4)("4") == 4
    for fn, bad in ((a.positive_int, "0"), (a.positive_int, "-1"), (a.positive_int, "1.5"), (a.positive_int, "abc"),
                    (a.nonneg_int, "-5"), (a.positive_float, "0"), (a.positive_float, "nan"),
                    (a.positive_float, "inf"), (a.nonneg_float, "-1"), (a.share, "0"), (a.share, "1.5"),
                    (a.int_in(0, 4), "5"), (a.int_in(0, 4), "-1")):
        with pytest.raises(argparse.ArgumentTypeError):
            fn(bad)


def test_comma_list(args_mod):
    three_or_four = args_mod.comma_list(args_mod.nonneg_int, 3, 4)
    assert three_or_four("4,1,5") == [4, 1, 5] and three_or_four("4, 1, 5, 2") == [4, 1, 5, 2]
    for bad in ("4,1", "4,1,5,2,9", "a,b,c", "4,-1,5", ""):
        with pytest.raises(argparse.ArgumentTypeError):
            three_or_four(bad)


def test_path_types(args_mod, tmp_path):
    f = tmp_path / "f.txt"
    f.write_text("x")
    assert args_mod.existing_file(str(f)) == f and args_mod.existing_dir(str(tmp_path)) == tmp_path
    assert args_mod.json_output(str(tmp_path / "new.json")) == tmp_path / "new.json"
    for fn, bad in ((args_mod.existing_file, tmp_path / "none"), (args_mod.existing_file, tmp_path),
                    (args_mod.existing_dir, tmp_path / "none"), (args_mod.existing_dir, f),
                    (args_mod.json_output, tmp_path), (args_mod.json_output, tmp_path / "no" / "x.json")):
        with pytest.raises(argparse.ArgumentTypeError):
            fn(str(bad))


def test_cpu_core(args_mod):
    ok = min(os.sched_getaffinity(0))
    assert args_mod.cpu_core(str(ok)) == ok
    for bad in ("-1", str(max(os.sched_getaffinity(0)) + 1000), "x"):
        with pytest.raises(argparse.ArgumentTypeError):
            args_mod.cpu_core(bad)


def test_guarded_turns_package_errors_into_one_line(args_mod, capsys):
    from toffe_deploy.errors import InputError

    def boom():
        raise InputError("/x/y", "missing file")

    assert args_mod.guarded("prog", boom) == 2
    assert capsys.readouterr().err.strip() == "prog.py: error: /x/y: missing file"   # as argparse names it
    assert args_mod.guarded("prog", lambda: 0) == 0


# ----------------------------------------------------------------------------- the scripts
MISSING = "/nonexistent-dir-for-tests/x"

CASES = [
    ("fit_plane_fit", ["--refits", "-1"]), ("fit_plane_fit", ["--refits", "5"]), ("fit_plane_fit", ["--history", "0"]),
    ("fit_plane_fit", ["--history", "-5"]), ("fit_plane_fit", ["--history", "abc"]),
    ("fit_plane_fit", ["--history-windows", "0"]), ("fit_plane_fit", ["--history-margin", "-1"]),
    ("fit_plane_fit", ["--max-windows", "-1"]), ("fit_plane_fit", ["--limit", "-1"]),
    ("fit_plane_fit", ["--data", MISSING]),
    ("frontend_support", ["--support", "4,1"]), ("frontend_support", ["--support", "a,b,c"]),
    ("frontend_support", ["--support", "4,1,5,2,9"]), ("frontend_support", ["--support", "4,99,5"]),
    ("frontend_support", ["--max-windows", "0"]), ("frontend_support", ["--ckpt", MISSING]),
    ("bench_exact", ["dump", "--max-windows", "0", "-o", "/tmp/x.json"]),
    ("bench_exact", ["dump", "--max-windows", "-1", "-o", "/tmp/x.json"]),
    ("bench_tracking", ["--max-windows", "0"]), ("bench_tracking", ["--max-windows", "-1"]),
    ("bench_tracking", ["--limit", "-1"]), ("bench_tracking", ["--score-gate", "0"]),
    ("bench_tracking", ["--score-gate", "nan"]), ("bench_tracking", ["--cost", "--repeats", "0"]),
    ("bench_tracking", ["--json", "/tmp"]), ("bench_tracking", ["--data", MISSING]),
    ("bench_tracking", ["--ofpd", "merge_frac"]), ("bench_tracking", ["--config", "input_min_cluster=x"]),
    ("bench_tracking", ["--ofpd", "merge_frac=0.3", "--truth-blobs"]),
    ("bench_tracking", ["--ofpd", "merge_frac=0.3", "--detections", "/tmp"]),
    ("detect_diagnose", ["--max-windows", "0"]), ("detect_diagnose", ["--dt", "0"]),
    ("detect_diagnose", ["--dt", "-500"]), ("detect_diagnose", ["--ofpd", "merge_frac=0.3x"]),
    ("detect_diagnose", ["--ofpd", "merge_frac"]), ("detect_diagnose", ["--render", MISSING]),
    ("detect_diagnose", ["--data", MISSING]), ("detect_diagnose", ["--json", "/tmp"]),
    ("bench_parts", ["--repeats", "0"]), ("bench_parts", ["--core", "-1"]), ("bench_parts", ["--core", "100000"]),
    ("bench_features", ["--repeats", "0"]), ("bench_features", ["--features", "faint,nosuch"]),
    ("bench_features", ["--features", ""]), ("bench_features", ["--events", MISSING]),
    ("bench_processes", ["--rounds", "0"]), ("bench_processes", ["--seconds", "0"]),
    ("bench_processes", ["--events", MISSING]), ("bench_processes", ["--out", "/tmp"]),
    ("train_asnet", ["--eval-only", "--eval-windows", "0"]), ("train_asnet", ["--cost-windows", "0"]),
    ("train_asnet", ["--limit", "0"]), ("train_asnet", ["--downsample", "0"]),
    ("bench_run", ["--targets", "foo"]), ("bench_run", ["--repeats", "0"]), ("bench_run", ["--dense-windows", "0"]),
    ("bench_run", ["--lava-windows", "0"]), ("bench_run", ["--long-seconds", "0"]),
    ("bench_run", ["--events", MISSING]), ("bench_run", ["--out", "/tmp"]), ("bench_run", ["--core", "-1"]),
    ("bench_run", ["--core", "100000"]),
    ("bench_synth", ["--duration-s", "0"]), ("bench_synth", ["--duration-s", "nan"]),
    ("bench_synth", ["--duration-s", "inf"]), ("bench_synth", ["--bins", "9"]), ("bench_synth", ["--bins", "0"]),
    ("bench_synth", ["--shape", "blob"]), ("bench_synth", ["--curve", "xx"]), ("bench_synth", ["--json", "/tmp"]),
    ("live_latency", ["--fractions", "0"]), ("live_latency", ["--fractions", "-1"]), ("live_latency", ["--seconds", "0"]),
    ("live_latency", ["--period-ms", "nan"]), ("live_latency", ["--period-ms", "-5"]),
    ("live_latency", ["--events", MISSING]),
    ("fault_sweep", ["--pythonpath", MISSING]), ("fault_sweep", ["--pythonpath", "/tmp"]),
    ("fault_sweep", ["--only", "nosuch"]), ("fault_sweep", ["--match", "no such scenario"]),
    ("nir_check", ["export", "--windows", "0"]), ("nir_check", ["export", "--json", "/tmp"]),
    ("nir_check", ["export", "--data", MISSING]),
    ("energy_latency", ["--warmup", "-1"]), ("energy_latency", ["--energy-s", "nan"]),
    ("energy_latency", ["--min-events", "-5"]),
    ("noise_ablation", ["--hot-rate", "nan"]), ("noise_ablation", ["--noise", "nan"]),
]


@pytest.mark.parametrize("script, argv", CASES, ids=[f"{s}:{' '.join(a)}" for s, a in CASES])
def test_bad_option_is_one_line_exit_2(script, argv, capsys):
    rc = _main_rc(_load(script), argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2, err
    assert err and "Traceback" not in "\n".join(err) and "error" in err[-1]
    if script != "energy_latency":           # plain argparse there: usage block, then the one error line
        assert len(err) == 1, err


def test_bench_lava_bad_options(capsys):
    pytest.importorskip("lava")
    mod = _load("bench_lava")
    for argv in (["--windows", "0"], ["--windows", "-1"], ["--distinct", "0"], ["--bins", "0"], ["--width", "0"],
                 ["--height", "-5"], ["--stages", "0"], ["--out", "/tmp"], ["--check-every", "-1"]):
        assert _main_rc(mod, argv) == 2
        _one_line_error(capsys, 2)


def test_missing_bundle_is_one_line(tmp_path, capsys):
    for script, argv in (("bench_parts", ["--bundle", str(tmp_path)]), ("bench_run", ["--bundle", str(tmp_path)]),
                         ("bench_features", ["--bundle", str(tmp_path)]),
                         ("bench_processes", ["--bundle", str(tmp_path)]),
                         ("bench_tracking", ["--bundle", str(tmp_path)]),
                         ("live_latency", ["--bundle", str(tmp_path)]), ("nir_check", [str(tmp_path)])):
        rc = _main_rc(_load(script), argv)
        assert rc == 2 and "not a deploy bundle" in _one_line_error(capsys, rc)


def test_bench_exact_compare_bad_files_exit_2(tmp_path, capsys):
    mod = _load("bench_exact")
    good = tmp_path / "good.json"
    good.write_text(json.dumps({"recording": "r", "windows": [{"t0_us": 0, "objects": []}]}))
    (tmp_path / "bad.json").write_text("{not json")
    (tmp_path / "foreign.json").write_text(json.dumps({"a": 1}))
    for other in ("missing.json", "bad.json", "foreign.json"):
        rc = mod.main(["compare", str(good), str(tmp_path / other)])
        assert rc == mod.EXIT_BAD_INPUT == 2 and other in _one_line_error(capsys, rc)
    assert mod.main(["compare", str(good), str(good)]) == mod.EXIT_SAME
    assert mod.EXIT_DIFFERS == 1


def test_detect_diagnose_render_refuses_a_foreign_json(tmp_path, capsys):
    f = tmp_path / "x.json"
    f.write_text(json.dumps({"split": "a"}))
    rc = _load("detect_diagnose").main(["--render", str(f)])
    assert rc == 2 and "not a detect_diagnose.py --json file" in _one_line_error(capsys, rc)


def test_detect_diagnose_unknown_override_keys_list_the_valid_ones():
    from toffe_deploy.config import ToffeConfig
    from toffe_deploy.errors import ToffeError

    mod = _load("detect_diagnose")
    cfg = ToffeConfig()
    with pytest.raises(ToffeError, match="unknown key.*nosuch.*merge_frac"):
        mod.apply_overrides(cfg, [("nosuch", 1)], [])
    with pytest.raises(ToffeError, match="unknown key.*nosuch.*input_min_cluster"):
        mod.apply_overrides(cfg, [], [("nosuch", 1)])
    with pytest.raises(ToffeError, match="input_min_cluster"):
        mod.apply_overrides(cfg, [], [("input_min_cluster", 0)])
    assert mod.apply_overrides(cfg, [("merge_frac", 0.3)], [("input_min_cluster", 2)]).input_min_cluster == 2


def test_bench_tracking_detections_header_and_refusals(tmp_path, capsys):
    from toffe_deploy.errors import InputError

    mod = _load("bench_tracking")
    files = [tmp_path / "a.h5"]
    path = tmp_path / "multi.jsonl"
    mod.save_detections(path, "multi", files, [], max_windows=3)
    assert json.loads(path.read_text().splitlines()[0])["max_windows"] == 3
    assert mod.load_detections(path, files, 3) == {0: []}
    with pytest.raises(InputError, match="--max-windows 3, fewer than the 5 asked"):
        mod.load_detections(path, files, 5)
    with pytest.raises(InputError, match="other sequences"):
        mod.load_detections(path, [tmp_path / "b.h5"], 3)
    old = tmp_path / "old.jsonl"                  # saved before the header had max_windows: replayed, with a warning
    old.write_text(json.dumps({"split": "multi", "files": [str(f) for f in files], "fields": mod.DET_FIELDS}) + "\n")
    assert mod.load_detections(old, files, 50) == {0: []}
    assert "warning" in capsys.readouterr().err
    (tmp_path / "junk.jsonl").write_text("junk\n")
    with pytest.raises(InputError, match="not a --save-detections file"):
        mod.load_detections(tmp_path / "junk.jsonl", files, 3)


def test_bench_tracking_missing_detections_and_file_as_save_dir(tmp_path, make_bundle, capsys):
    bundle = make_bundle(tmp_path / "b")
    data = tmp_path / "data"
    (data / "multi").mkdir(parents=True)
    (data / "multi" / "m.h5").write_bytes(b"")              # split_files lists it; nothing reads it here
    mod = _load("bench_tracking")
    base = ["--bundle", str(bundle.root), "--data", str(data), "--split", "multi"]
    rc = mod.main(base + ["--detections", str(tmp_path)])
    assert rc == 2 and "multi.jsonl: missing file" in _one_line_error(capsys, rc)
    (tmp_path / "afile").write_text("x")
    rc = mod.main(base + ["--save-detections", str(tmp_path / "afile")])
    assert rc == 2 and "not a directory" in _one_line_error(capsys, rc)
    rc = mod.main(base[:-1] + ["nosuch"])
    assert rc == 2 and "no sequences in split 'nosuch'" in _one_line_error(capsys, rc)
    rc = mod.main(base + ["--ofpd", "nosuch=1"])
    assert rc == 2 and "--ofpd: unknown key(s) nosuch (valid: " in _one_line_error(capsys, rc)
    rc = mod.main(base + ["--ofpd", "merge_frac=\"x\""])
    assert rc == 2 and "merge_frac" in _one_line_error(capsys, rc)
    assert capsys.readouterr().out == ""                    # nothing printed before the refusals


def test_peak_memory_exit_codes(capsys):
    mod = _load("peak_memory")
    assert mod.main(["/nonexistent-command-for-tests"]) == 2
    assert "cannot run it" in _one_line_error(capsys, 2)
    assert mod.main([sys.executable, "-c", "import os, signal; os.kill(os.getpid(), signal.SIGKILL)"]) == 128 + 9
    assert "MiB" in capsys.readouterr().err
    assert mod.main([sys.executable, "-c", "raise SystemExit(3)"]) == 3


def test_noise_ablation_refuses_a_recording_it_cannot_score(tmp_path, make_bundle, capsys):
    import numpy as np

    from toffe_deploy.events import make_events
    from toffe_deploy.events.io import write_events_h5

    bundle = make_bundle(tmp_path / "b")
    rec = tmp_path / "short.h5"
    ev = make_events(np.array([1]), np.array([1]), np.array([10]), np.array([1]))
    write_events_h5(rec, ev, (64, 48), t_range=(0, 100))
    rc = _load("noise_ablation").main(["--bundle", str(bundle.root), "--events", str(rec), "--out", str(tmp_path / "o")])
    assert rc == 2 and "short.h5" in _one_line_error(capsys, rc)
    assert not (tmp_path / "o").exists()


def test_fit_plane_fit_refuses_an_unknown_check_split(tmp_path, capsys):
    (tmp_path / "ckpt").mkdir()
    (tmp_path / "ckpt" / "config.json").write_text("{}")
    data = tmp_path / "data"
    (data / "train").mkdir(parents=True)
    (data / "train" / "s.h5").write_bytes(b"")
    rc = _load("fit_plane_fit").main(["--ckpt", str(tmp_path / "ckpt"), "--data", str(data), "--check", "nosuch"])
    assert rc == 2 and "no sequences in split 'nosuch'" in _one_line_error(capsys, rc)


def test_bench_tracking_recall_by_events_per_edge():
    """The misses of objects the sensor hardly sees (about 1 event per passing edge) are told
    from the rest: the recall over objects at or above each threshold, from the attrs the
    generator writes (a dict, or its JSON text), nothing for a recording without them."""
    mod = _load("bench_tracking")
    app = {"objects": [{"events_per_edge": 0.9}, {"events_per_edge": 2.4}]}
    assert mod.events_per_edge({"appearance": app}) == {0: 0.9, 1: 2.4}
    assert mod.events_per_edge({"appearance": json.dumps(app)}) == {0: 0.9, 1: 2.4}
    assert mod.events_per_edge({}) == {} and mod.events_per_edge({"appearance": "not json"}) == {}
    rows = [{"events_per_edge": 0.9, "windows": 100, "detected": 10},
            {"events_per_edge": 1.3, "windows": 100, "detected": 90},
            {"events_per_edge": 2.4, "windows": 200, "detected": 200}]
    r = mod.recall_by_events_per_edge(rows)
    assert r[">=1.0"] == {"objects": 2, "windows": 300, "recall": 290 / 300}
    assert r[">=1.5"]["recall"] == 1.0 and r[">=2.0"]["objects"] == 1
    assert mod.recall_by_events_per_edge(rows + [{"events_per_edge": None, "windows": 5, "detected": 0}]) == {}
    assert mod._object_count({"objects": json.dumps([{}, {}])}) == 2 and mod._object_count({}) == 0


def test_a_quick_noise_ablation_writes_beside_the_full_table_not_over_it():
    """`noise_ablation.py --quick` replaced benchmarks/results/noise_ablation.{md,json} (the full
    table the README quotes) with its 6 windows; it writes to results/quick/ as energy_latency does."""
    mod = _load("noise_ablation")
    assert Path(mod.parse_args(["--quick"]).out) == ROOT / "benchmarks" / "results" / "quick"
    assert Path(mod.parse_args([]).out) == ROOT / "benchmarks" / "results"


def test_a_reduced_asnet_run_does_not_replace_the_shipped_figures(tmp_path):
    """`train_asnet.py --eval-only --limit 1` rewrote the shipped, tracked eval_test.json (64
    sequences -> 1, recall NaN); a reduced run writes only into another --out."""
    mod = _load("train_asnet")
    assert mod.writes_results(mod.parse_args(["--eval-only"]))
    for extra in (["--limit", "1"], ["--eval-windows", "1"], ["--cost-only", "--cost-windows", "2"]):
        assert not mod.writes_results(mod.parse_args(["--eval-only", *extra]))
        assert mod.writes_results(mod.parse_args(["--eval-only", *extra, "--out", str(tmp_path)]))
