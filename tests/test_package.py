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
    entry = next(n for n in names if n.endswith("entry_points.txt"))
    assert "warpe-cl = warpe_cl.cli:main" in zipfile.ZipFile(wheel).read(entry).decode()


def test_installed_kernel_folder_is_found():
    from warpe_cl.device import kernel_dir
    assert (kernel_dir() / "walk.cl").is_file()


def test_kernel_folder_belongs_to_the_imported_package():
    """The kernels are read beside the package that is imported (``warpe_cl/cl`` installed,
    ``cl/`` in a checkout), never from another checkout that an editable install points at."""
    import warpe_cl
    from warpe_cl.device import kernel_dir
    here = Path(warpe_cl.__file__).resolve().parent
    assert kernel_dir() in (here / "cl", here.parent / "cl")
