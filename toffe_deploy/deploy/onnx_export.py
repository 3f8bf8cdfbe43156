"""OFPD (torch) -> ONNX opset 17, named I/O, dynamic batch; optional fp16 and int8 variants.

Input ``events`` (N, C, h, w) float32 (ofpd_io.prepare), outputs ``pose`` (N, 2),
``direction`` (N, 2), ``speed`` (N, 1); N is dynamic so the runtime batches all stage frames of
a window into one session run. Every file is checked with onnx.checker (full check, with shape
inference) and opened by onnxruntime before it goes into a bundle.

Variants for the edge GPU: fp16 converts weights and activations to float16 but keeps float32
I/O (so the runtime's prepare/decode are unchanged); int8 is onnxruntime's dynamic
quantization (int8 weights, activations quantized per batch at run time).
"""
from __future__ import annotations

import io
import logging
import os
import warnings
from pathlib import Path

import numpy as np

from ..config import ToffeConfig

OPSET = 17
INPUT_NAME = "events"
OUTPUT_NAMES = ("pose", "direction", "speed")
VARIANTS = ("fp16", "int8")
#: int8 covers the layers that carry the compute (convolutions and fully connected layers); the
#: heads' tail (normalising the direction, adding the crop centre) stays float: quantizing
#: d / sqrt(|d|^2 + 1e-12) rounds the epsilon to 0 and gives 0 / 0 = NaN on small vectors.
INT8_OPS = ("Conv", "Gemm", "MatMul")


def build_ofpd(config: ToffeConfig, state: dict[str, np.ndarray]):
    """The float torch OFPD of a checkpoint, in eval mode (torch imported here, not at module load)."""
    import torch

    from ..model.ofpd import OFPD

    model = OFPD.from_config(config)
    model.load_state_dict({k: torch.from_numpy(np.asarray(v, dtype=np.float32)) for k, v in state.items()})
    return model.eval()


def export_ofpd_onnx(model, config: ToffeConfig, path: str | os.PathLike, opset: int = OPSET) -> Path:
    """Export a torch OFPD to ONNX at ``path`` and run onnx.checker on it."""
    import torch

    from ..ofpd_io import input_shape

    c, h, w = input_shape(config)
    dummy = torch.zeros((2, c, h, w), dtype=torch.float32)
    dyn = {INPUT_NAME: {0: "N"}, **{o: {0: "N"} for o in OUTPUT_NAMES}}
    buf = io.BytesIO()
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")
        torch.onnx.export(model, (dummy,), buf, input_names=[INPUT_NAME], output_names=list(OUTPUT_NAMES),
                          dynamic_axes=dyn, opset_version=opset, do_constant_folding=True)
    path = Path(path)
    path.write_bytes(buf.getvalue())
    check_onnx(path)
    return path


def check_onnx(path: str | os.PathLike) -> None:
    """onnx.checker full check (raises onnx.checker.ValidationError on a bad model)."""
    import onnx

    onnx.checker.check_model(str(path), full_check=True)


def make_fp16(src: str | os.PathLike, dst: str | os.PathLike) -> Path:
    """float16 weights and activations, float32 inputs/outputs (Cast nodes at the edges)."""
    import onnx
    from onnxruntime.transformers.float16 import convert_float_to_float16

    model = convert_float_to_float16(onnx.load(str(src)), keep_io_types=True)
    _toposort(model.graph)      # the converter appends its input Casts after their consumers
    onnx.save(model, str(dst))
    check_onnx(dst)
    return Path(dst)


def _toposort(graph) -> None:
    """Reorder graph.node topologically in place (ONNX requires producers before consumers)."""
    known = {i.name for i in graph.input} | {i.name for i in graph.initializer} | {""}
    pending = list(graph.node)
    ordered = []
    while pending:
        ready = [n for n in pending if all(i in known for i in n.input)]
        if not ready:
            raise ValueError("ONNX graph has a cycle or an input nobody produces")
        for n in ready:
            ordered.append(n)
            known.update(n.output)
        pending = [n for n in pending if all(n is not r for r in ready)]
    del graph.node[:]
    graph.node.extend(ordered)


