"""Rendering of the energy/latency results: the Table 2 layout in markdown, and the log-scale plot.

A result row is a plain dict (it goes to JSON as it is):

    model, target, status ("ok" | "unavailable"), reason,
    E_mj, E_kind   headline dynamic energy per inference and what it is
                   ("measured (source)", "below noise (source)" or "modelled (constants...)")
    L_ms, L_kind   headline latency per inference (p50 wall time on host targets; modelled
                   Loihi 2 T_ts * B plus the measured host part on the hybrid)
    ...            every raw figure (percentiles, op counts, Loihi activity, simulator wall time)
"""
from __future__ import annotations

import math
from typing import Iterable

MODELS = ("asnet", "dotie", "dotie_cluster", "dotie_cluster_window", "toffe")
MODEL_NAMES = {"asnet": "Adaptive-SpikeNet (Pico), optical flow -> object flow",
               "dotie": "DOTIE w/o clustering, speed separation",
               "dotie_cluster": "DOTIE with clustering, detection (DBSCAN every step, as its code)",
               "dotie_cluster_window": "DOTIE, one DBSCAN per window (not its code; for comparison)",
               "toffe": "TOFFE, object flow"}
MODEL_TICKS = {"asnet": "Adaptive-\nSpikeNet", "dotie": "DOTIE", "dotie_cluster": "DOTIE + DBSCAN\nper step", "dotie_cluster_window": "DOTIE + DBSCAN\nper window",
               "toffe": "TOFFE"}
TARGETS = ("cpu", "cuda", "loihi-sim", "loihi2")

#: The paper's Table 2, E (mJ) / L (ms) per model and hardware.
PAPER_TABLE2 = {
    "hardware": {"cpu": "i9-12700KF", "cuda": "RTX 3090 Ti", "jetson": "Jetson TX2", "loihi": "Loihi 2 + TX2"},
    "asnet": {"cpu": (1029.1, 24.04), "cuda": (417.2, 4.14), "jetson": (89.2, 41.84), "loihi": (None, None)},
    "dotie": {"cpu": (28.8, 0.62), "cuda": (31.1, 0.34), "jetson": (4.6, 5.95), "loihi": (0.083, 0.29)},
    "dotie_cluster": {"cpu": (558.0, 16.8), "cuda": (426.9, 4.50), "jetson": (74.2, 93.46), "loihi": (69.6, 88.67)},
    "toffe": {"cpu": (92.5, 2.17), "cuda": (123.0, 1.34), "jetson": (13.0, 20.12), "loihi": (8.38, 15.33)},
}
GOALS = {"cpu_latency_ratio": 16.8 / 2.17, "cpu_energy_ratio": 558.0 / 92.5}

#: Which of our targets sits beside which paper column.
COLUMNS = (("cpu", "cpu"), ("cuda", "cuda"), ("loihi-sim", "loihi"), ("loihi2", "loihi"))


