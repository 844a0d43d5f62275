"""The wheel carries the kernels and the presets (style.md item 1)."""
from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def test_wheel_contains_kernels_and_presets(tmp_path):
    res = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w",
                          str(tmp_path), str(REPO)], capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    wheel = next(tmp_path.glob("warpe_cl-*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    for kernel in ("walk.cl", "selftest.cl", "real.h", "philox.h", "fresnel.h", "scatter.h",
                   "tally.h"):
        assert f"warpe_cl/cl/{kernel}" in names, kernel
    assert "warpe_cl/presets/radiative/slab_co2_1m.yaml" in names
    for instrument in ("bela", "gala", "atlas"):
        assert f"warpe_cl/presets/instruments/{instrument}.yaml" in names, instrument
    assert "warpe_cl/instrument/chain.py" in names
    for module in ("__init__", "schema", "validate", "preset", "grid"):   # the config package
        assert f"warpe_cl/config/{module}.py" in names, module
    entry = next(n for n in names if n.endswith("entry_points.txt"))
    assert "warpe-cl = warpe_cl.cli:main" in zipfile.ZipFile(wheel).read(entry).decode()


def test_installed_kernel_folder_is_found():
    from warpe_cl.device import kernel_dir
    assert (kernel_dir() / "walk.cl").is_file()
