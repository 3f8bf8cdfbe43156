"""Adaptive-SpikeNet (Kosta & Roy, ICRA 2023), its small "Pico" variant, as the optical-flow
baseline of the paper's Table 2, with the step that turns its flow into object flow.

Architecture (fully spiking U-Net of the EV-FlowNet / Spike-FlowNet family, as the paper
describes it; its code is not public and the exact Pico widths are not in the sources we could
read, so the widths here are an assumption, stated in ``ASNetConfig``):

    input  x[t]: ON / OFF event counts of bin t (2 channels, graded), t = 1..B (B = 5 steps)
    enc_k  = LIF(conv3x3 stride 2 (enc_{k-1}))                   k = 1..4, widths 8, 16, 32, 64
    res_j  = LIF(conv3x3(LIF(conv3x3(r_{j-1}))) + r_{j-1})       j = 1..2, width 64 (r_0 = enc_4)
    dec_k  = LIF(convT4x4 stride 2 (concat(dec_{k-1}, enc_{5-k})))  k = 1..4, widths 32, 16, 8, 8
    flow   = sum_t conv1x1(dec_4[t]) / B                          (non-spiking integrator read-out)

LIF per layer with a learnable leak and threshold (the paper's "adaptive" neurons), soft reset:

    u[t] = lambda_l * u[t-1] + I[t] - vth_l * o[t-1],   o[t] = H(u[t] / vth_l - 1)

(``model.lif.lif_step``; lambda_l clamped to [0, 1], vth_l >= 0.05; state zero each window).
Weights start as N(0, (2.5)^2 / fan_in): with the default (PyTorch) scale the sparse event input
(0.2% of the pixels) dies out by the fourth encoder, no gradient reaches the deep layers (spike
vanishing, the problem the paper's learnable dynamics address; measured on a training window).
Widths 8-16-32-64 are the full model's 64-128-256-512 divided by 8: 0.26 M parameters, which is
the full EV-FlowNet's ~13 M divided by the 48x the paper quotes for its smallest SNN.

Object flow from the optical flow (``flow_objects``): the flow at the window's event pixels
whose |flow| > ``min_flow_px_ms`` is grouped into blobs with the project's own grouping
(``ofpd_io.blobs_xy``: connected components linked within link_px, merged as for TOFFE's
objects); each group of >= min_events pixels is one object at its pixels' centroid, moving with
their mean flow (direction atan2(v, u), speed |mean flow|), its bin the config's bin of that
speed (clipped to 1..N).

Cost (``count_ops``): per layer and step, from the spikes measured on the window,
* dense: MACs of every conv over every output (what a dense CPU/GPU pass does), plus one LIF
  update per neuron;
* event-driven: one accumulate per (input spike, output it reaches) -- exact, by convolving the
  spike map with a ones kernel -- (graded first layer: one MAC per non-zero input and output it
  reaches), plus LIF updates of the neurons that receive input in the step (a lower bound:
  neurons that only hold decaying state are not counted);
* memory: weights read once per step, membrane state read + written per updated neuron (4 B
  each), spikes written and read (1 B).
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..config import ToffeConfig
from ..errors import InputError
from ..fileio import JSON_ERRORS

WEIGHTS_FILE = "weights.safetensors"
CONFIG_FILE = "config.json"
FORMAT = "toffe-asnet-baseline"


@dataclass(frozen=True)
class ASNetConfig:
    """Sizes of the network and how it was trained. ``downsample``: the sensor is summed over
    d x d pixel blocks before the network (training on a 2-core CPU, README); flow comes out in
    network pixels per ms and is multiplied by d for the sensor."""

    in_channels: int = 2
    n_bins: int = 5
    enc_channels: tuple[int, ...] = (8, 16, 32, 64)
    n_res: int = 2
    dec_channels: tuple[int, ...] = (32, 16, 8, 8)
    leak_init: float = 0.9
    vth_init: float = 1.0
    init_gain: float = 2.5
    downsample: int = 4
    dt_us: int = 500
    min_flow_px_ms: float = 0.1
    source: str = ("Kosta & Roy, Adaptive-SpikeNet, ICRA 2023 (arXiv 2209.11741): fully spiking "
                   "EV-FlowNet-style U-Net, 4 encoders, 2 residual blocks, 4 decoders, B = 5 steps; "
                   "Pico widths assumed = full widths / 8 (not found in the readable sources)")

    @property
    def multiple(self) -> int:
        """Input sides are padded to a multiple of this (the encoders halve them 4 times)."""
        return 2 ** len(self.enc_channels)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["enc_channels"] = list(self.enc_channels)
        d["dec_channels"] = list(self.dec_channels)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ASNetConfig":
        known = {f for f in cls.__dataclass_fields__}
        kw = {k: v for k, v in d.items() if k in known}
        for k in ("enc_channels", "dec_channels"):
            if k in kw:
                kw[k] = tuple(int(c) for c in kw[k])
        return cls(**kw)


@dataclass(frozen=True)
class LayerSpec:
    """One synaptic layer: kind conv | convT | res_conv | readout, input channels, output
    channels, kernel, stride, whether its input is spikes (else graded counts or a sum)."""

    name: str
    kind: str
    c_in: int
    c_out: int
    kernel: int
    stride: int
    spiking_input: bool = True
    neurons: bool = True


def layer_specs(cfg: ASNetConfig) -> list[LayerSpec]:
    """The layers in forward order (module doc)."""
    out = []
    c = cfg.in_channels
    for k, ch in enumerate(cfg.enc_channels, 1):
        out.append(LayerSpec(f"enc{k}", "conv", c, ch, 3, 2, spiking_input=k > 1))
        c = ch
    for j in range(1, cfg.n_res + 1):
        out.append(LayerSpec(f"res{j}a", "conv", c, c, 3, 1))
        out.append(LayerSpec(f"res{j}b", "conv", c, c, 3, 1))
    skips = list(cfg.enc_channels[::-1])
    for k, ch in enumerate(cfg.dec_channels, 1):
        out.append(LayerSpec(f"dec{k}", "convT", c + skips[k - 1], ch, 4, 2))
        c = ch
    out.append(LayerSpec("flow", "conv", c, 2, 1, 1, neurons=False))
    return out


def _torch_model(cfg: ASNetConfig):
    """The torch module (imported lazily: the harness's numpy paths need no torch)."""
    import torch
    import torch.nn as nn
    import torch.nn.functional as F

    from ..model.lif import lif_step

    class AdaptiveSpikeNet(nn.Module):
        """Module doc; forward(x (N, B, 2, H, W)) -> flow (N, 2, H, W) in network px/ms."""

        def __init__(self):
            super().__init__()
            self.cfg = cfg
            self.specs = layer_specs(cfg)
            convs = {}
            for s in self.specs:
                if s.kind == "convT":
                    convs[s.name] = nn.ConvTranspose2d(s.c_in, s.c_out, s.kernel, s.stride, padding=1, bias=False)
                else:
                    convs[s.name] = nn.Conv2d(s.c_in, s.c_out, s.kernel, s.stride, padding=s.kernel // 2,
                                              bias=s.name == "flow")
            self.convs = nn.ModuleDict(convs)
            with torch.no_grad():       # N(0, gain^2 / fan_in): sparse spikes still reach the deep layers
                for s in self.specs:
                    fan = s.c_in * s.kernel ** 2 / (s.stride ** 2 if s.kind == "convT" else 1)
                    self.convs[s.name].weight.normal_(0.0, cfg.init_gain / math.sqrt(fan))
            n_lif = sum(1 for s in self.specs if s.neurons)
            self.leak = nn.Parameter(torch.full((n_lif,), float(cfg.leak_init)))
            self.vth = nn.Parameter(torch.full((n_lif,), float(cfg.vth_init)))
            self.lif_index = {s.name: i for i, s in enumerate(s for s in self.specs if s.neurons)}

        def neuron_params(self, name):
            i = self.lif_index[name]
            return self.vth[i].clamp(min=0.05), self.leak[i].clamp(0.0, 1.0)

        def forward(self, x, record=None):
            """x (N, B, C, H, W) counts; H, W multiples of cfg.multiple. ``record``: a dict that
            receives per layer name the list over steps of its input (spikes or counts)."""
            n, b = x.shape[:2]
            state = {}

            def lif(name, current):
                vth, leak = self.neuron_params(name)
                u, o = state.get(name, (torch.zeros_like(current), torch.zeros_like(current)))
                u, o = lif_step(u, o, current, vth, leak)
                state[name] = (u, o)
                return o

            def syn(name, inp):
                if record is not None:
                    record.setdefault(name, []).append(inp.detach())
                return self.convs[name](inp)

            acc = 0.0
            for t in range(b):
                h = x[:, t]
                skips = []
                for k in range(1, len(self.cfg.enc_channels) + 1):
                    h = lif(f"enc{k}", syn(f"enc{k}", h))
                    skips.append(h)
                for j in range(1, self.cfg.n_res + 1):
                    a = lif(f"res{j}a", syn(f"res{j}a", h))
                    h = lif(f"res{j}b", syn(f"res{j}b", a) + h)
                for k in range(1, len(self.cfg.dec_channels) + 1):
                    h = lif(f"dec{k}", syn(f"dec{k}", torch.cat([h, skips[-k]], dim=1)))
                acc = acc + syn("flow", h)
            return acc / b

    return AdaptiveSpikeNet()


def build_model(cfg: ASNetConfig = ASNetConfig()):
    """A freshly initialised torch model (random weights)."""
    return _torch_model(cfg)


def n_params(cfg: ASNetConfig) -> int:
    """Weights + biases + the per-layer leak and threshold."""
    w = sum(s.c_in * s.c_out * s.kernel ** 2 for s in layer_specs(cfg))
    n_lif = sum(1 for s in layer_specs(cfg) if s.neurons)
    return int(w + 2 + 2 * n_lif)


# ---------------------------------------------------------------------------------- input
def network_input(binned: np.ndarray, cfg: ASNetConfig) -> np.ndarray:
    """(B, 2, H, W) counts -> (B, 2, H', W') float32: summed over d x d blocks (d = downsample)
    and zero-padded at the bottom/right to multiples of cfg.multiple."""
    b = np.asarray(binned)
    if b.ndim != 4 or b.shape[1] != 2:
        raise ValueError(f"binned window must be (B, 2, H, W), got {b.shape}")
    d = int(cfg.downsample)
    nb, c, h, w = b.shape
    hd, wd = -(-h // d), -(-w // d)
    m = cfg.multiple
    hp, wp = -(-hd // m) * m, -(-wd // m) * m
    out = np.zeros((nb, c, hp * d, wp * d), np.float32)
    out[:, :, :h, :w] = b
    if d > 1:
        out = out.reshape(nb, c, hp, d, wp, d).sum(axis=(3, 5))
    return out


def sensor_flow(flow_net: np.ndarray, cfg: ASNetConfig, sensor_size: tuple[int, int]) -> np.ndarray:
    """Network flow (2, H', W') in network px/ms -> (2, H, W) sensor px/ms (nearest upsampling)."""
    d = int(cfg.downsample)
    w, h = int(sensor_size[0]), int(sensor_size[1])
    f = np.asarray(flow_net, np.float32)
    if d > 1:
        f = np.repeat(np.repeat(f, d, axis=1), d, axis=2)
    return f[:, :h, :w] * np.float32(d)


# ------------------------------------------------------------------------- flow -> objects
@dataclass(frozen=True)
class FlowObject:
    """One object read from the flow: centroid (sensor px), mean flow (px/ms), its pixels."""

    x: float
    y: float
    u: float
    v: float
    n_pixels: int

    @property
    def speed_px_ms(self) -> float:
        return float(math.hypot(self.u, self.v))

    @property
    def direction_rad(self) -> float:
        return float(math.atan2(self.v, self.u))


def flow_objects(flow: np.ndarray, event_mask: np.ndarray, config: ToffeConfig,
                 min_flow_px_ms: float = 0.1) -> list[FlowObject]:
    """Objects of a sensor-resolution flow (2, H, W) at the event pixels (H, W) (module doc)."""
    from ..ofpd_io import blobs_xy, ofpd_settings

    ys, xs = np.nonzero(event_mask)
    u, v = flow[0, ys, xs], flow[1, ys, xs]
    moving = np.hypot(u, v) > min_flow_px_ms
    xs, ys, u, v = xs[moving], ys[moving], u[moving], v[moving]
    if xs.size == 0:
        return []
    group, count, _bbox, _closed = blobs_xy(xs, ys, int(event_mask.shape[1]), config)
    need = int(ofpd_settings(config)["min_events"])
    out = []
    for g in np.flatnonzero(count >= need):
        sel = group == g
        out.append(FlowObject(float(xs[sel].mean()), float(ys[sel].mean()), float(u[sel].mean()),
                              float(v[sel].mean()), int(sel.sum())))
    return out


def to_predictions(objs: list[FlowObject], config: ToffeConfig) -> list:
    """FlowObjects as metrics.Prediction rows (bin from the speed, as TOFFE's bins)."""
    from ..metrics import Prediction

    sc = config.speed_scale
    n = len(config.speed_bins)
    out = []
    for o in objs:
        k = min(max(config.speed_bin_of_px_ms(o.speed_px_ms), 1), n)
        out.append(Prediction(k, o.x, o.y, o.direction_rad, float(sc.to_mps(o.speed_px_ms)),
                              float(config.representative_speeds[k - 1]), o.speed_px_ms))
    return out


# ------------------------------------------------------------------------------ op counts
def _ones_conv(inp, spec: LayerSpec):
    """Per output position: the number of non-zero inputs (all channels) in its receptive field
    (torch tensors (1, C, H, W) -> (H_out, W_out))."""
    import torch
    import torch.nn.functional as F

    nz = (inp != 0).to(torch.float32).sum(dim=1, keepdim=True)
    ones = torch.ones((1, 1, spec.kernel, spec.kernel))
    if spec.kind == "convT":
        return F.conv_transpose2d(nz, ones, stride=spec.stride, padding=1)[0, 0]
    return F.conv2d(nz, ones, stride=spec.stride, padding=spec.kernel // 2)[0, 0]


def count_ops(model, x_net: np.ndarray) -> tuple[np.ndarray, dict]:
    """Run one window (B, 2, H', W') through ``model`` recording every layer's input, and count
    its operations (module doc). Returns (flow (2, H', W') network px/ms, counts dict with per
    layer: neurons, dense_macs, event_ops (accumulates; MACs for the graded first layer),
    active_updates, inputs_nonzero, input_rate, and totals)."""
    import torch

    specs = layer_specs(model.cfg)
    rec: dict = {}
    with torch.no_grad():
        flow = model(torch.from_numpy(np.ascontiguousarray(x_net))[None], record=rec)[0].numpy()
    layers = []
    tot = dict(dense_macs=0.0, event_acs=0.0, event_macs=0.0, neurons=0, dense_updates=0.0,
               active_updates=0.0, spikes=0.0, weight_bytes=0.0, state_bytes_dense=0.0,
               state_bytes_event=0.0, spike_bytes=0.0)
    steps = int(x_net.shape[0])
    for s in specs:
        ins = rec[s.name]
        h_in, w_in = ins[0].shape[-2:]
        if s.kind == "convT":
            h_out, w_out = h_in * s.stride, w_in * s.stride
            dense = h_in * w_in * s.c_in * s.c_out * s.kernel ** 2
        else:
            h_out, w_out = -(-h_in // s.stride), -(-w_in // s.stride)
            dense = h_out * w_out * s.c_in * s.c_out * s.kernel ** 2
        neurons = h_out * w_out * s.c_out if s.neurons else 0
        ev, nz, active = 0.0, 0.0, 0.0
        for t, inp in enumerate(ins):
            rf = _ones_conv(inp, s)
            ev += float(rf.sum()) * s.c_out
            nz += float((inp != 0).sum())
            if s.neurons:           # neurons with input this step (module doc: a lower bound)
                active += float((rf > 0).sum()) * s.c_out
        in_elems = h_in * w_in * s.c_in * steps
        row = {"name": s.name, "kind": s.kind, "c_in": s.c_in, "c_out": s.c_out, "kernel": s.kernel,
               "stride": s.stride, "in_hw": [int(h_in), int(w_in)], "out_hw": [int(h_out), int(w_out)],
               "neurons": int(neurons), "dense_macs": float(dense * steps), "event_ops": ev,
               "event_op_kind": "mac" if not s.spiking_input else "ac", "inputs_nonzero": nz,
               "input_rate": nz / in_elems if in_elems else 0.0, "active_updates": active,
               "weights": int(s.c_in * s.c_out * s.kernel ** 2)}
        layers.append(row)
        tot["dense_macs"] += row["dense_macs"]
        tot["event_acs" if s.spiking_input else "event_macs"] += ev
        tot["neurons"] += int(neurons)
        tot["dense_updates"] += float(neurons * steps)
        tot["active_updates"] += active
        tot["weight_bytes"] += 4.0 * row["weights"] * steps
        tot["state_bytes_dense"] += 8.0 * neurons * steps
        tot["state_bytes_event"] += 8.0 * active
        tot["spike_bytes"] += 2.0 * nz if s.spiking_input else 0.0
    tot["spikes"] = sum(r["inputs_nonzero"] for r, s in zip(layers, specs) if s.spiking_input)
    return flow, {"layers": layers, "totals": tot, "steps": steps, "params": n_params(model.cfg)}


def host_ops(counts: dict):
    """The counts under the harness's two host rules: (dense HostOps, event-driven HostOps).

    dense: fp32 MACs of every conv output + dense LIF (cost_model.dense_lif_ops), weights and
    all membrane state through SRAM; event-driven: fp32 adds per spike fan-out (the weights are
    float: an accumulate is one fp32 add), fp32 MACs for the graded first layer, LIF only on
    updated neurons, state and spikes of those only."""
    from ..energy.cost_model import HostOps, dense_lif_ops

    t = counts["totals"]
    dense = HostOps(mac_fp32=t["dense_macs"], sram_bytes=t["weight_bytes"] + t["state_bytes_dense"])
    dense = dense + dense_lif_ops(int(t["dense_updates"]), 1)
    event = HostOps(add_fp32=t["event_acs"], mac_fp32=t["event_macs"],
                    sram_bytes=t["weight_bytes"] + 8.0 * (t["event_acs"] + t["event_macs"]) / 2.0
                    + t["spike_bytes"])
    event = event + HostOps(mac_fp32=t["active_updates"], add_fp32=2 * t["active_updates"],
                            sram_bytes=t["state_bytes_event"])
    return dense, event


# ------------------------------------------------------------------------------ baseline
class AdaptiveSpikeNetBaseline:
    """The trained baseline: ``detect(events, t0)`` -> metrics.Prediction list for one window,
    ``flow(binned)`` -> sensor flow, ``op_counts(binned)`` -> count_ops dict + host rules.
    ``runner``: "torch" (eager, the reference) or "onnx" (ONNX Runtime, ``optimised()``).

    ``config``: the TOFFE config whose sensor, bins, dt and grouping settings it shares."""

    def __init__(self, model, cfg: ASNetConfig, config: ToffeConfig, runner: str = "torch", threads: int = 1):
        if runner not in ("torch", "onnx"):
            raise ValueError(f"runner must be torch or onnx, got {runner!r}")
        self.model = model.eval()
        self.cfg = cfg
        self.config = config
        self.runner = runner
        self.threads = int(threads)
        self._sessions: dict = {}

    def optimised(self, threads: int = 1) -> "AdaptiveSpikeNetBaseline":
        """The same network run by ONNX Runtime (``onnx_session``): the optimised level."""
        return AdaptiveSpikeNetBaseline(self.model, self.cfg, self.config, "onnx", threads)

    @classmethod
    def load(cls, path: str | Path, config: ToffeConfig) -> "AdaptiveSpikeNetBaseline":
        """From a directory with config.json + weights.safetensors (safetensors: no pickle)."""
        import torch
        from safetensors.torch import load_file

        root = Path(path)
        cfg_path, w_path = root / CONFIG_FILE, root / WEIGHTS_FILE
        for p in (cfg_path, w_path):
            if not p.is_file():
                raise InputError(p, "missing file (train it with benchmarks/train_asnet.py)")
        try:
            meta = json.loads(cfg_path.read_text(encoding="utf-8"))
        except (OSError, *JSON_ERRORS) as exc:
            raise InputError(cfg_path, f"not readable JSON ({exc})") from None
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise InputError(cfg_path, f"not a {FORMAT} config")
        cfg = ASNetConfig.from_dict(meta.get("model", {}))
        model = build_model(cfg)
        try:
            state = load_file(str(w_path))
            model.load_state_dict(state)
        except Exception as exc:   # a truncated file or other shapes: say which file
            raise InputError(w_path, f"cannot load weights ({str(exc).splitlines()[0]})") from None
        return cls(model, cfg, config)

    def net_flow(self, binned: np.ndarray) -> np.ndarray:
        """(2, H', W') network flow of a binned (B, 2, H, W) window."""
        import torch

        x = network_input(binned, self.cfg)[None]
        if self.runner == "onnx":
            sess = self._sessions.get(x.shape)
            if sess is None:
                sess = self._sessions[x.shape] = onnx_session(self.model, x.shape, self.threads)
            return sess.run(None, {"x": x})[0][0]
        with torch.no_grad():
            return self.model(torch.from_numpy(x))[0].numpy()

    def flow(self, binned: np.ndarray) -> np.ndarray:
        """(2, H, W) sensor flow, px/ms."""
        return sensor_flow(self.net_flow(binned), self.cfg, self.config.sensor_size)

    def detect_binned(self, binned: np.ndarray) -> list:
        """Object flow (metrics.Prediction) of a binned window."""
        mask = np.asarray(binned).any(axis=(0, 1))
        objs = flow_objects(self.flow(binned), mask, self.config, self.cfg.min_flow_px_ms)
        return to_predictions(objs, self.config)

    def detect(self, events: np.ndarray, t0: int) -> list:
        """Object flow of the window [t0, t0 + dt) of an event array (the timed inference)."""
        from ..events.binning import bin_window

        c = self.config
        return self.detect_binned(bin_window(events, int(t0), c.dt_us, c.n_bins, tuple(c.sensor_size),
                                             dtype=np.uint8))

    def op_counts(self, binned: np.ndarray) -> dict:
        """count_ops of one window plus its ``host_dense`` / ``host_event`` HostOps dicts."""
        _flow, counts = count_ops(self.model, network_input(binned, self.cfg))
        dense, event = host_ops(counts)
        counts["host_dense"] = dense.to_dict()
        counts["host_event"] = event.to_dict()
        d = self.cfg.downsample
        counts["network_input_wh"] = [int(-(-binned.shape[3] // d)), int(-(-binned.shape[2] // d))]
        return counts


def onnx_session(model, x_shape: tuple[int, ...], threads: int = 1):
    """An ONNX Runtime CPU session of ``model`` for inputs of x_shape (N, B, 2, H', W'): the B
    steps unrolled into one static graph (exported in memory, no file), fp32, ``threads`` intra-op
    threads. Same arithmetic as torch (tested within 1e-4)."""
    import io
    import warnings

    import onnxruntime as ort
    import torch

    buf = io.BytesIO()
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")             # tracer notes on the Python loop over steps
        torch.onnx.export(model, (torch.zeros(x_shape),), buf, input_names=["x"], output_names=["flow"],
                          opset_version=17)
    so = ort.SessionOptions()
    so.intra_op_num_threads = int(threads)
    so.inter_op_num_threads = 1
    return ort.InferenceSession(buf.getvalue(), so, providers=["CPUExecutionProvider"])


def save_baseline(path: str | Path, model, cfg: ASNetConfig, extra: dict | None = None) -> None:
    """Write config.json + weights.safetensors atomically into directory ``path``."""
    from safetensors.torch import save_file

    from ..fileio import atomic_path

    root = Path(path)
    root.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().contiguous().clone() for k, v in model.state_dict().items()}
    with atomic_path(root / WEIGHTS_FILE, suffix=".safetensors") as tmp:
        save_file(state, str(tmp))
    meta = {"format": FORMAT, "version": 1, "model": cfg.to_dict(), "params": n_params(cfg), **(extra or {})}
    with atomic_path(root / CONFIG_FILE, suffix=".json") as tmp:
        tmp.write_text(json.dumps(meta, indent=1) + "\n", encoding="utf-8")
