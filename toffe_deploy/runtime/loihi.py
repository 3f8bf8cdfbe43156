"""The OFS cascade on Lava (loihi-sim / loihi2 targets): network, host I/O and runtime hygiene.

Network (lava_procs), for N stages at pipeline depth d_k = N - k:

    host --window--> EventBinSource --x_N--> OFSNeuron_N --o_N--> CascadeBridge_N --x_N-1--> ...
                                       \\------------------------------^    |
                                                                          '--record--> host

Time step t of the network is time bin (t - 1) mod B of window (t - 1) // B - d_k at stage k: the
bridges replay the masked input one window later, so all N stages run concurrently on
successive windows.

Reset "zero" bundles build each stage from stock Lava processes only, what Loihi2HwCfg maps to
NeuroCores (the paper's hybrid: the bridges, i.e. closing, inversion and masking, run on the host):

    EventBinSource --a_out--> Conv_N (lava.proc.conv) --> LIFReset_N (lava.proc.lif) --> CascadeBridge_N --a_out--> Conv_N-1 ...

The Conv delivers one step late, so the LIF sees bin b of a window at the window's step b + 2
(LIFReset zeroes u and v where time_step mod B == STOCK_RESET_OFFSET), and each record reaches
the host one step later (one more pipeline period to flush). The host drives the network one window (B steps, ``RunSteps``) at a time,
which keeps the network paused in the host phase between windows: stopping it is then always
clean. While the network computes window p, the host pulls window p + 1 from its iterator and
the consumer works on the results of earlier windows. After the last window, N - 1 empty
windows flush the pipeline.

Hygiene: the runtime is stopped on success, on error, on Ctrl-C and on SIGTERM, at any stage of
start-up too (what start() built so far is killed and unlinked). Lava's child processes ignore
SIGINT (the host alone handles it) and die with the host, even on SIGKILL; their shared memory
is named after the host and reclaimed by the next start once the host is gone (lava_host).
Ctrl-C, SIGTERM and SIGHUP during a host <-> network exchange are deferred to the end of that
exchange; every window and every wait on the network check that the children and the
shared-memory manager are alive; every wait has a timeout; a runtime that does not stop in time
has its processes killed and its shared memory unlinked.
"""
from __future__ import annotations

import atexit
import contextlib
import queue
import signal
import threading
import time
import weakref
from typing import Any, Iterable, Iterator, Sequence

import numpy as np

from ..cascade import CascadeResult
from ..errors import ToffeError
from ..fixed_point import LoihiOFSParams
from ..signals import redeliver_swallowed
from . import lava_host

TAGS = ("fixed_pt", "floating_pt")
HW_MISSING = "loihi2 target needs lava-loihi (Intel's NRC package), not installed; use --target loihi-sim"
HW_SUBTRACT = ("loihi2 target runs only stock Loihi 2 neurons, which reset to zero: this bundle's OFS resets by "
               "subtraction (reset: subtract); export a checkpoint trained with --reset zero, or use --target loihi-sim")
#: LIFReset's reset_offset in the stock network: the source emits bin 0 at a window's first step
#: (time_step = w * B + 1) and the Conv adds one step, so the LIF's window starts at w * B + 2.
STOCK_RESET_OFFSET = 2


def lava_conv_weight(weight: np.ndarray) -> np.ndarray:
    """Our (1, C, K, K) cross-correlation kernel as lava.proc.conv's (C_out, kW, kH, C_in) true
    convolution kernel: both spatial axes flipped, then x first."""
    return np.ascontiguousarray(np.flip(np.asarray(weight), axis=(2, 3)).transpose(0, 3, 2, 1))


def stock_neuron_kwargs(p: LoihiOFSParams, n_bins: int, tag: str = "fixed_pt") -> dict:
    """LIFReset parameters of one stage: the integers of ``p`` for fixed_pt (bit exact to
    fixed_point.lif_step with reset "zero"), or the float values they stand for (floating_pt)."""
    common = dict(bias_mant=0, reset_interval=int(n_bins), reset_offset=STOCK_RESET_OFFSET % int(n_bins))
    if tag == "fixed_pt":
        return dict(du=int(p.du), dv=int(p.dv), vth=int(p.vth_mant), bias_exp=0, **common)
    _w, vth, lam = p.float_equivalent()
    return dict(du=1.0, dv=1.0 - lam, vth=float(vth), **common)


