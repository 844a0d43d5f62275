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

The folder lives in the cache folder (:func:`cache_dir`). Where that cannot be written (a
read-only home, ``$WARPE_CL_CACHE_DIR`` naming a file), dropping the registration would drop
Intel's runtime and renumber the devices, so that a job's ``--device 0:0`` lands on another
driver: :func:`usable_cache_dir` then makes a private temporary folder for this run (and its
child processes, through ``$WARPE_CL_CACHE_DIR``), says so in one warning line, and removes
it when the process that made it ends. The device numbering stays the same; the price is
that no verdict is kept from one run to the next.
"""
from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import tempfile
import warnings
from functools import lru_cache
from importlib import metadata
from pathlib import Path

from .errors import WarpeWarning

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


#: folders found writable (or made as a fallback) by this process: ``{asked: used}``
_usable: dict = {}


def _writable(folder: Path) -> str | None:
    """``None`` where ``folder`` exists or can be made, and a file can be made in it; else
    why not (one line)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".write-test-"):
            pass
    except OSError as err:
        return f"{type(err).__name__}: {err.strerror or err}"
    return None


def usable_cache_dir() -> Path:
    """The cache folder (:func:`cache_dir`) where it can be written, else a private temporary
    folder for this run.

    The fallback folder is made once per process, named in one
    :class:`~warpe_cl.errors.WarpeWarning` line (which folder failed, which is used, what it
    costs), handed to child processes through ``$WARPE_CL_CACHE_DIR`` (so a sweep's workers
    and the qualification's children share it and say nothing), and removed when this process
    ends.

    Returns
    -------
    Path
    """
    folder = cache_dir()
    if str(folder) in _usable:
        return _usable[str(folder)]
    problem = _writable(folder)
    if problem is None:
        _usable[str(folder)] = folder
        return folder
    try:
        private = Path(tempfile.mkdtemp(prefix="warpe-cl-cache-"))
    except OSError:            # no temporary folder either: the verdicts are not stored
        return folder
    atexit.register(shutil.rmtree, private, True)
    _usable[str(folder)] = _usable[str(private)] = private
    os.environ["WARPE_CL_CACHE_DIR"] = str(private)
    warnings.warn(f"the cache folder {folder} cannot be written ({problem}); using {private} "
                  "for this run: the OpenCL drivers keep their numbers, but no qualification "
                  "verdict is kept (each run checks its devices again, seconds to a minute); "
                  "set $WARPE_CL_CACHE_DIR to a writable folder", WarpeWarning, stacklevel=2)
    return private


def pip_driver_libraries() -> dict:
    """``{distribution: absolute library path}`` of the pip-installed OpenCL drivers present."""
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
    root = usable_cache_dir() / "icd"
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
        or when ``$WARPE_CL_PIP_DRIVERS`` is ``0``). Where the cache folder cannot be
        written, the registration goes to a private folder of this run
        (:func:`usable_cache_dir`); empty only where no temporary folder can be made either.
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


#: GPU drivers whose device shows in /dev while their OpenCL library may be unregistered:
#: ``(vendor, device nodes, OpenCL library file names, .icd file name)``
GPU_DRIVERS = (
    ("NVIDIA", ("/dev/nvidia0",), ("libnvidia-opencl.so.1", "libnvidia-opencl.so"), "nvidia.icd"),
    ("AMD", ("/dev/kfd",), ("libamdocl64.so",), "amdocl64.icd"),
)
#: where GPU images put the drivers' libraries (container runtimes: /usr/local/nvidia/lib64)
GPU_LIBRARY_DIRS = ("/usr/local/nvidia/lib64", "/usr/local/nvidia/lib",
                    "/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64",
                    "/usr/lib", "/opt/rocm/lib", "/opt/rocm/opencl/lib")


def unregistered_gpu_hint(gpu_listed: bool) -> str | None:
    """One line where a GPU is visible to the system but OpenCL lists none: a GPU's device
    node (``/dev/nvidia0``, ``/dev/kfd``) or its driver's OpenCL library
    (``libnvidia-opencl.so.1``, ``libamdocl64.so`` in :data:`GPU_LIBRARY_DIRS`) is there, and
    no ``.icd`` file registers it (issue 43: many GPU images ship the library without
    ``/etc/OpenCL/vendors/nvidia.icd``). The line names the library and how to register it
    without root (``$OCL_ICD_VENDORS``, docs/devices.md); where no library is found, what to
    install. Looks at the file system only.

    Parameters
    ----------
    gpu_listed : bool
        Whether OpenCL lists a GPU device (then there is nothing to say).

    Returns
    -------
    str or None
    """
    if gpu_listed:
        return None
    for vendor, nodes, libraries, icd_name in GPU_DRIVERS:
        present = [n for n in nodes if os.path.exists(n)]
        found = [str(Path(d) / name) for d in GPU_LIBRARY_DIRS for name in libraries
                 if (Path(d) / name).is_file()]
        if not present and not found:
            continue
        seen = ", ".join(present + found[:1])
        if not found:
            return (f"hint: an {vendor} GPU is visible to the system ({seen}) but not to OpenCL, "
                    f"and no {libraries[0]} was found in {', '.join(GPU_LIBRARY_DIRS)}: install "
                    f"its driver's OpenCL library, then register it (docs/devices.md)")
        folder = "$HOME/.opencl-vendors"
        return (f"hint: an {vendor} GPU is visible to the system ({seen}) but not to OpenCL: "
                f"register its driver's library without root: mkdir -p {folder} && "
                f"cp /etc/OpenCL/vendors/*.icd {folder}/ 2>/dev/null; "
                f"echo {found[0]} > {folder}/{icd_name} && export OCL_ICD_VENDORS={folder} "
                f"(docs/devices.md)")
    return None
