#!/usr/bin/env python
"""Peak memory of a command and all its child processes, Lava's /dev/shm channels included.

    python benchmarks/peak_memory.py toffe-deploy run export/ --target loihi-sim --events long.h5 --out /tmp/f.jsonl

Samples every 0.2 s: the proportional set size (PSS, each shared page counted once) of every
process in the command's tree, without their /dev/shm pages, plus the growth of /dev/shm's use
since the start (Lava's channel rings). Prints the peak and what /dev/shm still holds after the
command ended (leaked segments would show there), in MiB (2**20 bytes, as the other benchmarks).
Linux only (reads /proc).

Exit status: the command's own; 128 + N when a signal N ended it (as a shell reports it); 2
when the command cannot be started (not found, not executable), with one line on stderr.
"""
from __future__ import annotations

import os
import subprocess
import sys
import time

MIB = 2 ** 20


def process_tree(pid: int) -> list[int]:
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as f:
                    todo += [int(c) for c in f.read().split()]
        except OSError:
            pass
    return out


def pss_without_shm(pid: int) -> int:
    """Proportional set size of a process minus its /dev/shm pages, in bytes (0 once it is gone).

    Lava's processes are forks of the host and share most pages copy-on-write; PSS divides each
    shared page among its sharers, so the sum over processes counts it once. /dev/shm pages are
    left out here and counted once from the segments themselves.
    """
    pss = shm = 0
    try:
        with open(f"/proc/{pid}/smaps_rollup") as f:
            for line in f:
                if line.startswith("Pss:"):
                    pss = int(line.split()[1]) * 1024
                elif line.startswith("Pss_Shmem:"):
                    shm = int(line.split()[1]) * 1024
    except OSError:
        pass
    return pss - shm


def shm_used() -> int:
    st = os.statvfs("/dev/shm")
    return (st.f_blocks - st.f_bfree) * st.f_frsize


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        try:
            print(__doc__, file=sys.stdout if argv else sys.stderr, flush=True)
        except BrokenPipeError:                 # `--help | head`: stop quietly, as the CLI does
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except OSError as exc:                  # `> /dev/full`
            print(f"peak_memory: error: cannot write the help: {exc.strerror or exc}", file=sys.stderr)
            return 2
        return 0 if argv else 2
    base = shm_used()
    t0 = time.time()
    try:
        proc = subprocess.Popen(argv)
    except OSError as exc:               # not found, not executable, ...
        print(f"peak_memory: error: {argv[0]}: cannot run it: {exc.strerror or exc}", file=sys.stderr)
        return 2
    peak = peak_shm = 0
    while proc.poll() is None:
        shm = max(shm_used() - base, 0)
        peak = max(peak, sum(pss_without_shm(p) for p in process_tree(proc.pid)) + shm)
        peak_shm = max(peak_shm, shm)
        time.sleep(0.2)
    rc = proc.returncode
    how = f"exit {rc}" if rc >= 0 else f"killed by signal {-rc}"
    print(f"{how}, {time.time() - t0:.0f} s; peak memory {peak / MIB:.0f} MiB "
          f"(PSS of the process tree + /dev/shm), of which /dev/shm {peak_shm / MIB:.0f} MiB; "
          f"/dev/shm still used after the end: {max(shm_used() - base, 0) / MIB:.1f} MiB", file=sys.stderr)
    return rc if rc >= 0 else 128 - rc


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
