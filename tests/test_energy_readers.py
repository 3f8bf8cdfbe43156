"""Energy readers on fake sysfs trees built in tmp dirs (RAPL wrap-around, both INA3221 drivers)."""
from __future__ import annotations

import time
from pathlib import Path

import pytest

from toffe_deploy.energy.measure import measure_dynamic
from toffe_deploy.energy.readers import (Ina3221Reader, NvmlReader, RaplReader, Rail, ReaderUnavailable, discover,
                                         select_rails, unwrap_delta)

MAX_UJ = 262_143_328_850      # a real package's max_energy_range_uj


def put(path: Path, value) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"{value}\n")
    return path


def rapl_tree(root: Path, pkg_uj: int, dram_uj: int = 0) -> Path:
    base = root / "class" / "powercap"
    put(base / "intel-rapl:0" / "name", "package-0")
    put(base / "intel-rapl:0" / "energy_uj", pkg_uj)
    put(base / "intel-rapl:0" / "max_energy_range_uj", MAX_UJ)
    put(base / "intel-rapl:0:0" / "name", "core")                 # inside the package: not added
    put(base / "intel-rapl:0:0" / "energy_uj", 999_999_999)
    put(base / "intel-rapl:0:0" / "max_energy_range_uj", MAX_UJ)
    put(base / "intel-rapl:0:1" / "name", "dram")                 # outside the package: added
    put(base / "intel-rapl:0:1" / "energy_uj", dram_uj)
    put(base / "intel-rapl:0:1" / "max_energy_range_uj", 65_712_999_613)
    put(base / "intel-rapl:1" / "name", "psys")                   # whole platform: not added
    put(base / "intel-rapl:1" / "energy_uj", 5)
    put(base / "intel-rapl:1" / "max_energy_range_uj", MAX_UJ)
    return base / "intel-rapl:0" / "energy_uj"


def test_unwrap_delta():
    assert unwrap_delta(100, 250, 1000) == 150
    assert unwrap_delta(900, 50, 1000) == 150        # 900 -> 1000 (100) then 0 -> 50
    assert unwrap_delta(7, 7, 1000) == 0


def test_rapl_sums_package_and_dram_only_and_unwraps(tmp_path):
    pkg = rapl_tree(tmp_path, MAX_UJ - 1_000_000, dram_uj=0)
    r = RaplReader(tmp_path)
    assert "package-0" in r.source and "dram" in r.source and "psys" not in r.source and "core" not in r.source
    assert r.energy_j() == 0.0
    put(pkg, 2_000_000)                                     # wrapped: 1 J to the top + 2 J after it
    put(tmp_path / "class/powercap/intel-rapl:0:1/energy_uj", 500_000)
    assert r.energy_j() == pytest.approx(3.5)
    put(pkg, 4_000_000)
    assert r.energy_j() == pytest.approx(5.5)               # cumulative across the wrap


def test_rapl_missing_is_unavailable(tmp_path):
    with pytest.raises(ReaderUnavailable, match="no RAPL zones"):
        RaplReader(tmp_path)


def test_measure_dynamic_with_rapl_counter_that_wraps(tmp_path):
    """Each inference adds 0.25 J to the counter, the idle counter is still: E_dyn = 0.25 J."""
    pkg = rapl_tree(tmp_path, MAX_UJ - 300_000)
    r = RaplReader(tmp_path)
    state = {"uj": MAX_UJ - 300_000}

    def run_one(_i):
        state["uj"] = (state["uj"] + 250_000) % MAX_UJ
        put(pkg, state["uj"])
        time.sleep(0.002)

    dyn = measure_dynamic(r, run_one, n_items=3, min_run_s=0.03, idle_s=0.02)
    assert dyn.status == "measured" and dyn.k >= 3
    assert dyn.per_inference_j == pytest.approx(0.25, rel=1e-9)
    assert dyn.idle_w == 0.0


