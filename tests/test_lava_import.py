"""Lava's import sets the 'fork' start method without force: it must survive an earlier tqdm bar."""
import subprocess
import sys


def test_lava_imports_after_a_progress_bar():
    code = ("from tqdm import tqdm\n"
            "for _ in tqdm(range(2), disable=True): pass\n"
            "from toffe_deploy.runtime.loihi import import_lava\n"
            "import_lava()\n"
            "import multiprocessing as mp; print(mp.get_start_method())\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().endswith("fork")
