"""Description of the machine a benchmark ran on (stored beside every figure)."""
from __future__ import annotations

import os
import platform
import sys
from importlib import metadata


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", "r", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _mem_total_gib() -> float | None:
    try:
        with open("/proc/meminfo", "r", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemTotal:"):
                    return round(int(line.split()[1]) / 2 ** 20, 1)
    except (OSError, ValueError):
        pass
    return None


def _version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def describe_machine(counters: dict | None = None) -> dict:
    """CPU model, cores (total and usable by this process), memory, load, OS, package versions,
    onnxruntime providers and the energy counters found."""
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    try:
        import onnxruntime as ort
        providers = ort.get_available_providers()
    except ImportError:
        providers = []
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    return {
        "cpu_model": _cpu_model(),
        "cpu_cores": os.cpu_count(),
        "cpu_cores_usable": usable,
        "memory_gib": _mem_total_gib(),
        "loadavg_1_5_15": [round(v, 2) for v in load] if load else None,
        "os": f"{platform.system()} {platform.release()}",
        "python": sys.version.split()[0],
        "packages": {n: _version(n) for n in ("numpy", "opencv-python-headless", "onnxruntime", "scikit-learn",
                                               "lava-nc", "toffe-deploy")},
        "onnxruntime_providers": providers,
        "energy_counters": counters or {},
    }


def short_name(machine: dict) -> str:
    """One line for table headers: CPU model, the cores this process may use and the machine's
    (the load average the reports compare with is the machine's: "1 cores" beside "load > 2
    cores" read as a contradiction)."""
    usable, total = machine.get("cpu_cores_usable", "?"), machine.get("cpu_cores", "?")
    cores = f"{usable} core{'' if usable == 1 else 's'}" + (f" of {total}" if total not in ("?", usable) else "")
    return f"{machine.get('cpu_model', '?')}, {cores}"