def _head_nodes(path) -> list[str]:
    """Names of the output-head nodes (``pose_head``, ``direction_head``, ``speed_head``) of an OFPD graph."""
    import onnx

    return [n.name for n in onnx.load(str(path)).graph.node if "_head" in n.name]


def make_int8(src: str | os.PathLike, dst: str | os.PathLike, calib: np.ndarray | None = None) -> Path:
    """Static int8 QDQ quantization (per-channel weights) of INT8_OPS, activations calibrated on ``calib``.

    QDQ (QuantizeLinear/DequantizeLinear pairs) is the form TensorRT and onnxruntime's GPU
    providers run in int8; onnxruntime's CPU provider runs it too (so parity is measurable here).
    ``calib`` (n, C, h, w) float32 is a set of real OFPD inputs (the runtime's object crops of
    held-out windows). The three output heads (64 -> 2, 2, 1: under 1 % of the MACs) stay fp32:
    quantized, their int8 outputs cost x1.7 in speed and 6 deg in direction (measured on the
    shipped checkpoint; x1.3 and 2.6 deg with fp32 heads).
    """
    from onnxruntime.quantization import (CalibrationDataReader, QuantFormat, QuantType, quantize_static)

    if calib is None or len(calib) == 0:
        raise ValueError("int8 variant needs calibration inputs (held-out frames with objects)")

    class _Reader(CalibrationDataReader):
        def __init__(self, x):
            self._it = iter([{INPUT_NAME: x[i:i + 1].astype(np.float32)} for i in range(len(x))])

        def get_next(self):
            return next(self._it, None)

    root = logging.getLogger()
    level = root.level
    root.setLevel(logging.ERROR)          # the quantizer logs a pre-processing advice on the root logger
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            quantize_static(str(src), str(dst), _Reader(np.asarray(calib)), quant_format=QuantFormat.QDQ,
                            per_channel=True, activation_type=QuantType.QInt8, weight_type=QuantType.QInt8,
                            op_types_to_quantize=list(INT8_OPS), nodes_to_exclude=_head_nodes(src))
    finally:
        root.setLevel(level)
    check_onnx(dst)
    return Path(dst)


def make_variant(name: str, src: str | os.PathLike, dst: str | os.PathLike, calib: np.ndarray | None = None) -> Path:
    """Write variant ``name`` (fp16 or int8) of the ONNX model ``src`` at ``dst``."""
    if name == "fp16":
        return make_fp16(src, dst)
    if name == "int8":
        return make_int8(src, dst, calib)
    raise ValueError(f"unknown ONNX variant {name!r} (choose from {', '.join(VARIANTS)})")


def ort_session(path: str | os.PathLike, providers: list[str] | None = None):
    """An onnxruntime session on CPU (one intra-op thread: this is a 2-core shared machine)."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    so.inter_op_num_threads = 1
    so.log_severity_level = 3
    return ort.InferenceSession(str(path), sess_options=so, providers=providers or ["CPUExecutionProvider"])


def run_onnx(session, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pose, direction, speed) from an onnxruntime session for input x (N, C, h, w)."""
    out = session.run(list(OUTPUT_NAMES), {INPUT_NAME: np.ascontiguousarray(x, dtype=np.float32)})
    return tuple(np.asarray(o) for o in out)


def onnx_io_info(path: str | os.PathLike) -> dict:
    """Opset, input and output names with their (symbolic) shapes, for the manifest."""
    import onnx

    m = onnx.load(str(path), load_external_data=False)

    def shape(vi):
        return [d.dim_param if d.dim_param else int(d.dim_value) for d in vi.type.tensor_type.shape.dim]

    return {
        "opset": max(int(o.version) for o in m.opset_import if o.domain in ("", "ai.onnx")),
        "inputs": {vi.name: {"shape": shape(vi), "dtype": onnx.helper.tensor_dtype_to_np_dtype(
            vi.type.tensor_type.elem_type).name} for vi in m.graph.input},
        "outputs": {vi.name: {"shape": shape(vi), "dtype": onnx.helper.tensor_dtype_to_np_dtype(
            vi.type.tensor_type.elem_type).name} for vi in m.graph.output},
    }
