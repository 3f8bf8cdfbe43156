"""benchmarks/bench_exact.py at tiny size: a dump of the cpu target's full output compares equal
to itself run again, and a changed object or cascade digest is found."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _load():
    spec = importlib.util.spec_from_file_location("bench_exact", ROOT / "benchmarks" / "bench_exact.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_dump_twice_is_identical_and_a_change_is_found(tmp_path, make_bundle, make_recording, capsys):
    bundle = make_bundle(tmp_path / "b", ofs_pool=2)
    rec = make_recording(tmp_path / "rec.h5")
    mod = _load()
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    for out in (a, b):
        assert mod.main(["dump", "--bundle", str(bundle.root), "--events", str(rec), "-o", str(out)]) == 0
    assert mod.main(["compare", str(a), str(b)]) == 0
    assert "identical" in capsys.readouterr().out
    dump = json.loads(a.read_text())
    assert len(dump["windows"]) >= 20 and all(len(w["cascade"]) == 16 for w in dump["windows"])
    objs = [(i, o) for i, w in enumerate(dump["windows"]) for o in w["objects"]]
    assert objs and isinstance(objs[0][1]["x"], str)             # floats kept at full precision
    i, o = objs[-1]
    o["x"] = repr(float(o["x"]) + 1e-12)                          # the last bit of one position
    a.write_text(json.dumps(dump))
    assert mod.main(["compare", str(a), str(b)]) == 1
    assert f"window {i} " in capsys.readouterr().out
    dump["windows"][i]["objects"] = json.loads(b.read_text())["windows"][i]["objects"]
    dump["windows"][0]["cascade"] = "0" * 16
    a.write_text(json.dumps(dump))
    assert mod.main(["compare", str(a), str(b)]) == 1
    assert mod.main(["dump", "--bundle", str(tmp_path / "missing"), "-o", str(tmp_path / "c.json")]) == 2
    assert not (tmp_path / "c.json").exists()
