"""Energy counters and power sensors a machine may expose, each behind one small reader.

Two kinds of source exist, and both end up as a cumulative energy in joules:

* energy counters (Intel/AMD RAPL through powercap sysfs, NVIDIA NVML's total-energy counter):
  E(t) is read directly; a counter that wraps (RAPL: at ``max_energy_range_uj``) is unwrapped
  on every read, so reads must come more often than one wrap period (minutes to hours);
* power sensors (Jetson INA3221 rails, old ``ina3221x`` IIO driver and new ``ina3221`` hwmon
  driver): P(t) is sampled and integrated by the trapezoid rule, E = sum (P_i + P_i+1)/2 * dt.

Every reader takes the root of the tree it reads (``/sys`` by default), so the tests build fake
sysfs trees in temporary directories. ``discover(root)`` lists the readers that work here and,
for those that exist but cannot be read (RAPL is root-only on recent kernels), why not.
"""
from __future__ import annotations

import abc
import ctypes
import glob
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path


class ReaderUnavailable(Exception):
    """This counter does not exist here, or cannot be read (the message says which)."""


def _read_int(path: Path) -> int:
    with open(path, "r", encoding="ascii") as f:
        return int(f.read().strip())


def _read_str(path: Path, default: str = "") -> str:
    try:
        with open(path, "r", encoding="utf-8") as f:
            return f.read().strip()
    except OSError:
        return default


def unwrap_delta(prev: int, cur: int, max_range: int) -> int:
    """Increase of a counter that runs 0..max_range and restarts at 0 (at most one wrap).

    The powercap documentation gives ``max_energy_range_uj`` as the counter's range, so a read
    lower than the previous one means the counter passed max_range: delta = max_range - prev + cur.
    """
    if cur >= prev:
        return cur - prev
    return max_range - prev + cur


