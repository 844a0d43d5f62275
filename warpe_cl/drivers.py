"""OpenCL drivers installed with pip, made visible to the OpenCL loader (docs/devices.md).

An OpenCL driver (an "ICD") is found by the loader through ``.icd`` files, one line each
naming the driver's library, in ``/etc/OpenCL/vendors`` or in the folder (or file) named by
``$OCL_ICD_VENDORS``. pyopencl's wheel adds its own PoCL. Intel's CPU runtime from pip
(``intel-opencl-rt``, with ``intel-cmplr-lib-rt`` for its maths libraries) installs
``libintelocl.so`` into the environment's ``lib/`` but registers nothing: its ``.icd`` names a
path of Intel's build machine. :func:`register` writes, once per user and per set of drivers,
a folder holding one ``.icd`` per driver the loader would have seen anyway (the files of
``$OCL_ICD_VENDORS`` or ``/etc/OpenCL/vendors``) plus one for each pip-installed driver by its
absolute path, and points ``$OCL_ICD_VENDORS`` at it. Nothing is installed and no root is
needed; the system's drivers stay visible. ``WARPE_CL_PIP_DRIVERS=0`` turns it off.

It must run before the first OpenCL call of the process: :func:`warpe_cl.device._cl` calls it
before importing pyopencl, and child processes inherit the variable.
"""
from __future__ import annotations

import hashlib
import os
import tempfile
from functools import lru_cache
from pathlib import Path

SYSTEM_VENDORS = Path("/etc/OpenCL/vendors")

#: pip distributions that carry an OpenCL driver library, and its file name
PIP_DRIVERS = {"intel-opencl-rt": "libintelocl.so"}


def cache_dir() -> Path:
    """warpe-cl's per-user cache folder: ``$WARPE_CL_CACHE_DIR``, else
    ``$XDG_CACHE_HOME/warpe-cl``, else ``~/.cache/warpe-cl``."""
    env = os.environ.get("WARPE_CL_CACHE_DIR", "").strip()
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME", "").strip() or os.path.join(Path.home(), ".cache")
    return Path(base) / "warpe-cl"


def pip_driver_libraries() -> dict:
    """``{distribution: absolute library path}`` of the pip-installed OpenCL drivers present."""
    from importlib import metadata
    found = {}
    for dist_name, lib in PIP_DRIVERS.items():
        try:
            dist = metadata.distribution(dist_name)
        except metadata.PackageNotFoundError:
            continue
        for f in dist.files or ():
            if Path(str(f)).name == lib:
                path = Path(str(dist.locate_file(f))).resolve()
                if path.is_file():
                    found[dist_name] = str(path)
                    break
    return found


def _visible_icd_files() -> list:
    """The ``.icd`` files the loader would read without us: ``$OCL_ICD_VENDORS`` (a folder or
    one file) if set, else ``/etc/OpenCL/vendors``."""
    env = os.environ.get("OCL_ICD_VENDORS", "").strip()
    where = Path(env) if env else SYSTEM_VENDORS
    if where.is_file():
        return [where]
    if where.is_dir():
        return sorted(p for p in where.iterdir() if p.suffix == ".icd" and p.is_file())
    return []


def _icd_folder(entries: dict) -> Path:
    """A folder with one ``.icd`` file per entry ``{file name: library line}``, named by the
    hash of its contents and created atomically (safe for concurrent processes)."""
    text = "".join(f"{k}\0{v}\n" for k, v in sorted(entries.items()))
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    root = cache_dir() / "icd"
    folder = root / digest
    if folder.is_dir():
        return folder
    root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".icd-", dir=root))
    for name, line in entries.items():
        (tmp / name).write_text(line + "\n")
    try:
        os.replace(tmp, folder)
    except OSError:            # another process made the same folder first
        for p in tmp.iterdir():
            p.unlink()
        tmp.rmdir()
    return folder


@lru_cache(maxsize=None)
def register() -> dict:
    """Make pip-installed OpenCL drivers visible to the loader of this process and its children.

    Returns
    -------
    dict
        ``{distribution: library path}`` of the drivers registered (empty when there is none,
        when ``$WARPE_CL_PIP_DRIVERS`` is ``0``, or when the cache folder cannot be written).
    """
    if os.environ.get("WARPE_CL_PIP_DRIVERS", "1").strip() == "0":
        return {}
    libs = pip_driver_libraries()
    if not libs:
        return {}
    current = os.environ.get("OCL_ICD_VENDORS", "").strip()
    if current and Path(current).parent == cache_dir() / "icd":
        return libs             # done already (a parent process registered them)
    entries = {}
    for i, path in enumerate(_visible_icd_files()):
        try:
            line = path.read_text().strip()
        except OSError:
            continue
        if line:
            entries[f"{i:02d}-{path.name}"] = line
    present = set(entries.values())
    for dist_name, lib in libs.items():
        if lib not in present:
            entries[f"pip-{dist_name}.icd"] = lib
    try:
        folder = _icd_folder(entries)
    except OSError:
        return {}
    os.environ["OCL_ICD_VENDORS"] = str(folder)
    return libs
