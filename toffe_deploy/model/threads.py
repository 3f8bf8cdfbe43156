"""torch's intra-op thread count for a block: one small module, imported by the export's parity
checks and by the baselines timed against TOFFE, so both run torch as the benchmarks count it."""
from __future__ import annotations


class torch_threads:
    """Run torch with n intra-op threads inside the block (restored after).

    The float reference runs many small element-wise steps; on a shared 2-core machine torch's
    default thread pool makes them 20x slower (measured: 29.9 s vs 1.8 s for fixed_vs_float at
    640x480 while another process trained), so the checks use one thread.
    """

    def __init__(self, n: int):
        self.n = n
        self.old = None

    def __enter__(self):
        import torch

        self.old = torch.get_num_threads()
        torch.set_num_threads(self.n)
        return self

    def __exit__(self, *exc):
        import torch

        torch.set_num_threads(self.old)
        return False
