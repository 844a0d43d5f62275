"""Provenance and versions, and atomic output writing.

The output Dataset itself is assembled in :mod:`warpe_cl.dataset`, and results are read back
by :func:`warpe_cl.database.load_result`; this module imports neither.

Every file warpe-cl writes (results, figures, the sweep manifest, the verdict cache) goes
through a hidden temporary file in the destination folder, renamed over the destination only
once complete (:func:`write_netcdf`, :func:`write_text`, :class:`Outputs`): an error, a crash or
Ctrl-C never leaves a partial file, and the temporary file is removed on the way out. A file
replaced keeps its permission bits, a symbolic link is written through to its target, and a
NetCDF file that the folder has no room for is refused before HDF5 starts writing it.
"""
from __future__ import annotations

import datetime as _dt
import errno
import os
import platform as _platform
import secrets
import shutil
import signal
import stat
import sys
import threading
from io import BytesIO
from pathlib import Path

import numpy as np

from .errors import ConfigError


def json_default(value):
    """JSON fallback for the NumPy values a configuration may hold: arrays and NumPy scalars as
    Python lists and numbers (``tolist``), anything else as its text."""
    tolist = getattr(value, "tolist", None)
    return tolist() if tolist is not None else str(value)


def package_version() -> str:
    """The installed version of warpe-cl ("unknown" in a bare checkout)."""
    try:
        from importlib.metadata import version
        return version("warpe-cl")
    except Exception:  # noqa: BLE001 - running from a checkout without metadata
        return "unknown"


def utc_now() -> str:
    """The current UTC time as ISO 8601 to the second (``2025-01-31T12:00:00+00:00``)."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def versions(modules=("xarray", "pyopencl")) -> dict:
    """Versions of warpe-cl, Python and numpy, and of those of ``modules`` already imported.

    Parameters
    ----------
    modules : tuple of str
        Module names whose version is added when this process has imported them (none is
        imported here).

    Returns
    -------
    dict
        ``{"warpe_cl": ..., "python": ..., "numpy": ..., name: ...}`` (the sweep manifest's
        ``versions``; :func:`provenance` names them ``NAME_version``).
    """
    out = {"warpe_cl": package_version(), "python": sys.version.split()[0],
           "numpy": np.__version__}
    for name in modules:
        module = sys.modules.get(name)
        if module is not None:
            out[name] = getattr(module, "__version__", getattr(module, "VERSION_TEXT", "?"))
    return out


def provenance(extra: dict | None = None) -> dict:
    """Attributes every output file carries: versions, host, time, command line."""
    try:
        import pyopencl  # noqa: F401 - its version goes in the file where it is installed
    except Exception:  # noqa: BLE001 - pyopencl missing: the numpy engine still works
        pass
    v = versions(("pyopencl",))
    out = {
        "warpe_cl_version": v["warpe_cl"],
        "created_utc": utc_now(),
        "python_version": v["python"],
        "numpy_version": v["numpy"],
        "host": _platform.node(),
        "command": " ".join(sys.argv),
        "Conventions": "CF-1.8",
    }
    if "pyopencl" in v:
        out["pyopencl_version"] = v["pyopencl"]
    if extra:
        out.update(extra)
    return out


def write_netcdf(ds, path, key: str | None = None) -> Path:
    """Write ``ds`` as NetCDF-4 (h5netcdf) atomically: a temporary file in the same folder,
    renamed over ``path`` only once complete, so a crash or Ctrl-C never leaves a partial
    file (nor the temporary one). A full disk or a folder that cannot be written is one
    :class:`~warpe_cl.errors.ConfigError` naming ``key`` (:meth:`Outputs.netcdf`)."""
    with Outputs() as outputs:
        outputs.netcdf(ds, path, key=key)
    return Path(path)


def write_text(path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically, as :func:`write_netcdf` does, and flushed
    to disk before the rename (the sweep manifest)."""
    with Outputs() as outputs:
        outputs.text(path, text)
    return Path(path)