class LavaRuntimeError(ToffeError):
    """The Lava network failed or stopped answering (reported in one line, exit code 2)."""


def import_lava() -> None:
    """Import Lava's runtime, whatever touched multiprocessing before.

    Lava calls ``multiprocessing.set_start_method('fork')`` (no force) when its runtime is first
    imported; that raises "context has already been set" once anything created a multiprocessing
    object (tqdm does for every progress bar, even a disabled one). An unset or 'fork' default
    is reset so that Lava's own call succeeds; it sets 'fork' again. Missing Lava is one line.
    """
    import multiprocessing as mp
    import sys

    if "lava.magma.runtime.message_infrastructure.multiprocessing" not in sys.modules and mp.get_start_method(allow_none=True) == "fork":
        mp.set_start_method(None, force=True)
    try:
        import lava.magma.core.process.process  # noqa: F401
        import lava.magma.core.run_configs  # noqa: F401
        import lava.magma.runtime.message_infrastructure.multiprocessing  # noqa: F401
    except ImportError as e:  # pragma: no cover - exercised only without the extra installed
        raise ToffeError(f"the Lava targets need lava-nc ({e}); install the 'lava' extra: "
                         "pip install -e '.[lava]', or use --target cpu") from e


def check_hardware() -> None:
    """Raise the one-line ToffeError unless lava-loihi (needed for Loihi2HwCfg) is importable."""
    import_lava()
    from lava.utils.loihi import is_installed
    if not is_installed():
        raise ToffeError(HW_MISSING)


def run_config(tag: str = "fixed_pt", hardware: bool = False, stock: bool = False):
    """Loihi2SimCfg (or Loihi2HwCfg with lava-loihi) selecting our process models by ``tag``.

    Our Processes are named in exception_proc_model_map so that the choice never depends on
    model discovery order. ``stock`` (reset "zero" bundles): the OFS is Lava's Conv + LIFReset,
    their ``tag`` models in simulation (fixed_pt: Lava's bit-accurate ones); on Loihi2HwCfg the
    compiler maps them to NeuroCores and only our source and bridges run on the host. Without
    ``stock`` the OFS neuron is ours, a Python model with no NeuroCore microcode.
    """
    if tag not in TAGS:
        raise ToffeError(f"unknown Lava model tag {tag!r}; choose one of {', '.join(TAGS)}")
    import_lava()
    from lava.magma.core.run_configs import Loihi2HwCfg, Loihi2SimCfg

    from lava_procs.bridge.models import PyCascadeBridgeModel
    from lava_procs.bridge.process import CascadeBridge
    from lava_procs.event_source.models import PyEventBinSourceModel
    from lava_procs.event_source.process import EventBinSource
    from lava_procs.ofs_neuron.models import PyOFSNeuronModelFixed, PyOFSNeuronModelFloat
    from lava_procs.ofs_neuron.process import OFSNeuron

    if stock:
        from lava.proc.conv.models import PyConvModelFixed, PyConvModelFloat
        from lava.proc.conv.process import Conv
        from lava.proc.lif.models import PyLifResetModelBitAcc, PyLifResetModelFloat
        from lava.proc.lif.process import LIFReset

        from lava_procs.bridge.models import PyCascadeBridgeStockModel
        from lava_procs.event_source.models import PyEventBinSourceStockModel

        models = {EventBinSource: PyEventBinSourceStockModel, CascadeBridge: PyCascadeBridgeStockModel}
        if not hardware:     # on Loihi2HwCfg the stock processes take their NeuroCore models
            fixed = tag == "fixed_pt"
            models.update({Conv: PyConvModelFixed if fixed else PyConvModelFloat,
                           LIFReset: PyLifResetModelBitAcc if fixed else PyLifResetModelFloat})
    else:
        models = {EventBinSource: PyEventBinSourceModel, CascadeBridge: PyCascadeBridgeModel,
                  OFSNeuron: PyOFSNeuronModelFixed if tag == "fixed_pt" else PyOFSNeuronModelFloat}
    if hardware:
        check_hardware()
        return Loihi2HwCfg(select_tag=tag, exception_proc_model_map=models)
    return Loihi2SimCfg(select_tag=tag, exception_proc_model_map=models)


DEFERRED = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


#: networks started and not yet closed (weakly held): _close_live stops them at interpreter exit
_LIVE: "weakref.WeakSet" = weakref.WeakSet()
_EXIT_HOOK = False


