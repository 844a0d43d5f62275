"""The wheel carries the kernels and the presets: they are package data, found by path at run
time (warpe_cl.cl and warpe_cl.presets in setup.cfg), so an installed warpe-cl needs no
checkout."""
from __future__ import annotations

import subprocess
import sys
import zipfile

import pytest

from conftest import REPO


@pytest.mark.slow
def test_wheel_contains_kernels_and_presets(tmp_path):
    # --no-build-isolation: the build uses this environment's setuptools (a test extra), so the
    # suite needs no network.
    res = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                          "-q", "-w", str(tmp_path), str(REPO)], capture_output=True, text=True,
                         timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    wheel = next(tmp_path.glob("warpe_cl-*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    from warpe_cl.device import SELFTEST_FILES, every_program_file
    from warpe_cl.engine import WALK_FILES
    for kernel in every_program_file(WALK_FILES + SELFTEST_FILES):   # every build's parts
        assert f"warpe_cl/cl/{kernel}" in names, kernel
    assert "warpe_cl/presets/radiative/slab_co2_1m.yaml" in names
    for instrument in ("bela", "gala", "atlas"):
        assert f"warpe_cl/presets/instruments/{instrument}.yaml" in names, instrument
    # every module of the package (a new subpackage must be listed in setup.cfg's packages)
    modules = {f"warpe_cl/{p.relative_to(REPO / 'warpe_cl').as_posix()}"
               for p in (REPO / "warpe_cl").rglob("*.py")}
    assert modules - names == set()
    # and no module the tree no longer has (pip builds in place, reusing an ignored build/)
    shipped = {n for n in names if n.startswith("warpe_cl/") and n.endswith(".py")
               and not n.startswith(("warpe_cl/cl/", "warpe_cl/presets/"))}
    assert shipped - modules == set(), "stale modules: remove build/ and build again"
    entry = next(n for n in names if n.endswith("entry_points.txt"))
    assert "warpe-cl = warpe_cl.cli:main" in zipfile.ZipFile(wheel).read(entry).decode()


def test_installed_kernel_folder_is_found():
    from warpe_cl.device import kernel_dir
    assert (kernel_dir() / "walk.cl").is_file()


def test_kernel_folder_belongs_to_the_imported_package():
    """The kernels are read beside the package that is imported (``warpe_cl/cl`` installed,
    ``cl/`` in a checkout), never from another checkout that an editable install points at."""
    from pathlib import Path

    import warpe_cl
    from warpe_cl.device import kernel_dir
    here = Path(warpe_cl.__file__).resolve().parent
    assert kernel_dir() in (here / "cl", here.parent / "cl")