def fmt(x: float | None, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    if x == 0:
        return "0"
    if abs(x) >= 100:
        return f"{x:.1f}"
    return f"{x:.{digits}g}"


def energy_tag(kind: str) -> str:
    """Short mark for a table cell: [m] modelled, [b] below noise, [r]/[n]/[j] measured source."""
    k = kind.lower()
    if k.startswith("modelled"):
        return "m"
    if k.startswith("below noise"):
        return "b"
    if "rapl" in k:
        return "r"
    if "nvml" in k:
        return "n"
    if "ina3221" in k:
        return "j"
    if "loihi" in k:
        return "l"
    return "?"


def cell(row: dict | None) -> str:
    if row is None:
        return "not run"
    if row.get("status") != "ok":
        return "n/a"
    e = "below noise" if row.get("E_kind", "").startswith("below noise") else fmt(row.get("E_mj"))
    tag = energy_tag(row.get("E_kind", ""))
    lk = "ᵐ" if row.get("L_kind", "").startswith("modelled") else ""
    return f"{e} [{tag}] / {fmt(row.get('L_ms'))}{lk}"


def index_rows(rows: Iterable[dict]) -> dict[tuple[str, str], dict]:
    return {(r["model"], r["target"]): r for r in rows}


def ratio(a: float | None, b: float | None) -> float | None:
    if a is None or b is None or b <= 0 or not (math.isfinite(a) and math.isfinite(b)):
        return None
    return a / b


def ratios(rows: Iterable[dict]) -> dict[str, dict]:
    """DOTIE-with-clustering / TOFFE, energy and latency, per target (same run)."""
    idx = index_rows(rows)
    out = {}
    for t in TARGETS:
        d, f = idx.get(("dotie_cluster", t)), idx.get(("toffe", t))
        if not (d and f and d.get("status") == "ok" and f.get("status") == "ok"):
            continue
        out[t] = {"energy": ratio(d.get("E_mj"), f.get("E_mj")), "latency": ratio(d.get("L_ms"), f.get("L_ms")),
                  "energy_modelled": ratio(d.get("E_model_mj"), f.get("E_model_mj")),
                  "energy_kind": f"{d.get('E_kind')} vs {f.get('E_kind')}"}
    return out


def markdown_table(rows: list[dict], machine_name: str) -> str:
    """Table 2 layout: per model, the paper's E / L beside ours per hardware column."""
    idx = index_rows(rows)
    hw = PAPER_TABLE2["hardware"]
    head = ["model", f"paper {hw['cpu']}", f"ours cpu ({machine_name})", f"paper {hw['cuda']}", "ours cuda",
            f"paper {hw['loihi']}", "ours Loihi 2 (modelled) + host cpu", "ours loihi2"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]

    def paper(m, col):
        if m not in PAPER_TABLE2:
            return "-"
        e, l = PAPER_TABLE2[m][col]
        return f"{fmt(e)} / {fmt(l)}"

    def ours(m, t):              # comparison rows (no paper figure) are run on cpu only
        r = idx.get((m, t))
        return "-" if r is None and m not in PAPER_TABLE2 else cell(r)

    for m in MODELS:
        cells = [MODEL_NAMES[m], paper(m, "cpu"), ours(m, "cpu"), paper(m, "cuda"), ours(m, "cuda"),
                 paper(m, "loihi"), ours(m, "loihi-sim"), ours(m, "loihi2")]
        lines.append("| " + " | ".join(cells) + " |")
    r = ratios(rows)

    def rcell(t):
        x = r.get(t)
        if not x:
            return "-"
        return f"{fmt(x['energy'])}x / {fmt(x['latency'])}x"

    p = PAPER_TABLE2

    def pr(col):
        return (f"{fmt(p['dotie_cluster'][col][0] / p['toffe'][col][0])}x / "
                f"{fmt(p['dotie_cluster'][col][1] / p['toffe'][col][1])}x")

    lines.append("| **ratio DOTIE with clustering / TOFFE** | " + " | ".join(
        [pr("cpu"), rcell("cpu"), pr("cuda"), rcell("cuda"), pr("loihi"), rcell("loihi-sim"), rcell("loihi2")]) + " |")
    return "\n".join(lines)


def legend() -> str:
    return ("Cells: dynamic energy per inference E (mJ) [how] / latency per inference L (ms, p50, batch 1). "
            "[m] modelled from counted operations (constants in the JSON), [r] measured RAPL, [n] measured NVML, "
            "[j] measured Jetson INA3221, [l] Loihi 2 profiler, [b] measured but below noise; "
            "ᵐ latency modelled (Loihi 2 T_ts x B from counted activity, plus the host part measured here). "
            "n/a: target not available on this machine (reason in the JSON).")


def detail_table(rows: list[dict]) -> str:
    """Every row: latency percentiles, energy variants, and the simulator wall time where run."""
    head = ["model", "target", "L p50 ms", "L p90 ms", "L p99 ms", "E mJ", "E how", "E op-model mJ", "notes"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        if r.get("status") != "ok":
            lines.append(f"| {r['model']} | {r['target']} | - | - | - | - | - | - | n/a: {r.get('reason', '')} |")
            continue
        lat = r.get("latency") or {}
        notes = list(r.get("notes", []))
        sim = r.get("sim_wall")
        if sim:
            notes.append(f"Lava simulator wall time {fmt(sim.get('p50_ms'))} ms/window p50 over {sim.get('n')} "
                         f"windows (simulation, not Loihi latency)")
        lines.append("| " + " | ".join([
            r["model"], r["target"], fmt(lat.get("p50_ms", r.get("L_ms"))), fmt(lat.get("p90_ms")), fmt(lat.get("p99_ms")),
            "below noise" if r.get("E_kind", "").startswith("below") else fmt(r.get("E_mj")), r.get("E_kind", ""),
            fmt(r.get("E_model_mj")), "; ".join(notes)]) + " |")
    return "\n".join(lines)


def hybrid_split_table(row: dict | None) -> str:
    """TOFFE on Loihi 2 + host: the modelled Loihi side per stage, the host side, and the paper."""
    if not row or row.get("status") != "ok" or "loihi" not in row:
        return "(no Loihi 2 model: TOFFE was not counted)"
    lo, host = row["loihi"], row["host"]
    lines = ["| part | E (mJ) | L (ms) | how |", "|---|---|---|---|"]
    for i, st in enumerate(lo["stages"], start=1):
        lines.append(f"| Loihi 2 OFS stage {i} ({st['cores']} cores, T_ts {fmt(st['t_ts_mean_us'])} us, "
                     f"{st['synops'] / max(st['steps'], 1):.0f} synops/step) | {fmt(st['energy_mj'])} | "
                     f"{fmt(st['latency_ms'])} | modelled |")
    lines.append(f"| **Loihi 2 side, OFS cascade (B = {lo['steps_per_stage']}, {len(lo['stages'])} stages in sequence)** | "
                 f"{fmt(lo['energy_mj'])} | {fmt(lo['latency_ms'])} | {lo['label']} |")
    lines.append(f"| host side: masks + OFPD (this CPU) | {fmt(host['energy_mj'])} | {fmt(host['latency_ms'])} | "
                 f"E {host['energy_kind']}; L measured p50 |")
    lines.append(f"| **total per inference** | {fmt(row['E_mj'])} | {fmt(row['L_ms'])} | |")
    e, l = PAPER_TABLE2["toffe"]["loihi"]
    lines.append(f"| paper, Loihi 2 + Jetson TX2 (measured) | {fmt(e)} | {fmt(l)} | Table 2 |")
    return "\n".join(lines)


def goals(rows: list[dict]) -> dict:
    """The issue's goals, evaluated on this run's cpu rows."""
    r = ratios(rows).get("cpu")
    if not r:
        return {"evaluated": False, "reason": "TOFFE or DOTIE with clustering did not run on cpu"}
    lat_ok = r["latency"] is not None and r["latency"] >= GOALS["cpu_latency_ratio"]
    em = r["energy_modelled"]
    idx = index_rows(rows)
    tp = ratio(idx[("dotie_cluster", "cpu")].get("E_time_power_mj"), idx[("toffe", "cpu")].get("E_time_power_mj"))
    win = idx.get(("dotie_cluster_window", "cpu"), {})
    window = {"cpu_latency_ratio_window": ratio(win.get("L_ms"), idx[("toffe", "cpu")].get("L_ms")),
              "cpu_energy_ratio_window_modelled": ratio(win.get("E_model_mj"), idx[("toffe", "cpu")].get("E_model_mj"))}
    return {**window, "evaluated": True, "cpu_latency_ratio": r["latency"], "cpu_energy_ratio_time_power": tp, "cpu_latency_goal": GOALS["cpu_latency_ratio"],
            "cpu_latency_met": bool(lat_ok), "cpu_energy_ratio_modelled": em,
            "cpu_energy_goal": GOALS["cpu_energy_ratio"], "cpu_energy_met": bool(em is not None and em >= GOALS["cpu_energy_ratio"]),
            "cpu_energy_ratio_headline": r["energy"], "cpu_energy_headline_kind": r["energy_kind"]}


def plot(rows: list[dict], path, title: str) -> None:
    """Energy and latency per model and target (ours beside the paper's), log scale, PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    idx = index_rows(rows)
    series = [("paper CPU", lambda m: PAPER_TABLE2[m]["cpu"] if m in PAPER_TABLE2 else (None, None)),
              ("paper Loihi 2 + TX2", lambda m: PAPER_TABLE2[m]["loihi"] if m in PAPER_TABLE2 else (None, None))]
    for t in TARGETS:
        if any(idx.get((m, t), {}).get("status") == "ok" for m in MODELS):
            kinds = {energy_tag(idx.get((m, t), {}).get("E_kind", "")) for m in MODELS
                     if idx.get((m, t), {}).get("status") == "ok"}
            series.append((f"ours {t}" + (" (Loihi 2 model + host)" if t == "loihi-sim" else "")
                           + (", E modelled" if kinds == {"m"} else ""),
                           lambda m, t=t: (idx.get((m, t), {}).get("E_mj"), idx.get((m, t), {}).get("L_ms"))
                           if idx.get((m, t), {}).get("status") == "ok" else (None, None)))
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    x = np.arange(len(MODELS))
    width = 0.8 / len(series)
    for ax, which, label in ((axes[0], 0, "dynamic energy per inference (mJ)"), (axes[1], 1, "latency per inference (ms)")):
        for i, (name, get) in enumerate(series):
            vals = [get(m)[which] for m in MODELS]
            vals = [v if (v is not None and v > 0) else np.nan for v in vals]
            ax.bar(x + (i - (len(series) - 1) / 2) * width, vals, width, label=name,
                   hatch="//" if name.startswith("paper") else None, alpha=0.85)
        ax.set_yscale("log")
        ax.set_xticks(x)
        ax.set_xticklabels([MODEL_TICKS[m] for m in MODELS], fontsize=8)
        ax.set_ylabel(label)
        ax.grid(True, which="both", axis="y", alpha=0.3)
    axes[1].legend(fontsize=8, loc="best")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)
