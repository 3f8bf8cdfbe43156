"""OFPD in onnxruntime: one session per run, all of a window's stage frames in one batched call.

Execution providers per target: ``cpu`` -> CPUExecutionProvider; ``cuda`` -> TensorRT, then CUDA
(whichever this onnxruntime build offers, CPU kept as the fallback for unsupported nodes). A
missing GPU provider is a one-line ToffeError naming what is missing, never a silent CPU run.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ..errors import InputError, ToffeError

INPUT_NAME = "events"
OUTPUT_NAMES = ("pose", "direction", "speed")
GPU_PROVIDERS = ("TensorrtExecutionProvider", "CUDAExecutionProvider")


def providers_for(target: str, available: list[str] | None = None) -> list[str]:
    """The provider list for a target, or ToffeError when this onnxruntime cannot serve it."""
    import onnxruntime as ort

    available = list(ort.get_available_providers() if available is None else available)
    if target == "cuda":
        gpu = [p for p in GPU_PROVIDERS if p in available]
        if not gpu:
            raise ToffeError(
                "target cuda needs onnxruntime with the CUDAExecutionProvider or TensorrtExecutionProvider "
                f"(this onnxruntime {ort.__version__} offers only {', '.join(available) or 'none'}); "
                "install onnxruntime-gpu with a CUDA runtime, or use --target cpu")
        return gpu + ["CPUExecutionProvider"]
    return ["CPUExecutionProvider"]


class OFPDRunner:
    """An onnxruntime session of the bundle's OFPD: ``run(x (N, C, h, w)) -> (pose, direction, speed)``."""

    def __init__(self, onnx_path: str | os.PathLike, target: str = "cpu", threads: int | None = 1):
        import onnxruntime as ort

        self.path = Path(onnx_path)
        self.providers = providers_for(target)
        opts = ort.SessionOptions()
        opts.log_severity_level = 3
        if threads:
            # One intra-op thread: OFPD is tiny, thread hand-offs cost more than they save here.
            opts.intra_op_num_threads = int(threads)
            opts.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(str(self.path), sess_options=opts, providers=self.providers)
        except Exception as exc:  # onnxruntime raises its own exception types for bad models
            raise InputError(self.path, f"onnxruntime cannot load the OFPD model: {str(exc).splitlines()[0]}") from None
        inputs = [i.name for i in self.session.get_inputs()]
        outputs = [o.name for o in self.session.get_outputs()]
        if inputs != [INPUT_NAME] or set(OUTPUT_NAMES) - set(outputs):
            raise InputError(self.path, f"OFPD model must take input {INPUT_NAME!r} and give {', '.join(OUTPUT_NAMES)}; "
                                        f"it takes {inputs} and gives {outputs}")
        shape = self.session.get_inputs()[0].shape
        self.input_shape = tuple(shape[1:])
        # The CPU provider alone has no provider to fall back from, so its run goes straight to
        # the C++ session: InferenceSession.run's Python checks of the input names (known
        # good, above) and its fallback handling cost ~5 us a window (bench_parts.py "ort").
        self._output_names = list(OUTPUT_NAMES)
        inner = getattr(self.session, "_sess", None)
        self._run = (inner.run if self.providers == ["CPUExecutionProvider"] and hasattr(inner, "run")
                     else self.session.run)

    @property
    def provider(self) -> str:
        """The provider actually used first by the session."""
        return self.session.get_providers()[0]

    def run(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One batched inference over N prepared frames (N may be 0)."""
        x = np.ascontiguousarray(x, dtype=np.float32)
        if x.shape[0] == 0:
            return np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32), np.zeros((0, 1), np.float32)
        pose, direction, speed = self._run(self._output_names, {INPUT_NAME: x}, None)
        # NaN or inf out: a broken model (NaN weights, an overflow), whose objects were written
        # as null positions and speeds with exit 0, against the output schema
        if not (_finite_sum(pose, direction, speed) or
                (np.isfinite(pose).all() and np.isfinite(direction).all() and np.isfinite(speed).all())):
            raise InputError(self.path, "produced non-finite output (NaN or inf): the OFPD model is broken "
                                        "(NaN or huge weights?); re-export the bundle")
        return pose, direction, speed


def _finite_sum(*arrays: np.ndarray) -> bool:
    """True when the float64 sum of every value is finite, which float32 values (|v| < 3.5e38)
    reach only when each is finite; False may also be an overflow of huge finite float64 values,
    so a caller confirms it with np.isfinite. Python's sum over a window's handful of rows: a
    third of the time of np.isfinite(a).all() per array (~4 us each in the pipeline)."""
    total = 0.0
    for a in arrays:
        total += sum(a.ravel().tolist())
    return math.isfinite(total)