def _temporary_name(path: Path) -> Path:
    """A new hidden file ``.NAME.XXXXXXXX.tmp.EXT`` next to ``path`` (the extension kept, so
    that writers choosing a format by it, such as matplotlib, still do).

    Created as ``open(path, "w")`` would create it (read-write for all, less the umask), not
    private as :func:`tempfile.mkstemp` makes it: the renamed file is the result others read.
    """
    while True:
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp{path.suffix}")
        try:
            os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
            return tmp
        except FileExistsError:     # 2^32 names: another writer's, try the next
            continue


def _keep_mode(tmp: Path, path: Path) -> None:
    """Give ``tmp`` the permission bits of ``path`` when it exists, so that replacing a file
    keeps them (a file made private, 600, stays private)."""
    try:
        mode = stat.S_IMODE(os.stat(path).st_mode)
    except FileNotFoundError:
        return
    os.chmod(tmp, mode)


#: The errno values that mean "this folder cannot take the file": said in one line.
_STORAGE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EFBIG}


def storage_error(err: BaseException) -> str | None:
    """What the system said when a write failed for want of space or permission, else None.

    h5py and h5netcdf raise an OSError with ``errno`` set, or an OSError or RuntimeError
    whose message holds HDF5's ``errno = 28, error message = 'No space left on device'``;
    the exception's causes are searched too.

    Parameters
    ----------
    err : BaseException

    Returns
    -------
    str or None
        ``"No space left on device (ENOSPC)"`` and the like.
    """
    seen = set()
    while err is not None and id(err) not in seen:
        seen.add(id(err))
        number = getattr(err, "errno", None)
        if number in _STORAGE_ERRNOS:
            return f"{os.strerror(number)} ({errno.errorcode[number]})"
        text = str(err)
        for number in _STORAGE_ERRNOS:
            if os.strerror(number) in text or f"errno = {number}," in text:
                return f"{os.strerror(number)} ({errno.errorcode[number]})"
        err = err.__cause__ or err.__context__
    return None


def netcdf_size(ds) -> int:
    """The bytes a NetCDF file of ``ds`` takes, about and not less: its variables' bytes and
    its attributes' text, 5 % more, and HDF5's metadata (2 KiB a variable, 64 KiB for the
    file; a result of ``run`` takes 116 kB for 62 kB of variables and 45 variables)."""
    attrs = sum(len(str(v)) for v in ds.attrs.values())
    attrs += sum(len(str(v)) for var in ds.variables.values() for v in var.attrs.values())
    return int(1.05 * (int(ds.nbytes) + attrs)) + 2048 * len(ds.variables) + 2 ** 16


def _megabytes(n: int) -> str:
    return f"{n / 1e6:.3g}" if n < 1e8 else f"{n / 1e6:.0f}"


