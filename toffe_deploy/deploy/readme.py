"""The bundle's README.md: written into every bundle so the documentation travels with it.

The repository's export/README.md is this text (the exporter replaces export/ as a whole, so
the file there is always the one generated here).
"""
from __future__ import annotations

README_TITLE = "# toffe-deploy bundle"

_README = README_TITLE + """ (`toffe-deploy export CKPT -o DIR`)

A deploy bundle is what `toffe-deploy export` makes from a trained checkpoint and what
`toffe-deploy run` executes: the OFS spiking cascade quantized to Loihi 2 fixed point (run as
Lava processes, or bit-exactly by the numpy `cpu` target) and the OFPD CNN as ONNX (for
onnxruntime on the host or an edge GPU). `run` verifies every file against the sha256 in
`manifest.json` and refuses a bundle that was modified. The export is atomic: a failed export
leaves no bundle behind, and an existing directory is replaced only when it is a bundle (or
empty, or holds only this README), otherwise only with `--force`.

## File tree

```
export/
  manifest.json        versions, config summary, camera, quantization report, parity summary, sha256 of every file
  config.json          the checkpoint's ToffeConfig, unchanged
  ofs_loihi.json       quantized OFS, one entry per speed bin (the form lava_procs builds processes from)
  ofpd.onnx            OFPD, fp32, ONNX opset 17, dynamic batch
  ofpd_fp16.onnx       optional (--variants fp16): weights and activations in float16, fp32 I/O
  ofpd_int8.onnx       optional (--variants int8): static int8 QDQ (per-channel weights, activations calibrated on real OFPD inputs, heads fp32)
  ofs.nir              the OFS stages as a NIR graph (nir.read loads it)
  netx/ofs_stage<k>.net  lava-dl netx HDF5, one network per stage (conv + CUBA neuron)
  parity.json          the five parity checks of this export, with their goals (not written with --checks none)
  README.md            this file
```

## The OFS arithmetic (what every integer below means)

Stage k (speed bin k, k = 1..N) is one conv layer (C_in = 2 polarity channels -> 1, K x K,
zero padding K//2, stride 1, no bias) into one population of LIF neurons. Per time step t of a
window (B steps, one per time bin; state zero at the window start; input s_in = 1 where the
bin holds at least one event of that polarity), with the bundle's `reset` (config.json,
ofs_loihi.json `reset_mode`):

```
a_in[t] = sum_{c,i,j} w[c,i,j] * s_in[t, c, y+i-K//2, x+j-K//2]
subtract: v[t] = clip24( trunc0(v[t-1] * (4096 - dv) / 4096) + (a_in[t] << 6) - (vth_mant << 6) * o[t-1] )
zero:     v[t] = clip24( trunc0((o[t-1] ? 0 : v[t-1]) * (4096 - dv) / 4096) + (a_in[t] << 6) )
o[t]    = v[t] > (vth_mant << 6)
```

trunc0 truncates toward zero, clip24 saturates at +-(2^23 - 1). `subtract` is the paper's eq.
(1)-(2) with reset by subtraction of vth * o[t-1], undecayed, at step t; it runs only in our own
Lava process model (`lava_procs`, a Python model: on a Loihi system it runs on the host).
`zero` is Loihi 2's stock CUBA LIF (`lava.proc.lif` LIF / LIFReset, bit-accurate model
`PyLifResetModelBitAcc`: v = 0 after a spike), what NeuroCores, netx and NIR run; a `zero` bundle
builds each stage from stock `lava.proc.conv.Conv` + `lava.proc.lif.LIFReset` (reset_interval =
B). Float units: W = w / weight_scale, vth = vth_mant / weight_scale, lambda = 1 - dv / 4096.
The current is memoryless (du = 4095). The cascade (eq. 3-4) runs stage N first; each stage's spikes, OR-ed
over the window, are closed with a `mask_kernel` square and inverted to mask the next
(slower) stage's input. With `ofs_pool` p > 1 (config.json) the stages run on the OFS grid, the
sensor OR-pooled over p x p pixel blocks (ceil(W / p) x ceil(H / p) neurons per stage; the netx
and NIR files have that shape); the host pools each window before it goes to the chip, and a
closed mask cell covers its p x p sensor pixels, so OFPD still sees every event.

## The host front end (config.json)

Before the OFS, on the host and on every target, each window's binary volume goes through the
input front end that the checkpoint was trained with (`toffe_deploy/events/frontend.py`,
`events/support.py`): `input_norm` (`"none"`: every spike; `"first"`: each pixel and polarity's
first spike of the window), then `input_min_cluster` n (drop the pixels whose 8-connected
cluster of the window's event pixels has fewer than n pixels; 1 keeps all), then, when
config.json has `input_support` [K, r, m, c] (absent: off), keep a pixel that the cluster filter
dropped if the window and the K windows before it fired S >= T pixels in its (2r + 1)^2 box
(S counts each pixel once per window), T = m + floor(c (2r + 1)^2 E / (H W)), E the event pixels
of those K + 1 windows. A reader streaming windows in time order keeps the K windows before (windows
missing from the stream count as empty; a jump back, or by a time that is no multiple of dt,
forgets them); one that starts at a chosen time reads [t0 - K dt, t0) first.

## ofs_loihi.json

| field | meaning |
|---|---|
| `format`, `format_version` | `"toffe-ofs-loihi"`, 1 |
| `weight_layout` | `(1, C_in, K, K)`, cross-correlation (torch Conv2d layout) |
| `state_shift` | 6: a_in and vth are shifted left by 6 bits into the 24-bit state (any other value is refused) |
| `reset_mode` | `"subtract"` or `"zero"` (above); absent in files written before it: subtract. Must equal config.json's `reset` |
| `reset`, `input` | the reset rule and input encoding above, in words |
| `stages[k-1].stage` | k (1 = slowest speed bin) |
| `stages[k-1].weight` | int weights in [-127, 127], nested lists (1, C_in, K, K) |
| `stages[k-1].vth_mant` | threshold mantissa, 1 .. 2^17 - 1 |
| `stages[k-1].dv` | voltage decay, 0 .. 4095 (lambda = 1 - dv / 4096) |
| `stages[k-1].du` | current decay, 4095 (memoryless input current; the only value the runtimes implement, others are refused) |
| `stages[k-1].weight_scale` | s: float weight = weight / s, float threshold = vth_mant / s |
| `stages[k-1].notes` | every clamp the quantizer applied (empty when none) |
| `stages[k-1].float` | the checkpoint's float threshold and leak, for reference |

The weight scale maps the largest |w| of the stage to 127 (full 8-bit range); the threshold
is expressed in the same scale; a threshold whose mantissa would need more than 17 bits
lowers the scale (a note says so).

## ofpd.onnx (and variants)

Input `events`: (N, C, h, w) float32 with dynamic N, made by `toffe_deploy.ofpd_io.prepare`
from N objects' speed-separated frames: C = 2B pooled event planes (B time bins x 2 polarities)
+ the motion planes + 2 coordinate planes, h = w = g = `crop_px / pool` cells (32 by default).
Event plane 2b + p (time bin b, polarity p: 0 OFF, 1 ON) holds, per cell, the fraction of its
P x P pixels that have a front-end event in that bin and polarity (the mean of crop[b, p] > 0).
The crop is the S x S block whose centre x0 + (S - 1) / 2, y0 + (S - 1) / 2 lies nearest the
two-pass centroid of the object's event pixels (their mean, then the mean of those within S / 2
of it), zero outside the sensor (`ofpd_io.crop_origin_xy` and `ofpd_io.prepare_xy`, with the
module doc of `toffe_deploy/ofpd_io.py`, are the reference implementation).
Each object's crop is S x S px with cells of P = S / g px; with `config.ofpd.crop = "scaled"`
(OFPDs trained since the layout keys exist) S = g * clip(2^ceil(log2(1.5 * extent / g)),
pool_min, pool_max), 64..512 px by default, with `"fixed"` S = `crop_px`. The motion planes
(`config.ofpd.motion = "time_cov"`: planes 2B and 2B + 1; none for `"none"`, older OFPDs) hold
per cell 12 n cov(t, u) / P^2 and 12 n cov(t, v) / P^2 over its n event ones (the cell's ones in
every event plane), t the time bin scaled to
-1/2..1/2 and (u, v) the position inside the cell in cells: which way time runs in the cell,
the direction of motion whatever the contrast sign. The last two planes hold the cell centres'
x, then y, in sensor px / 1000: the graph reads the crop centre (their mean) and P (their
spacing) from them. Outputs `pose` (N, 2) px on the full sensor (crop centre + a residual of
up to g P / 2), `direction` (N, 2) (cos, sin) of the image-plane motion angle (y down), `speed`
(N, 1) ln of the image-plane speed in px/ms (`config.ofpd.speed_unit = "px_ms"`: the head
regresses ln(cells/ms) and the graph adds ln P), or ln(m/s) for `"mps"` (older checkpoints);
decode with `toffe_deploy.ofpd_io.decode`. It gives both m/s and px/ms through the config's
camera, and the reported speed bin: `config.ofpd.bin_from = "ofpd"`, the bin of this speed
(the speed clipped only to the bins' overall range), or `"ofs"` (older checkpoints), the
cascade's stage, the speed clipped into it. With `config.ofpd.plane_fit_weight` w > 0 the
speed of an object whose OFPD speed exceeds `plane_fit_min_px_ms` is blended, before that
decoding, with the velocity of planes fitted to the time surface of its ones (ln s = w ln
|v_plane| + (1 - w) ln s_OFPD; `toffe_deploy.plane_fit`, numpy/numba on the host, from the same
ones the crop is cut from; absent or 0: the OFPD's speed alone); `plane_fit_dir_weight` blends
the direction the same way, and with `plane_fit_history` [D, K_max, margin] the time surface is
the object's box (grown by margin px) over its last K = min(K_max, ceil(D / (s dt))) windows of
the front end's ones (`toffe_deploy.time_surface`: the host keeps the last K_max windows; an
object wanting more windows than the stream has seen keeps the OFPD's speed); with
`plane_fit_refits` n (0-4, absent 0), K is worked out again n times from the fit's own speed
and the surface fitted again where K changed. With `outline_centre` [D, k_min, reach, closed_frac]
(needs `plane_fit_history`), an object whose decoded speed asks for K = ceil(D / (s dt)) >=
k_min windows, all held, and whose own pixels do not lie all round their centroid (each
quadrant >= closed_frac of them), is placed at the mean-shift centre of the pixels its last K
windows fired within reach x its extent, plus s dt (K - 1) / 2 along its direction (the
outline's lag; `toffe_deploy.outline_centre`); absent: the OFPD's position. Which events form one object is
`config.ofpd.grouping`: `"blobs"` (connected event blobs of any size, an object's edges joined
until they surround it; keys `link_px`, `merge_frac`, `edge_merge_frac`, `min_events`; with
`split_frac` > 0, `"union"` only, a blob whose two halves are each a closed outline meeting
the other in a narrow waist, at most `split_waist` of the narrower one's width, is two objects,
and with `split_polarity` f > 0 so is a blob whose halves each hold a leading and a trailing edge
instead (>= f of a half's pixels fired one polarity only, >= f the other, apart; extents alike);
with `closed_apart` true, `"union"` only, two blobs that each surround their centroid and hold
`min_events` pixels stay two objects however close;
with `recent_events` [r, m, c], `"union"` and `input_support` only, a blob short of `min_events`
is an object when the latest K windows' event pixels in its box grown by r px reach
m + floor(c A E / (H W)) and it lies apart from every object; with `faint_objects` [L, z]
(`input_support` only) a slow object no stage reported is found where the event pixels of the
last L windows, each pixel counted at most 3 times, stand z noise standard deviations above the
sensor's density in a 32 px box, and now too, apart from the objects reported and from the
outer half of the extent disc of a big object (ones' box diagonal >= 32 px) reported in the 4
windows before (such an object's edges are regions of their own): it is reported with
`"faint": true`, bin 1 and its representative speed, its direction a rough guess;
`toffe_deploy.faint_objects`) or
`"boxes"` (a fixed +-`dedupe_px` box, older checkpoints); with blobs, `config.ofpd.stages`
says how the stage frames meet: `"union"`, the blobs of all stages' pixels together (an
object's edges that the cascade gave to several stages are one outline; its stage is the
fastest holding `min_events` of its pixels), or `"join"` (older checkpoints), each stage's
blobs apart, a slower stage's joining the objects reported so far. config.json's `ofpd` keys are listed
in `toffe_deploy/ofpd_io.py` (OFPD_DEFAULTS; each layout key a non-empty `ofpd` lacks takes its
legacy value: boxes / fixed / mps / no motion planes / bin from the OFS / join). Checked with `onnx.checker` (full check) at export.

## netx/ofs_stage<k>.net (lava-dl netx HDF5)

`layer/0`: `type = input`, `shape = (C_in, H, W)`; `layer/1`: `type = conv`, `shape = (1, H, W)`,
`inChannels`, `outChannels = 1`, `kernelSize`, `stride = 1`, `padding = K//2`, `dilation = 1`,
`groups = 1`, `weight` (1, C_in, K, K) float32 holding whole numbers (the same integers as ofs_loihi.json; netx reads float weights) and
`neuron/{type = CUBA, iDecay = 4096, vDecay = dv, vThMant = vth_mant, refDelay = 1, gradedSpike = false}`;
`simulation/{Ts = 1, tSample = B}`; file attributes `reset_note`, `reset_interval`, `reset_offset`.
netx's stock CUBA neuron resets to zero after a spike. For a **`reset: zero` bundle the files
reproduce the bundle bit for bit** when loaded with the periodic reset the manifest states
(`netx.reset_interval` = B, `netx.reset_offset` = 1) and fed bin b of window i at Lava step
i * B + b + 1 (steps count from 1: with a `lava.proc.io.source.RingBuffer` that is column i * B + b of
its data, which it sends one column a step from step 1), and the spikes of that bin come out one step later:

```python
from lava.lib.dl.netx.hdf5 import Network
net = Network(net_config="export/netx/ofs_stage4.net", reset_interval=5, reset_offset=1)
# connect a source of (W, H, 2) spikes to net.inp and net.out (W, H, 1) to a sink; run on
# Loihi2SimCfg(select_tag="fixed_pt") (or Loihi2HwCfg): toffe_deploy.deploy.netx_h5.run_netx_stage does this
```

Measured by the parity check `netx_vs_fixed` (lava-dl's own Network on Loihi2SimCfg fixed_pt):
0 differing spikes on every stage; reset_offset 2 gives wrong spikes. **A `reset: subtract`
bundle's files do not reproduce it** (netx cannot subtract; `netx.reproduces_bundle` is false,
the check reports the spike F1 for information). Stages are separate files because the
cascade's masking between them (closing, inversion) is not a netx layer: it runs on the host.

## ofs.nir (Neuromorphic Intermediate Representation)

One graph: `input` (C_in, H, W) feeds, for every stage k, `stage<k>_conv` (nir.Conv2d,
padding K//2) -> `stage<k>_lif` (nir.LIF) -> `stage<k>_output`, in the float values the
integers represent. NIR's LIF is continuous time, tau dv/dt = (v_leak - v) + r I with tau in
seconds; readers integrate it with one forward-Euler step per time bin of dt = dt_us / B
(metadata `time_step_s`, 1e-4 s for the shipped config; snnTorch's importer assumes 1e-4 s, so
it reads only bundles with dt_us / B = 100 us right; give Norse `dt=time_step_s`). It is written as tau = dt / (1 - lambda), r = 1, v_leak = 0,
v_reset = 0 and conv weights W / (1 - lambda) (the gain tau / dt folded in, since readers
differ on r), so v[t] = lambda v[t-1] + conv(W, s[t]); v_threshold is vth plus half a Loihi
state unit (1 / (128 s)), which decides ties the way the integers do. Run one window (B steps)
at a time from rest. NIR's LIF resets to v_reset in the step it fires: **a `reset: zero`
bundle's graph reproduces it** (metadata `reproduces_bundle`; checked in snnTorch 1.0 and
Norse 1.1 by `benchmarks/nir_check.py`) up to the decay's truncation: Loihi truncates the
decayed potential toward zero to whole state units every step (trunc0(v (4096 - dv) / 4096)),
which NIR's exact v * lambda cannot express, so the graph's membrane can sit up to about a unit
per step above the integers', and a potential that reaches exactly the integer threshold (no
spike: v > vth is strict) fires in the graph (1 spike of 12,045 on the shipped checkpoint's 4
held-out windows; a few in hundreds of thousands on dense random input, the same spikes in
float64 as in float32: not float rounding, checked from outside on 2026-11-30); **NIR cannot express reset
by subtraction**, so a `reset: subtract` bundle's graph says so in `metadata.reset` and its readers run a zero-reset
network instead. `metadata` also holds the integer parameters and the cascade rule (stage N
first, closing with mask_kernel, inversion), which NIR cannot express. Readers that open the
file: snnTorch 1.0 (`snntorch.import_nir.import_from_nir`, one stage per subgraph is practical
at 640x480) and Norse 1.1 (`norse.torch.from_nir(graph, dt=...)`, also one stage per subgraph:
given the whole four-branch graph it loads without complaint but returns a single output
tensor, one stage's, not four; `benchmarks/nir_check.py` shows the subgraph import); sinabs and
Rockpool pin nir <= 1.0.4, which cannot read `v_reset`.

## parity.json

Top level: `format`, `format_version`, `windows` (where the held-out windows came from: data set
or generator, seed, sizes), `all_pass`, and `checks`, holding one entry per check:

| `checks` key | check | goal |
|---|---|---|
| `fixed_vs_float` | numpy fixed-point OFS vs float torch OFS, per stage on the full binary windows: spike agreement, precision, recall, F1 (float = reference); `quantization_band` (bound on the float-vs-integer potential difference), `differing_in_band` (differences at pixels whose float potential came that close to the threshold, i.e. explained by 8-bit weights / 17-bit threshold) and `f1_outside_band` | F1 >= 0.99 |
| `lava_vs_fixed` | Lava simulator (Loihi2SimCfg, fixed_pt; `reset: zero`: stock Conv + LIFReset, else lava_procs) vs numpy fixed point, per stage on small crops (48x32) placed where the reference fires most: differing spikes, spikes compared | 0 |
| `netx_vs_fixed` | each `netx/ofs_stage<k>.net` (layer shapes set to the crop, same integers) in lava-dl's own `netx.hdf5.Network` with `reset_interval` B, `reset_offset` 1 vs numpy fixed point on the same crops: differing spikes, F1 | 0 for `reset: zero`; `informational` for subtract |
| `onnx_vs_torch` | onnxruntime vs torch OFPD: max abs difference of pose, direction, speed (and per variant) | < 1e-4 |
| `end_to_end` | deployed pipeline (the runtime's cpu target: fixed point + onnxruntime) vs float pipeline (torch OFS + torch OFPD), both scored against ground truth with `toffe_deploy.metrics`: pixE, dirE, speedE, relative differences; `agreement` compares the two pipelines' objects directly; `variants`: the same deployed pipeline with each OFPD variant, errors and relative difference to fp32 (informational, 10 % is the bar to be worth shipping) | within 2 % |

Each check has `status` (`pass`, `fail`, `informational` or `skipped: reason`), its measured
figures and its `goal`. A check that cannot run says why instead of passing silently;
`all_pass` counts `informational` as passed.

## manifest.json

| field | meaning |
|---|---|
| `format`, `format_version` | `"toffe-deploy-bundle"`, 1 |
| `created_utc`, `tool` | when and by which toffe-deploy version |
| `dependencies` | versions of numpy, opencv, onnx, onnxruntime, torch, lava-nc, lava-dl, nir, h5py, safetensors |
| `source` | the checkpoint path and the sha256 of its files |
| `config_summary` | sensor_size, n_bins (B), dt_us, speed bins (m/s and px/ms), representative speeds, focal_px, depth_m, kernels |
| `camera` | the camera the bundle was trained for and what its speed bins mean (below) |
| `config` | the full ToffeConfig (also config.json) |
| `ofs` | per stage vth_mant, dv, du, weight_scale, clamps, and `quantization` errors (max abs / relative weight error, threshold and leak error); `reset`; `loihi2_footprint`: `ofs_pool` and `ofs_grid` (the neurons per stage), neurons, synapses (fan-in, H W C K^2), shared weights and cores per stage (8192 neurons per core, a lower bound), total cores, chips (128 cores each), `fits_one_chip`, `max_pixels_one_chip` (grid area; 640x480 x 4 stages unpooled: 1,228,800 neurons, 152 cores, 2 chips; with `ofs_pool` 2: 307,200 neurons, 40 cores, 1 chip) |
| `ofpd` | opset, input/output names and shapes, `variants` with their files (each must also be listed in `files`), precision, `error_vs_fp32` (pose px, direction deg, speed ratio exp(abs(ln v - ln v_fp32)): max / p95 / mean over the objects of held-out windows not used for calibration), int8 `calibration_inputs`, and `end_to_end` (the parity check's per-variant errors) |
| `netx` | its files, `reset_interval` / `reset_offset` to pass to `netx.hdf5.Network`, `input_timing`, `reproduces_bundle` (true for `reset: zero`) and `reset_note` |
| `nir` | its file, nir version, `time_step_s`, `reproduces_bundle`, `reset_note` |
| `parity` | status and headline figure of each check |
| `warnings` | every clamp and every missed parity goal, also printed at export |
| `files` | `{path: {sha256, bytes}}` for every file of the bundle except manifest.json; paths are relative, stay inside the bundle (no `..`, no absolute path, no symbolic link leading out) and are all verified on load |

## manifest.json `camera`: what the speed bins mean

An event camera sees image-plane motion only, so the OFS stages separate image-plane speeds
(px/ms). The bins are stated in m/s for an object at `depth_m` seen with `focal_px`:

```
v_px_per_ms = v_mps * focal_px / (1000 * depth_m)
```

| field | meaning |
|---|---|
| `sensor_size` | [width, height] px of the training camera (`run` takes any sensor size: the OFS is a convolution, OFPD sees a crop) |
| `focal_px`, `hfov_deg` | its focal length in pixels and horizontal field of view, hfov = 2 atan(W / (2 focal_px)) |
| `depth_m` | the object distance the m/s bins are stated for |
| `speed_bins_px_ms` | bin k as [lo, hi) image-plane speed, px/ms: what stage k separates on any camera |
| `speed_bins_mps` | the same bins in m/s at `depth_m` and `focal_px` |
| `note` | the above in one sentence |

`toffe-deploy run` reports each object's speed in px/s (`speed_px_s`) and in m/s for the run's
camera: `--depth-m` (default `depth_m`) and `--focal-px` / `--hfov-deg` (default `focal_px` when
the recording is as wide as `sensor_size`, else the same field of view over the recording's width).
Bundles exported before this section existed have neither it nor `focal_px` / `depth_m` in
config.json: they load with the reference camera (640 px at 60 deg: 554.26 px; 5 m).
"""


def bundle_readme() -> str:
    """README.md written into every bundle."""
    return _README