def ina_old_tree(root: Path) -> None:
    dev = root / "bus/i2c/drivers/ina3221x/0-0041/iio:device0"
    for i, (name, mw) in enumerate([("VDD_IN", 4000), ("VDD_SYS_CPU", 900), ("VDD_SYS_DDR", 600)]):
        put(dev / f"rail_name_{i}", name)
        put(dev / f"in_power{i}_input", mw)
        put(dev / f"in_current{i}_input", mw // 5)
        put(dev / f"in_voltage{i}_input", 5000)


def ina_new_tree(root: Path) -> None:
    hw = root / "bus/i2c/drivers/ina3221/1-0040/hwmon/hwmon3"
    for i, (label, mv, ma) in enumerate([("VDD_IN", 5000, 400), ("VDD_CPU_GPU_CV", 5000, 200), ("VDD_SOC", 5000, 100)],
                                        start=1):
        put(hw / f"in{i}_label", label)
        put(hw / f"in{i}_input", mv)
        put(hw / f"curr{i}_input", ma)
    put(hw / "in4_input", 12)       # shunt voltage channels have no current file: ignored


def test_ina3221_old_driver_reads_input_rail_in_mw(tmp_path):
    ina_old_tree(tmp_path)
    with Ina3221Reader(tmp_path, period_s=10.0) as r:
        assert r.name == "ina3221x" and [x.label for x in r.rails] == ["VDD_IN"]
        assert len(r.all_rails) == 3
        assert r.power_w() == pytest.approx(4.0)
        t_a = time.perf_counter()
        e1 = r.energy_j()
        time.sleep(0.05)
        e2 = r.energy_j()
        t_b = time.perf_counter()
        assert 4.0 * 0.05 <= e2 - e1 <= 4.0 * (t_b - t_a)


def test_ina3221_new_driver_multiplies_volts_and_amps(tmp_path):
    ina_new_tree(tmp_path)
    with Ina3221Reader(tmp_path, period_s=10.0) as r:
        assert r.name == "ina3221" and [x.label for x in r.rails] == ["VDD_IN"]
        assert r.power_w() == pytest.approx(2.0)          # 5000 mV * 400 mA
        put(tmp_path / "bus/i2c/drivers/ina3221/1-0040/hwmon/hwmon3/curr1_input", 800)
        assert r.power_w() == pytest.approx(4.0)


def test_ina3221_integrates_a_power_step_by_trapezoid(tmp_path):
    ina_new_tree(tmp_path)
    cur = tmp_path / "bus/i2c/drivers/ina3221/1-0040/hwmon/hwmon3/curr1_input"
    with Ina3221Reader(tmp_path, period_s=10.0) as r:
        r.energy_j()
        put(cur, 1200)                                      # 2 W -> 6 W
        t0 = time.perf_counter()
        time.sleep(0.05)
        e = r.energy_j()
        dt = time.perf_counter() - t0
        e2 = r.energy_j()
        # one interval with endpoints 2 W and 6 W: trapezoid = 4 W * interval
        assert 4.0 * 0.05 <= e <= 4.0 * (dt + 0.01) + 1e-9
        assert e2 > e


def test_new_driver_disabled_channel_is_skipped(tmp_path):
    ina_new_tree(tmp_path)
    hw = tmp_path / "bus/i2c/drivers/ina3221/1-0040/hwmon/hwmon3"
    put(hw / "in1_enable", 0)
    with Ina3221Reader(tmp_path, driver="ina3221", period_s=10.0) as r:
        assert sorted(x.label for x in r.all_rails) == ["VDD_CPU_GPU_CV", "VDD_SOC"]
        assert r.power_w() == pytest.approx(1.5)            # no input rail: the parts are summed


def test_select_rails_prefers_the_input_rail():
    rails = [Rail("VDD_SYS_GPU"), Rail("POM_5V_IN"), Rail("VDD_SYS_CPU")]
    assert [r.label for r in select_rails(rails)] == ["POM_5V_IN"]
    assert len(select_rails(rails[::2])) == 2


def test_nvml_without_library_is_unavailable(tmp_path):
    with pytest.raises(ReaderUnavailable, match="not loadable"):
        NvmlReader(str(tmp_path / "libnvidia-ml.so.1"))


def test_discover_reports_why_each_source_is_missing(tmp_path):
    d = discover(tmp_path, nvml_library=str(tmp_path / "none.so"))
    assert d.readers == []
    assert set(d.unavailable) >= {"rapl", "nvml", "ina3221", "loihi2"}
    ina_old_tree(tmp_path)
    rapl_tree(tmp_path, 0)
    d = discover(tmp_path, nvml_library=str(tmp_path / "none.so"))
    try:
        assert sorted(r.name for r in d.readers) == ["ina3221x", "rapl"]
        assert d.describe()["found"][0]["source"]
    finally:
        d.close()


def test_loihi2_profiler_needs_lava_loihi():
    from toffe_deploy.energy.readers import Loihi2Profiler, loihi2_profiler_available

    if loihi2_profiler_available():
        pytest.skip("lava-loihi is installed here")
    with pytest.raises(ReaderUnavailable, match="lava-loihi"):
        Loihi2Profiler(num_steps=5)