def _close_live() -> None:
    """atexit: close every network still running. multiprocessing's own exit hook joins Lava's
    (non-daemon) children, which run until told to stop: a script that ended without closing its
    Pipeline hung there forever. Registered at the first start, after multiprocessing's hook, so
    it runs before it."""
    for cascade in list(_LIVE):
        with contextlib.suppress(BaseException):
            cascade.close()


@contextlib.contextmanager
def _signals_deferred():
    """Hold Ctrl-C, SIGTERM and SIGHUP until a host <-> network exchange is complete, then hand
    the first one to its handler. Only signals with a Python handler are held (an ignored one
    stays ignored, a default one keeps its default action)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    hit: list[tuple[int, Any]] = []
    old = {}
    for sig in DEFERRED:
        h = signal.getsignal(sig)
        if callable(h):
            old[sig] = signal.signal(sig, lambda signum, frame: hit.append((signum, frame)))
    try:
        yield
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)
    if hit:
        sig, frame = hit[0]
        old[sig](sig, frame)


def _as_packed(window: Any, shape: tuple[int, int, int, int]) -> np.ndarray:
    """A window as the source's packed (B, C, H, ceil(W/8)) uint8; nonzero = spike.

    Accepts a dense (B, C, H, W) array or a sparse volume with ``idx`` (unique flat indices of
    the ones) and ``shape`` (toffe_deploy.runtime.spikes.SpikeVolume), packed without densifying.
    """
    from lava_procs.packing import pack, pack_indices

    if hasattr(window, "idx") and hasattr(window, "shape") and not isinstance(window, np.ndarray):
        got = tuple(int(s) for s in window.shape)
        if got != shape:
            raise ToffeError(f"window shape {got} does not match the Lava network's (B, C, H, W) = {shape}")
        return pack_indices(window.idx, got)
    arr = np.asarray(window)
    if arr.shape != shape:
        raise ToffeError(f"window shape {arr.shape} does not match the Lava network's (B, C, H, W) = {shape}")
    return pack(arr > 0)


class LavaCascade:
    """The OFS cascade as a Lava network; a context manager that always stops the runtime.

    ``params``: the N stages (index k - 1 = speed bin k), or a deploy Bundle (``.ofs`` and
    ``.config``, whose n_bins, mask_kernel and sensor_size are then the defaults).
    ``sensor_size`` is (width, height). ``tag``: "fixed_pt" (bit exact to
    toffe_deploy.fixed_point) or "floating_pt". ``hardware``: Loihi2HwCfg (needs lava-loihi).

    ``cascade_stream(windows)`` yields, per window and in order, the same CascadeResult as
    ``run_cascade(x, lambda k, inp: run_ofs_fixed(inp, params[k - 1]), N, mask_kernel)``.
    Compile and start happen once, in ``start()`` / ``__enter__``; ``startup_s`` says how long.
    """

    def __init__(self, params: Sequence[LoihiOFSParams] | Any, n_bins: int | None = None,
                 mask_kernel: int | None = None, sensor_size: tuple[int, int] | None = None, *,
                 tag: str = "fixed_pt", hardware: bool = False, timeout_s: float = 120.0):
        if hasattr(params, "ofs") and hasattr(params, "config"):       # a deploy Bundle
            cfg = params.config
            n_bins = cfg.n_bins if n_bins is None else n_bins
            mask_kernel = cfg.mask_kernel if mask_kernel is None else mask_kernel
            sensor_size = tuple(cfg.sensor_size) if sensor_size is None else sensor_size
            params = params.ofs
        self.params = list(params)
        if not self.params:
            raise ToffeError("the Lava cascade needs at least one OFS stage")
        if n_bins is None or mask_kernel is None or sensor_size is None:
            raise ToffeError("LavaCascade needs n_bins, mask_kernel and sensor_size (or a bundle)")
        if tag not in TAGS:
            raise ToffeError(f"unknown Lava model tag {tag!r}; choose one of {', '.join(TAGS)}")
        channels = {int(p.weight.shape[1]) for p in self.params}
        if len(channels) != 1:
            raise ToffeError(f"OFS stages disagree on input channels: {sorted(channels)}")
        resets = {p.reset for p in self.params}
        if len(resets) != 1:
            raise ToffeError(f"OFS stages disagree on the reset rule: {sorted(resets)}")
        self.reset = resets.pop()
        self.stock = self.reset == "zero"     # stock Conv + LIFReset (module docstring)
        self._lag = 1 if self.stock else 0    # extra pipeline periods before a record reaches the host
        if hardware and not self.stock:
            raise ToffeError(HW_SUBTRACT)
        self.n_stages = len(self.params)
        self.n_bins = int(n_bins)
        self.mask_kernel = int(mask_kernel)
        self.width, self.height = (int(s) for s in sensor_size)
        self.channels = channels.pop()
        self.window_shape = (self.n_bins, self.channels, self.height, self.width)
        self.tag = tag
        self.hardware = bool(hardware)
        if self.hardware:
            check_hardware()                 # fail before the caller does any other work
        self.timeout_s = float(timeout_s)
        self.startup_s: float | None = None
        self.child_pids: list[int] = []
        self.shm_names: list[str] = []
        self.shm_bytes = 0
        self.shm_prefix: str | None = None   # every segment of this runtime starts with it
        self.reclaimed: lava_host.Reclaimed | None = None   # leftovers of dead hosts removed by start()
        self._runtime = None
        self._source = None
        self.processes: list[Any] = []       # every Process of the network (source first)
        self._bridges: list[Any] = []        # index k - 1
        self._record_ports: list[Any] = []
        self._old_sigterm: Any = None
        self._period = 0                     # windows fed so far (pipeline periods)
        self._inflight: list[int] | None = None   # stages whose record the running period owes
        self._failed = False                 # a period timed out or lost a process: close() kills at once

    # ----------------------------------------------------------------- life cycle
    def __enter__(self) -> "LavaCascade":
        self.start()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc is None:
            self.close()
            return
        try:                    # keep the caller's exception; close() has cleaned up regardless
            self.close()
        except Exception:
            pass

    def start(self) -> None:
        """Build, compile and start the network (once).

        A signal or error at any point in here kills the processes started so far, unlinks their
        shared memory and re-raises (ToffeError and BaseException as they are, others as
        LavaRuntimeError): nothing outlives a start that did not finish.
        """
        if self._runtime is not None:
            return
        t0 = time.perf_counter()
        self._period, self._inflight, self._failed = 0, None, False   # a fresh network: periods from 0 again
        self._catch_sigterm()                # before anything is forked
        try:
            with redeliver_swallowed():      # a signal swallowed by an at-fork hook is sent again
                self._start()
        except BaseException:
            self._restore_sigterm()
            raise
        self.startup_s = time.perf_counter() - t0
        _LIVE.add(self)                      # stopped at interpreter exit if its user does not (_close_live)
        global _EXIT_HOOK
        if not _EXIT_HOOK:                   # registered after multiprocessing's: runs before it joins the children
            atexit.register(_close_live)
            _EXIT_HOOK = True

    def __del__(self):
        """A network its user dropped without close() is stopped (it outlived its object: the
        children and their shared memory ran on, and the interpreter's exit waited on them forever)."""
        if getattr(self, "_runtime", None) is not None:
            with contextlib.suppress(BaseException):
                self.close()

    def _start(self) -> None:
        import multiprocessing as mp

        cfg = run_config(self.tag, self.hardware, self.stock)
        from lava_procs.bridge.process import CascadeBridge
        from lava_procs.event_source.process import EventBinSource

        self.reclaimed = lava_host.reclaim()
        lava_host.ensure_reaper()
        n, b = self.n_stages, self.n_bins
        self._source = EventBinSource(shape=(self.channels, self.height, self.width), n_bins=b,
                                      buffer_size=2, stock=self.stock, name="event_source")
        procs: list[Any] = [self._source]
        bridges: list[Any] = [None] * n
        x_port = self._source.s_out
        a_port = getattr(self._source, "a_out", None)
        for k in range(n, 0, -1):
            bridge = CascadeBridge(shape=(self.height, self.width), channels=self.channels, n_bins=b,
                                   mask_kernel=self.mask_kernel, depth=n - k, buffer_size=2, stock=self.stock,
                                   name=f"bridge{k}")
            stage = self._stage_processes(k, x_port, a_port, bridge)
            x_port.connect(bridge.x_in)
            procs += [*stage, bridge]
            x_port, a_port = bridge.x_out, getattr(bridge, "a_out", None)
            bridges[k - 1] = bridge
        self._bridges = bridges
        self.processes = procs
        self.shm_prefix = lava_host.next_runtime_prefix()
        before = set(mp.active_children())
        try:
            exe = self._source.compile(cfg)
            with lava_host.spawning(self.shm_prefix):      # the children fork here
                self._source.create_runtime(executable=exe)
            self._runtime = self._source.runtime
            self._record_ports = [br.receive_port() for br in bridges]
            mi = self._runtime._messaging_infrastructure
            self.child_pids = [a.pid for a in mi.actors]
            manager = self._manager_process()
            if manager is not None:
                self.child_pids.append(manager.pid)
            handles = list(getattr(mi.smm, "_shared_memory_handles", []))
            self.shm_names = [h.name for h in handles]
            self.shm_bytes = int(sum(h.size for h in handles))
        except BaseException as e:
            self._runtime = getattr(self._source, "_runtime", None)
            self._force_stop()
            self._runtime = None
            for proc in set(mp.active_children()) - before:   # forked before Lava listed them
                with contextlib.suppress(Exception):
                    proc.kill()
                    proc.join(5.0)
            if isinstance(e, ToffeError) or not isinstance(e, Exception):
                raise
            raise LavaRuntimeError(f"could not start the Lava network: {type(e).__name__}: {e}") from e

    def _stage_processes(self, k: int, x_port, a_port, bridge) -> list[Any]:
        """Build stage k between its input and its bridge; returns its processes.

        Stock: Conv (weights lava_conv_weight, zero padding K // 2) into LIFReset (shape
        (W, H, 1)), fed dense spikes on ``a_port``. Otherwise our fused OFSNeuron, fed the packed
        ``x_port``."""
        p = self.params[k - 1]
        if not self.stock:
            from lava_procs.ofs_neuron.process import OFSNeuron

            neuron = OFSNeuron(shape=(self.height, self.width), weight=p.weight, vth=p.vth_mant, dv=p.dv,
                               du=p.du, weight_scale=p.weight_scale, n_bins=self.n_bins, name=f"ofs{k}")
            x_port.connect(neuron.s_in)
            neuron.s_out.connect(bridge.s_in)
            return [neuron]
        from lava.proc.conv.process import Conv
        from lava.proc.lif.process import LIFReset

        weight = lava_conv_weight(p.weight)
        if self.tag != "fixed_pt":
            weight = weight / p.weight_scale
        conv = Conv(weight=weight, input_shape=(self.width, self.height, self.channels),
                    padding=p.kernel_size // 2, name=f"conv{k}")
        lif = LIFReset(shape=(self.width, self.height, 1), name=f"lif{k}",
                       **stock_neuron_kwargs(p, self.n_bins, self.tag))
        a_port.connect(conv.s_in)
        conv.a_out.connect(lif.a_in)
        lif.s_out.connect(bridge.s_in)
        return [conv, lif]

    def _manager_process(self):
        """The process of Lava's SharedMemoryManager (a multiprocessing Process), or None."""
        mi = getattr(self._runtime, "_messaging_infrastructure", None)
        manager = getattr(getattr(mi, "smm", None), "_manager", None)
        return getattr(manager, "_process", None)

    def _catch_sigterm(self) -> None:
        """Turn a polite kill (SIGTERM, e.g. from `timeout`) into SystemExit so that close() runs.

        Only over the default handler: the CLI installs its own (toffe_deploy.signals) first.
        Lava's children take the default action again (lava_host).
        """
        if threading.current_thread() is not threading.main_thread():
            return
        if signal.getsignal(signal.SIGTERM) in (signal.SIG_DFL, None):
            def on_term(sig, frame):
                raise SystemExit(128 + signal.SIGTERM)
            self._old_sigterm = signal.signal(signal.SIGTERM, on_term)

    def _restore_sigterm(self) -> None:
        if self._old_sigterm is not None and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, self._old_sigterm)
            self._old_sigterm = None

    def close(self) -> None:
        """Stop the runtime: drain a running window, stop, and kill what does not stop in time."""
        rt = self._runtime
        if rt is None:
            return
        try:
            if self._failed:
                self._force_stop()
                return
            with _signals_deferred():
                if self._inflight is not None:
                    self._end_period()
                self._stop_with_timeout()
        except BaseException:
            self._force_stop()
            raise
        finally:
            self._runtime = None
            self._inflight = None
            _LIVE.discard(self)
            if self.shm_prefix:               # a manager that died cannot unlink its segments
                lava_host.unlink_prefix(self.shm_prefix)
            self._restore_sigterm()

    # ----------------------------------------------------------------- streaming
    def cascade_stream(self, windows: Iterable[Any]) -> Iterator[CascadeResult]:
        """Run the cascade on each window (B, C, H, W) (nonzero = event); yield results in order."""
        from lava_procs.packing import unpack

        self.start()
        if self._inflight is not None:       # an earlier stream was abandoned mid-window
            self._end_period()
        n, b, c = self.n_stages, self.n_bins, self.channels
        it = iter(windows)
        zeros = np.zeros((b, c, self.height, (self.width + 7) // 8), np.uint8)
        base = self._period   # records of windows fed before this call map to w < 0: dropped
        pending: dict[int, list[Any]] = {}
        n_in = 0

        def pull():
            nonlocal n_in
            try:
                w = next(it)
            except StopIteration:
                return None
            n_in += 1
            return _as_packed(w, self.window_shape)

        nxt = pull()
        if nxt is None:
            return
        self._begin_period(nxt)
        while True:
            p = self._period - 1 - base               # the period now running
            nxt = pull()                               # overlaps with the network's steps
            for k, rec in self._end_period():
                w = p - (n - k) - self._lag
                if 0 <= w < n_in - (nxt is not None):
                    pending.setdefault(w, [None] * n)[k - 1] = rec
            more = nxt is not None or p < n_in - 1 + n - 1 + self._lag
            if more:
                self._begin_period(nxt if nxt is not None else zeros)
            done = p - (n - 1) - self._lag
            if done in pending:
                recs = pending.pop(done)
                yield self._result(recs, unpack)
            if not more:
                return

    def _result(self, recs: list[np.ndarray], unpack) -> CascadeResult:
        b, c, h, w = self.window_shape
        res = CascadeResult([None] * self.n_stages, [None] * self.n_stages, [None] * self.n_stages,
                            [None] * self.n_stages)
        for k0, rec in enumerate(recs):
            planes = unpack(rec, w)
            res.spikes[k0] = planes[:b]
            res.closed[k0] = planes[b]
            res.inputs[k0] = planes[b + 1:b + 1 + b * c].reshape(b, c, h, w)
            res.frames[k0] = planes[b + 1 + b * c:].reshape(b, c, h, w)
        return res

    # ----------------------------------------------------------------- host <-> network
    def _begin_period(self, packed: np.ndarray) -> None:
        from lava.magma.core.run_conditions import RunSteps

        period = self._period
        owed = [k for k in range(1, self.n_stages + 1) if period - (self.n_stages - k) - self._lag >= 0]
        self._check_alive(f"window {period}")
        with _signals_deferred():
            self._runtime.start(RunSteps(num_steps=self.n_bins, blocking=False))
            self._inflight = owed
            self._source.send(packed)
        self._period += 1

    def _end_period(self) -> list[tuple[int, np.ndarray]]:
        """Collect the records the running period owes, then wait for its last step. The period
        is over either way: after a timeout close() does not wait for it a second time."""
        out = []
        with _signals_deferred():
            try:
                for k in sorted(self._inflight, reverse=True):
                    out.append((k, self._recv(self._record_ports[k - 1], f"stage {k}")))
                self._wait_done()
            except BaseException:
                self._failed = True          # close() kills it at once: no graceful stop of a network that
                raise                        # timed out or lost a process (that cost another timeout)
            finally:
                self._inflight = None
        return out

    def _check_alive(self, what: str) -> None:
        rt = self._runtime
        manager = self._manager_process()
        if manager is not None and not manager.is_alive():
            raise LavaRuntimeError(f"Lava's shared-memory manager process stopped while waiting for {what}")
        for a in rt._messaging_infrastructure.actors:
            try:
                alive = a.is_alive()
            except ValueError:             # already joined and closed
                alive = False
            if not alive:
                exc = None
                with contextlib.suppress(Exception):
                    exc = a.exception
                detail = f": {exc[0]!r}" if exc else ""
                raise LavaRuntimeError(f"a Lava process stopped while waiting for {what}{detail}")
        if rt.service_to_runtime and rt.service_to_runtime[0].probe():
            msg = rt.service_to_runtime[0].peek()
            from lava.magma.runtime.mgmt_token_enums import MGMT_RESPONSE, enum_equal
            if enum_equal(msg, MGMT_RESPONSE.ERROR):
                errs = []
                for a in rt._messaging_infrastructure.actors:
                    with contextlib.suppress(Exception):
                        if a.exception:
                            errs.append(repr(a.exception[0]))
                raise LavaRuntimeError(f"the Lava network failed while waiting for {what}: "
                                       f"{'; '.join(errs) or 'error in a process model'}")

    def _await(self, port, what: str) -> None:
        """Block until ``port`` (a Lava CspRecvPort) holds a message, with a deadline, checking
        the network's health every 0.25 s (a failed child would otherwise leave us waiting)."""
        deadline = time.monotonic() + self.timeout_s
        while True:
            try:
                port._queue.get(timeout=0.25, peek=True)
                return
            except queue.Empty:
                self._check_alive(what)
                if time.monotonic() > deadline:
                    raise LavaRuntimeError(f"the Lava network did not deliver {what} within {self.timeout_s:g} s")

    def _recv(self, port, what: str) -> np.ndarray:
        self._await(port, what)
        return port.recv()

    def _wait_done(self) -> None:
        rt = self._runtime
        self._await(rt.service_to_runtime[0], "the end of a window")
        self._check_alive("the end of a window")     # an ERROR here raises without joining
        rt.wait()        # consumes DONE

    def _stop_with_timeout(self) -> None:
        rt = self._runtime
        # Lava's stop() only tells a runtime that has run to stop its processes; one that never
        # ran would then wait forever on children that were never told. Its service and models
        # handle STOP fine from the start, so let stop() send it.
        rt._is_started = True
        box: list[BaseException] = []

        def stop():
            try:
                rt.stop()
            except BaseException as e:  # noqa: BLE001 - re-raised in the caller's thread
                box.append(e)

        th = threading.Thread(target=stop, name="lava-stop", daemon=True)
        th.start()
        th.join(self.timeout_s)
        if th.is_alive() or box:
            self._force_stop()
            if box:
                raise LavaRuntimeError(f"stopping the Lava network failed: {box[0]!r}")
            raise LavaRuntimeError(f"the Lava network did not stop within {self.timeout_s:g} s; killed it")

    def _force_stop(self) -> None:
        """Kill the runtime's processes and unlink its shared memory (last resort)."""
        rt = self._runtime
        if rt is None:
            return
        mi = getattr(rt, "_messaging_infrastructure", None)
        manager = self._manager_process()     # smm.shutdown() forgets it
        import multiprocessing as mp

        for a in list(getattr(mi, "actors", [])):
            with contextlib.suppress(Exception):
                if a.is_alive():
                    a.kill()
            with contextlib.suppress(Exception):
                mp.Process.join(a, 5.0)
        smm = getattr(mi, "smm", None)
        if smm is not None:
            with contextlib.suppress(Exception):
                smm.shutdown()
        with contextlib.suppress(Exception):
            rt._watchdog_manager.stop()
        if manager is not None:
            with contextlib.suppress(Exception):
                if manager.is_alive():
                    manager.kill()
                manager.join(5.0)
        if self.shm_prefix:                   # the manager unlinks them; make sure
            lava_host.unlink_prefix(self.shm_prefix)
        rt._is_started = False                # nothing left for Runtime.__del__ to stop


def run_ofs_lava(windows: Sequence[np.ndarray], params: LoihiOFSParams, tag: str = "fixed_pt") -> list[np.ndarray]:
    """One OFS stage on Lava over each window (B, C, H, W); returns its spikes (B, H, W) bool.

    Bit exact to ``run_ofs_fixed`` with tag fixed_pt (the export parity check uses this).
    Windows of different shapes are allowed: one network per distinct shape, results in order.
    """
    windows = [np.asarray(x) for x in windows]
    out: list[np.ndarray | None] = [None] * len(windows)
    by_shape: dict[tuple[int, ...], list[int]] = {}
    for i, x in enumerate(windows):
        if x.ndim != 4:
            raise ToffeError(f"window {i} must be (B, C, H, W), got shape {x.shape}")
        by_shape.setdefault(x.shape, []).append(i)
    for (b, _c, h, w), idx in by_shape.items():
        with LavaCascade([params], n_bins=b, mask_kernel=1, sensor_size=(w, h), tag=tag) as lc:
            for i, res in zip(idx, lc.cascade_stream(windows[i] for i in idx)):
                out[i] = res.spikes[0]
    return out
