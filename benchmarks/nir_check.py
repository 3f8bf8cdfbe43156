"""Check a bundle's ofs.nir in NIR's own readers: snnTorch and Norse (not project dependencies).

Each stage's branch (input -> conv -> LIF -> output) is imported on its own (a 4-branch graph
imports very slowly in snnTorch) and run one window at a time from rest, one time bin per step;
its spikes are compared with the bundle's fixed-point stage (toffe_deploy.fixed_point, what
every runtime runs) and with toffe_deploy.deploy.nir_graph.simulate_nir_stage (NIR's semantics
in numpy). Reset "zero" bundles should agree (F1 >= 0.999); "subtract" ones cannot (NIR's LIF
resets to v_reset) and the F1 says by how much.

    pip install --target /tmp/nirpkgs --no-deps snntorch==1.0.0 norse==1.1.0 nirtorch
    PYTHONPATH=.:/tmp/nirpkgs python benchmarks/nir_check.py export/ --windows 4 [--data data/synth]

Readers that are not importable are reported as such. Prints one line per stage and reader and
writes ``--json`` when given. Exit status: 0 when at least one reader ran and, on a reset "zero"
bundle, every stage agrees with the fixed point (F1 >= 0.999); 1 when no reader could be
imported or a "zero" bundle's stage falls below that F1 ("subtract" bundles are reported, not
judged: they cannot agree); 2 for bad input (bundle, --data, options), one line on stderr.
"""
from __future__ import annotations

import contextlib
import io
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

F1_ZERO_RESET = 0.999        # what a reset "zero" bundle must reach against the fixed point

from toffe_deploy.deploy.bundle import load_bundle  # noqa: E402
from toffe_deploy.deploy.nir_graph import simulate_nir_stage  # noqa: E402
from toffe_deploy.fixed_point import run_ofs_fixed  # noqa: E402
from _args import OneLineParser, existing_dir, guarded, json_output, positive_int  # noqa: E402


def stage_graph(graph, k: int):
    """Branch k of the bundle's graph as its own NIRGraph (input -> conv -> lif -> output)."""
    import nir

    nodes = {"input": graph.nodes["input"], "conv": graph.nodes[f"stage{k}_conv"],
             "lif": graph.nodes[f"stage{k}_lif"], "output": graph.nodes[f"stage{k}_output"]}
    return nir.NIRGraph(nodes=nodes, edges=[("input", "conv"), ("conv", "lif"), ("lif", "output")],
                        metadata=graph.metadata)


def readers(dt_s: float) -> dict:
    """name -> (import a stage graph -> module, or the reason it is unavailable)."""
    out = {}
    try:
        from snntorch.import_nir import import_from_nir

        def snn(g):
            with contextlib.redirect_stdout(io.StringIO()):      # it prints its threshold rescaling
                return import_from_nir(g)
        out["snntorch"] = snn
    except ImportError as exc:
        out["snntorch"] = f"not importable: {exc}"
    try:
        import norse.torch as nt

        out["norse"] = lambda g: nt.from_nir(g, dt=dt_s)
    except ImportError as exc:
        out["norse"] = f"not importable: {exc}"
    return out


def run_module(module, window: np.ndarray) -> np.ndarray:
    """Spikes (B, H, W) of an imported stage on one window (B, C, H, W), from rest."""
    import torch

    x = torch.from_numpy((np.asarray(window) > 0).astype(np.float32))
    for sub in module.modules():        # snnTorch's neurons also keep their membrane inside the
        if hasattr(sub, "reset_mem"):   # module (nirtorch 2 hands back no state for them): rest
            sub.reset_mem()
    state, out = None, []
    with torch.no_grad():
        for t in range(x.shape[0]):
            o, state = module(x[t:t + 1]) if state is None else module(x[t:t + 1], state)
            out.append(o[0, 0].numpy() > 0)
    return np.stack(out)


def f1(a: list[np.ndarray], b: list[np.ndarray]) -> dict:
    tp = sum(int((x & y).sum()) for x, y in zip(a, b))
    na, nb = sum(int(x.sum()) for x in a), sum(int(y.sum()) for y in b)
    return {"f1": 2 * tp / (na + nb) if na + nb else 1.0, "differing": sum(int((x != y).sum()) for x, y in zip(a, b)),
            "spikes": na, "spikes_reference": nb}


def main(argv=None) -> int:
    ap = OneLineParser(prog="nir_check.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("bundle", type=Path)
    ap.add_argument("--windows", type=positive_int, default=4, help="held-out windows (default 4)")
    ap.add_argument("--data", type=existing_dir, default=None, help="data set whose test split gives the windows")
    ap.add_argument("--json", type=json_output, default=None)
    args = ap.parse_args(argv)
    return guarded("nir_check", run, args)


def run(args) -> int:
    import nir

    from toffe_deploy.errors import InputError
    from toffe_deploy.fileio import atomic_path, check_outputs

    from toffe_deploy.deploy.windows import heldout_windows

    bundle = load_bundle(args.bundle)
    check_outputs(files=[("--json", args.json)])
    if not (bundle.root / "ofs.nir").is_file():
        raise InputError(bundle.root / "ofs.nir", "missing file (export the bundle with its NIR graph)")
    graph = nir.read(str(bundle.root / "ofs.nir"))
    dt = float(graph.metadata["time_step_s"])
    held = heldout_windows(bundle.config, data=args.data, n_windows=args.windows, progress=False)
    from toffe_deploy.cascade import pool_any

    wins = [pool_any(w, bundle.config.ofs_pool) for w in held.windows]      # the OFS grid the graph's input is
    report = {"bundle": str(args.bundle), "reset": bundle.config.reset, "time_step_s": dt, "windows": len(wins),
              "readers": {}}
    ran, below = 0, []
    judge = bundle.config.reset == "zero"
    for name, load in readers(dt).items():
        if isinstance(load, str):
            report["readers"][name] = load
            print(f"{name}: {load}")
            continue
        stages = []
        for k, p in enumerate(bundle.ofs, start=1):
            g = stage_graph(graph, k)
            module = load(g)
            got = [run_module(module, w) for w in wins]
            ref = [run_ofs_fixed(w, p) for w in wins]
            sim = [simulate_nir_stage(graph, k, w) for w in wins]
            row = {"stage": k, "vs_fixed_point": f1(got, ref), "vs_nir_semantics": f1(got, sim)}
            stages.append(row)
            if judge and row["vs_fixed_point"]["f1"] < F1_ZERO_RESET:
                below.append(f"{name} stage {k}")
            print(f"{name} stage {k}: F1 {row['vs_fixed_point']['f1']:.4f} vs the bundle's fixed point "
                  f"({row['vs_fixed_point']['differing']} differing of {row['vs_fixed_point']['spikes_reference']} "
                  f"spikes), F1 {row['vs_nir_semantics']['f1']:.4f} vs NIR semantics in numpy")
        report["readers"][name] = stages
        ran += 1
    if args.json:
        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps(report, indent=1) + "\n")
    if not ran:
        print("nir_check: no NIR reader could be imported: nothing checked", file=sys.stderr)
        return 1
    if below:
        print(f"nir_check: F1 below {F1_ZERO_RESET} on a reset \"zero\" bundle: {', '.join(below)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