class EnergyReader(abc.ABC):
    """A cumulative energy source. ``energy_j()`` is monotonic from the reader's creation.

    name: short id (``rapl``, ``nvml``, ``ina3221``, ``ina3221x``); source: what exactly is
    summed (domains, rails, devices), printed beside every measured figure.
    """

    name = "reader"

    def __init__(self) -> None:
        self.source = ""

    @abc.abstractmethod
    def energy_j(self) -> float:
        """Joules since the reader was created (monotonic)."""

    def close(self) -> None:
        """Release what the reader holds (threads, libraries). Idempotent."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def describe(self) -> dict:
        return {"name": self.name, "source": self.source}


# ----------------------------------------------------------------------------------------- RAPL
@dataclass
class _RaplDomain:
    path: Path
    name: str
    max_range: int
    last: int
    total: int = 0


class RaplReader(EnergyReader):
    """Intel RAPL (also AMD's, which Linux exposes through the same powercap class).

    Sums the top-level ``package-*`` zones plus ``dram`` zones (which are outside the package);
    ``psys`` (whole platform, overlaps the packages) and the core/uncore subzones (inside the
    package) are not added, to avoid counting the same joules twice.
    """

    name = "rapl"

    def __init__(self, root: str | os.PathLike = "/sys"):
        super().__init__()
        base = Path(root) / "class" / "powercap"
        zones = sorted(p for p in base.glob("intel-rapl:*") if (p / "energy_uj").exists())
        if not zones:
            raise ReaderUnavailable(f"no RAPL zones under {base}")
        self.domains: list[_RaplDomain] = []
        problems = []
        for z in zones:
            name = _read_str(z / "name", z.name)
            if not (name.startswith("package") or name == "dram"):
                continue
            try:
                last = _read_int(z / "energy_uj")
                max_range = _read_int(z / "max_energy_range_uj")
            except PermissionError:
                problems.append(f"{z / 'energy_uj'}: permission denied (RAPL is root-only on this kernel)")
                continue
            except (OSError, ValueError) as exc:
                problems.append(f"{z / 'energy_uj'}: {exc}")
                continue
            self.domains.append(_RaplDomain(z, name, max_range, last))
        if not self.domains:
            raise ReaderUnavailable("; ".join(problems) or f"no package or dram RAPL zone under {base}")
        self.source = "RAPL " + "+".join(f"{d.name}({d.path.name})" for d in self.domains)

    def energy_j(self) -> float:
        total_uj = 0
        for d in self.domains:
            cur = _read_int(d.path / "energy_uj")
            d.total += unwrap_delta(d.last, cur, d.max_range)
            d.last = cur
            total_uj += d.total
        return total_uj * 1e-6


# ----------------------------------------------------------------------------------------- NVML
class NvmlReader(EnergyReader):
    """NVIDIA NVML ``nvmlDeviceGetTotalEnergyConsumption`` (mJ since driver load, Volta or newer).

    pynvml is not a dependency: the library is called through ctypes. ``library`` names the
    shared object to load (tests pass a path that does not exist).
    """

    name = "nvml"
    NVML_SUCCESS = 0

    def __init__(self, library: str = "libnvidia-ml.so.1", devices: list[int] | None = None):
        super().__init__()
        try:
            self._lib = ctypes.CDLL(library)
        except OSError as exc:
            raise ReaderUnavailable(f"NVML library {library} not loadable ({exc})") from None
        lib = self._lib
        init = getattr(lib, "nvmlInit_v2", None) or getattr(lib, "nvmlInit", None)
        if init is None or init() != self.NVML_SUCCESS:
            raise ReaderUnavailable("nvmlInit failed (no NVIDIA driver running?)")
        self._initialised = True
        count = ctypes.c_uint(0)
        get_count = getattr(lib, "nvmlDeviceGetCount_v2", None) or lib.nvmlDeviceGetCount
        if get_count(ctypes.byref(count)) != self.NVML_SUCCESS or count.value == 0:
            self.close()
            raise ReaderUnavailable("NVML sees no GPU")
        get_handle = getattr(lib, "nvmlDeviceGetHandleByIndex_v2", None) or lib.nvmlDeviceGetHandleByIndex
        self._handles = []
        names = []
        for i in devices if devices is not None else range(count.value):
            h = ctypes.c_void_p()
            if get_handle(ctypes.c_uint(i), ctypes.byref(h)) != self.NVML_SUCCESS:
                continue
            mj = ctypes.c_ulonglong(0)
            if lib.nvmlDeviceGetTotalEnergyConsumption(h, ctypes.byref(mj)) != self.NVML_SUCCESS:
                continue          # pre-Volta GPUs have no energy counter
            buf = ctypes.create_string_buffer(96)
            lib.nvmlDeviceGetName(h, buf, ctypes.c_uint(96))
            names.append(f"{i}:{buf.value.decode(errors='replace')}")
            self._handles.append(h)
        if not self._handles:
            self.close()
            raise ReaderUnavailable("no GPU with an NVML total-energy counter (needs Volta or newer)")
        self._start_mj = self._sum_mj()
        self.source = "NVML total energy " + ", ".join(names)

    def _sum_mj(self) -> int:
        total = 0
        for h in self._handles:
            mj = ctypes.c_ulonglong(0)
            self._lib.nvmlDeviceGetTotalEnergyConsumption(h, ctypes.byref(mj))
            total += mj.value
        return total

    def energy_j(self) -> float:
        return (self._sum_mj() - self._start_mj) * 1e-3

    def close(self) -> None:
        if getattr(self, "_initialised", False):
            self._initialised = False
            self._lib.nvmlShutdown()


# ------------------------------------------------------------------------------ Jetson INA3221
@dataclass
class Rail:
    """One INA3221 channel: power in mW = read_mw()."""

    label: str
    power_file: Path | None = None          # old driver: in_power<i>_input (mW)
    volt_file: Path | None = None           # new driver: in<i>_input (mV)
    curr_file: Path | None = None           # new driver: curr<i>_input (mA)

    def read_mw(self) -> float:
        if self.power_file is not None:
            return float(_read_int(self.power_file))
        return _read_int(self.volt_file) * _read_int(self.curr_file) / 1000.0


def _ina3221_old_rails(root: Path) -> list[Rail]:
    rails = []
    for dev in sorted(glob.glob(str(root / "bus/i2c/drivers/ina3221x/*/iio:device*"))):
        d = Path(dev)
        for pf in sorted(d.glob("in_power*_input")):
            idx = pf.name[len("in_power"):-len("_input")]
            rails.append(Rail(_read_str(d / f"rail_name_{idx}", f"{d.parent.name}/ch{idx}"), power_file=pf))
    return rails


def _ina3221_new_rails(root: Path) -> list[Rail]:
    rails = []
    for hw in sorted(glob.glob(str(root / "bus/i2c/drivers/ina3221/*/hwmon/hwmon*"))):
        d = Path(hw)
        for cf in sorted(d.glob("curr*_input")):
            idx = cf.name[len("curr"):-len("_input")]
            vf = d / f"in{idx}_input"
            if not vf.exists():
                continue
            if _read_str(d / f"in{idx}_enable", "1") == "0":
                continue
            label = _read_str(d / f"in{idx}_label", f"{d.parents[1].name}/ch{idx}")
            rails.append(Rail(label, volt_file=vf, curr_file=cf))
    return rails


def select_rails(rails: list[Rail]) -> list[Rail]:
    """The rails whose sum is the board's power: the input rail alone when there is one.

    Jetson boards put the whole module's input (VDD_IN, POM_5V_IN, VDD_IN_5V...) on one channel
    and its parts (CPU, GPU, SOC, DDR) on others; adding them all would count the parts twice.
    """
    inputs = [r for r in rails if "_IN" in r.label.upper() and "SYS" not in r.label.upper()]
    return inputs[:1] if inputs else rails


class PowerIntegrator(EnergyReader):
    """Integrates a sampled power (W) into energy by the trapezoid rule in a sampling thread.

    The thread wakes every ``period_s``; on a 2-core machine it costs well under 1% of a core at
    the default 10 ms. ``energy_j()`` also takes a sample, so a short run is bracketed exactly.
    """

    def __init__(self, period_s: float = 0.01):
        super().__init__()
        self.period_s = period_s
        self._lock = threading.Lock()
        self._t = time.perf_counter()
        self._p = self.power_w()
        self._e = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=f"{self.name}-sampler", daemon=True)
        self._thread.start()

    @abc.abstractmethod
    def power_w(self) -> float:
        """Instantaneous power in watts."""

    def _sample(self) -> float:
        with self._lock:
            p = self.power_w()
            t = time.perf_counter()
            self._e += 0.5 * (p + self._p) * (t - self._t)
            self._t, self._p = t, p
            return self._e

    def _loop(self) -> None:
        while not self._stop.wait(self.period_s):
            self._sample()

    def energy_j(self) -> float:
        return self._sample()

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)


class Ina3221Reader(PowerIntegrator):
    """Jetson INA3221 rails, either driver; ``driver`` = ``ina3221x`` (old IIO) or ``ina3221``
    (new hwmon), or None to take whichever exists (old first: TX2 / L4T 32)."""

    def __init__(self, root: str | os.PathLike = "/sys", driver: str | None = None, period_s: float = 0.01):
        root = Path(root)
        found = []
        if driver in (None, "ina3221x"):
            found = _ina3221_old_rails(root)
            self.name = "ina3221x"
        if not found and driver in (None, "ina3221"):
            found = _ina3221_new_rails(root)
            self.name = "ina3221"
        if not found:
            raise ReaderUnavailable(f"no INA3221 rails under {root / 'bus/i2c/drivers'}")
        self.rails = select_rails(found)
        self.all_rails = found
        try:
            for r in self.rails:
                r.read_mw()
        except (OSError, ValueError) as exc:
            raise ReaderUnavailable(f"INA3221 rail unreadable: {exc}") from None
        super().__init__(period_s)
        self.source = f"Jetson INA3221 ({self.name} driver) " + "+".join(r.label for r in self.rails)

    def power_w(self) -> float:
        return sum(r.read_mw() for r in self.rails) * 1e-3


# ------------------------------------------------------------------------------ Loihi 2 profiler
class Loihi2Profiler:
    """Loihi 2 board power and per-step execution time, through lava-loihi's profiler.

    lava-loihi (Intel's NRC package, not public) provides ``lava.utils.loihi2_profiler`` with
    ``Loihi2Power(num_steps)`` and ``Loihi2ExecutionTime(buffer_size)``; both attach to the board
    before the run (``pre_run_fxs`` of ``Loihi2HwCfg``) and collect afterwards (``post_run_fxs``).
    This is not an EnergyReader (the board reports per run, not as a host-readable counter):
    hand ``pre_run_fxs`` / ``post_run_fxs`` to the run config, then read ``results()``.
    """

    name = "loihi2-profiler"

    def __init__(self, num_steps: int):
        try:
            from lava.utils import loihi2_profiler  # type: ignore[attr-defined]
        except ImportError:
            raise ReaderUnavailable("lava-loihi not installed (lava.utils.loihi2_profiler missing)") from None
        self.num_steps = int(num_steps)
        self._power = loihi2_profiler.Loihi2Power(num_steps=self.num_steps)
        self._time = loihi2_profiler.Loihi2ExecutionTime(buffer_size=self.num_steps)
        self.source = "Loihi 2 board profiler (lava-loihi)"

    @property
    def pre_run_fxs(self) -> list:
        return [self._power.attach, self._time.attach]

    @property
    def post_run_fxs(self) -> list:
        return [lambda _board: self._power.get_results(), lambda _board: self._time.get_results()]

    def results(self) -> dict:
        """T_ts per step (us), total and static power (W) as the profiler reports them."""
        import numpy as np

        def arr(obj, *names):
            for n in names:
                v = getattr(obj, n, None)
                if v is not None:
                    return np.asarray(v, dtype=float)
            return None

        t_us = arr(self._time, "time_per_step", "execution_time_per_step")
        total = arr(self._power, "total_power")
        static = arr(self._power, "static_total_power", "static_power")
        out = {"source": self.source}
        if t_us is not None:
            out["t_ts_us"] = float(np.mean(t_us))
        if total is not None:
            out["total_power_w"] = float(np.mean(total))
        if static is not None:
            out["static_power_w"] = float(np.mean(static))
        return out


# ------------------------------------------------------------------------------------ discovery
@dataclass
class Discovery:
    """What the machine offers: working readers, and for every other source why it is not used."""

    readers: list[EnergyReader] = field(default_factory=list)
    unavailable: dict[str, str] = field(default_factory=dict)
    loihi2_profiler: bool = False

    def describe(self) -> dict:
        return {"found": [r.describe() for r in self.readers], "unavailable": dict(self.unavailable),
                "loihi2_profiler": self.loihi2_profiler}

    def close(self) -> None:
        for r in self.readers:
            r.close()


def discover(root: str | os.PathLike = "/sys", nvml_library: str = "libnvidia-ml.so.1") -> Discovery:
    """Try every known source. Never raises: failures are recorded in ``unavailable``."""
    d = Discovery()
    for key, make in (("rapl", lambda: RaplReader(root)), ("nvml", lambda: NvmlReader(nvml_library)),
                      ("ina3221", lambda: Ina3221Reader(root))):
        try:
            d.readers.append(make())
        except ReaderUnavailable as exc:
            d.unavailable[key] = str(exc)
        except OSError as exc:          # odd sysfs states: report, never crash the benchmark
            d.unavailable[key] = f"unreadable: {exc}"
    d.loihi2_profiler = loihi2_profiler_available()
    if not d.loihi2_profiler:
        d.unavailable["loihi2"] = "lava-loihi not installed (lava.utils.loihi2_profiler missing)"
    return d


def loihi2_profiler_available() -> bool:
    """True when lava-loihi's profiler module can be found (without importing Lava itself)."""
    import importlib.util
    try:
        return importlib.util.find_spec("lava.utils.loihi2_profiler") is not None
    except (ImportError, ValueError):
        return False
