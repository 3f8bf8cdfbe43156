"""Kernels cached by different processes and loaded into one run their own code (toffe_deploy.jit).

numba's per-process compile counter gave two different cached bodies of one helper the same
symbol (numba issue #10486); loaded together, one kernel ran the other's code, silently: the
DOTIE baseline's kernels gave wrong spikes after a pipeline had been loaded from the cache."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

SORT = "import numpy as np\nfrom toffe_deploy.jit import njit\n\n@njit(cache=True)\ndef f(x):\n    return np.sort(x)\n"
ARGSORT = SORT.replace("np.sort", "np.argsort")
CALL = """
import sys
import numpy as np
from toffe_deploy.jit import njit
for k in range(int(sys.argv[2])):          # what this process compiled before: moves numba's counter
    njit(lambda v, k=k: v + k)(1)
out = []
for name in sys.argv[1].split(","):
    out.append(" ".join(map(str, __import__(name).f(np.array([5, 3, 9, 1, 7, 2, 8], np.int64)))))
print("|".join(out))
"""


def test_kernels_cached_by_two_processes_run_their_own_code_in_a_third(tmp_path):
    """np.sort's kernel cached by one process, np.argsort's by another that compiled 3 functions
    first (under numba 0.61 their quicksort helpers then got the same counter value, 6), both
    loaded in a third: argsort returned the sorted values (1 2 3 5 7 8 9) before toffe_deploy.jit."""
    (tmp_path / "sort_mod.py").write_text(SORT)
    (tmp_path / "argsort_mod.py").write_text(ARGSORT)
    (tmp_path / "call.py").write_text(CALL)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"),
           "PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT), os.environ.get("PYTHONPATH", "")])}

    def call(names, pad=0):
        p = subprocess.run([sys.executable, str(tmp_path / "call.py"), names, str(pad)], capture_output=True,
                           text=True, env=env, cwd=tmp_path, timeout=300)
        assert p.returncode == 0, p.stderr
        return p.stdout.strip()

    x = np.array([5, 3, 9, 1, 7, 2, 8])
    want_sort, want_argsort = " ".join(map(str, np.sort(x))), " ".join(map(str, np.argsort(x)))
    assert call("sort_mod") == want_sort                       # compiled and cached here
    assert call("argsort_mod", pad=3) == want_argsort          # and here, after 3 other compiles
    assert len(list((tmp_path / "cache").rglob("*.nbc"))) == 2
    assert call("sort_mod,argsort_mod") == f"{want_sort}|{want_argsort}"       # both from the cache
    assert call("argsort_mod,sort_mod") == f"{want_argsort}|{want_sort}"


def test_every_kernel_module_takes_njit_from_toffe_deploy_jit():
    """The ids are random only once toffe_deploy.jit is imported: a module that took njit from
    numba directly could compile first, with the counter."""
    direct = [str(p.relative_to(ROOT)) for p in (ROOT / "toffe_deploy").rglob("*.py")
              if p.name != "jit.py" and any(line.startswith(("from numba import", "import numba"))
                                            for line in p.read_text().splitlines())]
    assert direct == []