class Outputs:
    """Several output files written all or nothing (``warpe-cl run --out X.nc --plot X.png``).

    :meth:`stage` gives a hidden temporary path next to each destination; leaving the
    ``with`` block normally renames every staged file onto its destination, with SIGINT and
    SIGTERM held back during the renames, so that Ctrl-C or SIGTERM finds either none of the
    files or all of them.
    Leaving it by an exception (KeyboardInterrupt included) removes the staged files and
    leaves the destinations as they were.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> with Outputs() as out:
    ...     _ = out.stage(folder / "a.txt").write_text("complete")
    >>> sorted(p.name for p in folder.iterdir())
    ['a.txt']
    """

    def __init__(self):
        self._staged: list = []           # (temporary, destination)

    def __enter__(self) -> "Outputs":
        return self

    def stage(self, path) -> Path:
        """A temporary path to write ``path``'s content to; its folder is created.

        A ``path`` that is a symbolic link is written through: the temporary file is made
        next to the link's target, which the rename replaces (the link stays a link).
        """
        path = Path(path)
        if path.is_symlink():
            path = Path(os.path.realpath(path))
        path.parent.mkdir(parents=True, exist_ok=True)
        self._staged.append((None, path))  # remembered before it exists: Ctrl-C while creating it
        tmp = _temporary_name(path)
        self._staged[-1] = (tmp, path)
        return tmp

    def netcdf(self, ds, path, key: str | None = None) -> None:
        """Stage ``path`` and write ``ds`` to it as NetCDF-4 (h5netcdf).

        Parameters
        ----------
        ds : xarray.Dataset
        path : str or path
        key : str, optional
            The option or key naming the file in an error (``"--out"``); the path otherwise.

        Raises
        ------
        ConfigError
            Before writing, when the folder has less free space than the file needs (its
            variables' bytes and a margin: :func:`netcdf_size`); while writing, when the
            system refuses (no space left, quota, read-only file system, permission): one
            line, the temporary file removed. HDF5 writes the file into memory, which Python
            then writes to the disk: HDF5 never meets a full disk, on which it crashes.

        Notes
        -----
        The whole file is built in memory first (:func:`_netcdf_image`): the peak memory of a
        write is about twice the Dataset's.
        """
        path = Path(path)
        folder = Path(os.path.realpath(path)).parent
        need = netcdf_size(ds)
        try:
            free = shutil.disk_usage(folder).free if folder.is_dir() else None
        except OSError:
            free = None
        if free is not None and need > free:
            raise ConfigError(f"not enough space in {folder}: the result needs about "
                              f"{_megabytes(need)} MB, {_megabytes(free)} MB free; free some "
                              "space or give a name in another folder", key=key or str(path))
        # HDF5 writes into memory, and Python to the disk: HDF5 meeting a full disk itself
        # prints hundreds of lines and crashes the interpreter on its way out
        image = _netcdf_image(ds)
        try:
            with open(self.stage(path), "wb") as stream:
                stream.write(image.getbuffer())
                stream.flush()
                os.fsync(stream.fileno())
        except OSError as err:
            reason = storage_error(err)
            if reason is None:
                raise
            raise ConfigError(f"cannot write {path}: {reason}; nothing was written",
                              key=key or str(path)) from None

    def text(self, path, text: str) -> None:
        """Stage ``path`` and write ``text`` to it (UTF-8), flushed to disk."""
        with open(self.stage(path), "w", encoding="utf-8") as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())

    def __exit__(self, kind, value, tb) -> bool:
        try:
            if kind is None:
                with _stops_held():
                    for tmp, path in self._staged:
                        _keep_mode(tmp, path)
                        os.replace(tmp, path)
        finally:
            for tmp, _ in self._staged:
                if tmp is not None and tmp.exists():
                    tmp.unlink()
            self._staged = []
        return False


def _netcdf_image(ds) -> BytesIO:
    """``ds`` as the bytes of a NetCDF-4 file (h5netcdf), in memory.

    ``ds.to_netcdf(BytesIO(), engine="h5netcdf")`` takes xarray's write lock for its target
    (``xarray.backends.locks.get_write_lock``), which inside a Dask worker is a lock of the
    distributed scheduler named by the target; an in-memory target has no name it knows
    ("Semaphore or Lock ... not known"), and every scenario of a Dask sweep failed. So the
    store is opened here with a lock of its own (``H5NetCDFStore.open(..., lock=...)``, the
    public route xarray documents), no global configuration changed: the image is private
    to this call, so a plain thread lock is all it needs. The variables and attributes are
    those ``to_netcdf(path, engine="h5netcdf")`` writes (tested).
    """
    from xarray.backends import H5NetCDFStore
    if any(var.chunks for var in ds.variables.values()):
        ds = ds.compute()      # the store writes NumPy arrays at once; dask ones would wait
    image = BytesIO()
    store = H5NetCDFStore.open(image, mode="w", lock=threading.Lock(), invalid_netcdf=False)
    try:
        ds.dump_to_store(store)
    finally:
        store.close()
    return image


#: The signals that stop warpe-cl as Ctrl-C does (the command line turns SIGTERM, Slurm's time
#: limit, into the same KeyboardInterrupt): held back while staged files are renamed.
_STOPS = {signal.SIGINT, signal.SIGTERM}


class _stops_held:
    """Hold SIGINT and SIGTERM back (delivered on exit) in the main thread; a no-op
    elsewhere."""

    def __enter__(self):
        self._held = (hasattr(signal, "pthread_sigmask")
                      and threading.current_thread() is threading.main_thread())
        if self._held:
            signal.pthread_sigmask(signal.SIG_BLOCK, _STOPS)
        return self

    def __exit__(self, *exc):
        if self._held:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOPS)
        return False
