"""Assembling the output Dataset (docs/interface.md §5), provenance and versions, and atomic output
writing.

Every file warpe-cl writes (results, figures, the sweep manifest, the verdict cache) goes
through a hidden temporary file in the destination folder, renamed over the destination only
once complete (:func:`write_netcdf`, :func:`write_text`, :class:`Outputs`): an error, a crash or
Ctrl-C never leaves a partial file, and the temporary file is removed on the way out.
"""
from __future__ import annotations

import datetime as _dt
import json
import os
import platform as _platform
import secrets
import signal
import sys
import threading
from pathlib import Path

import numpy as np

from .params import COMPONENTS, FATES, N_EMERGENCE

DERIVED = ("tau0", "omega", "extinction_per_m", "n_eff", "k_eff", "first_bf_time_ns",
           "specular_r0", "thickness_m", "porosity_factor", "matrix_absorption_per_m")


def package_version() -> str:
    """The installed version of warpe-cl ("unknown" in a bare checkout)."""
    try:
        from importlib.metadata import version
        return version("warpe-cl")
    except Exception:  # noqa: BLE001 - running from a checkout without metadata
        return "unknown"


def build_dataset(arrays: dict, counts, params, derived: dict, attrs: dict):
    """One scenario's Dataset.

    Parameters
    ----------
    arrays : dict
        Output of :func:`warpe_cl.tally.reduce_counts`.
    counts : Counts
        For ``photons`` and ``scattering_events``.
    params : WalkParams
        For the time edges (ns).
    derived : dict
        Derived radiative parameters (:func:`warpe_cl.radiative.radiative_parameters`).
    attrs : dict
        Provenance and configuration attributes.
    """
    import xarray as xr

    edges = np.asarray(params.time_edges, dtype=float)
    centres = np.sqrt(edges[:-1] * edges[1:]) if edges[0] > 0 else 0.5 * (edges[:-1] + edges[1:])
    ct = ("component", "time")
    ds = xr.Dataset(
        {
            "time_edges": ("time_edge", edges, {"units": "ns", "long_name": "time bin edges"}),
            "reflectance": (ct, arrays["reflectance"], {
                "units": "ns-1 sr-1",
                "long_name": "rays of the component leaving inside its FOV, per launched ray, "
                             "per sr, per ns (specular and bf_direct scaled by the roughness lobe)"}),
            "reflectance_stderr": (ct, arrays["reflectance_stderr"], {
                "units": "ns-1 sr-1", "long_name": "Poisson standard error of reflectance"}),
            "ray_count": (ct, arrays["ray_count"], {"units": "1", "long_name": "rays behind reflectance"}),
            "undersampled": (ct, arrays["undersampled"], {
                "long_name": "ray_count < min_rays (specular exempt)"}),
            "hemispherical_reflectance": (ct, arrays["hemispherical_reflectance"], {
                "units": "ns-1", "long_name": "rays of the component leaving at any angle, per "
                                              "launched ray, per ns"}),
            "fraction": ("component", arrays["fraction"], {
                "units": "1", "long_name": "rays of the component leaving at any angle and time, "
                                          "per launched ray"}),
            "early_fraction": ("component", arrays["early_fraction"], {
                "units": "1", "long_name": "rays of the component leaving before the first time "
                                          "edge, per launched ray (in fraction, in no time "
                                          "bin)"}),
            "solid_angle": ("component", arrays["omega_sr"], {
                "units": "sr", "long_name": "solid angle that reflectance is divided by"}),
            "fate_fraction": ("fate", arrays["fate_fraction"], {
                "units": "1", "long_name": "launched rays by fate (sums to 1)"}),
            "angular_reflectance": (("component", "emergence"), arrays["angular_reflectance"], {
                "units": "sr-1", "long_name": "time-integrated azimuth-averaged bidirectional "
                                              "reflectance, per 1 degree emergence bin"}),
            "photons": ((), np.int64(counts.photons), {"units": "1", "long_name": "rays launched"}),
            "scattering_events": ((), np.int64(counts.scattering_events), {
                "units": "1", "long_name": "volume scattering events over all rays"}),
            "mixed_history_fraction": ((), counts.mixed_history / counts.photons, {
                "units": "1", "long_name": "exits with both a volume scattering and a floor "
                                          "reflection (where the history and time-window rules "
                                          "can disagree), per launched ray"}),
        },
        coords={
            "time": ("time", centres, {"units": "ns", "long_name": "bin centre (geometric mean "
                                                                 "of the edges)"}),
            "component": ("component", list(COMPONENTS)),
            "fate": ("fate", list(FATES)),
            "emergence": ("emergence", np.arange(N_EMERGENCE) + 0.5, {
                "units": "deg", "long_name": "emergence angle in vacuum, bin centre"}),
        },
    )
    ds.attrs.update({k: derived[k] for k in DERIVED if k in derived})
    for key in ("material", "w", "number_density_per_m3", "n_rel"):
        values = [sp[key] for sp in derived.get("species", [])]
        if values:
            ds.attrs[f"species_{key}"] = values if key == "material" else np.asarray(values)
    ds.attrs.update(attrs)
    return ds


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


def _same_attr(a, b) -> bool:
    """Attribute equality that also holds for array attributes (species_w, ...)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return a is not None and b is not None and np.array_equal(a, b)
    return a == b


def _pad(ds, longest: dict):
    """``ds`` with each dimension of ``longest`` it has padded at its end, with NaN, to that
    length (``ds`` itself when none is shorter)."""
    widths = {d: (0, n - ds.sizes[d]) for d, n in longest.items()
              if d in ds.sizes and ds.sizes[d] < n}
    return ds.pad(widths, constant_values=np.nan) if widths else ds


def combine_scenarios(datasets: list, points: list, attrs: dict | None = None):
    """Stack scenario Datasets along ``scenario``.

    The swept values become coordinates, the per-scenario derived parameters (tau0, omega, ...)
    and Philox scenario keys become variables, attributes shared by every scenario stay
    attributes, and ``attrs`` (e.g. the whole preset with its sweep block) is added last.
    A dimension without coordinate whose length differs between scenarios (``photon``, the
    time tags of a photon-counting instrument) is padded at its end to the longest with NaN,
    as :func:`warpe_cl.instrument.output.build` pads it.
    """
    import xarray as xr

    longest = {}
    for ds in datasets:
        for dim, size in ds.sizes.items():
            if dim not in ds.indexes:
                longest[dim] = max(longest.get(dim, 0), size)
    datasets = [_pad(ds, longest) for ds in datasets]
    first = datasets[0].attrs            # an attribute varies if any scenario differs from
    varying = {k for k in {k for ds in datasets for k in ds.attrs}   # the first: O(N), not N^2
               if any(not _same_attr(ds.attrs.get(k), first.get(k)) for ds in datasets)}
    stripped = []
    for ds in datasets:
        ds = ds.copy()
        ds.attrs = {}               # dataset attributes only: variables keep their units
        stripped.append(ds)
    out = xr.concat(stripped, dim="scenario")
    out["time_edges"] = datasets[0]["time_edges"]   # shared by every scenario of a sweep
    out.attrs.update({k: v for k, v in datasets[0].attrs.items()
                      if k not in varying and k not in DERIVED})
    for k in DERIVED + ("scenario_key",):
        values = [ds.attrs.get(k) for ds in datasets]
        if all(v is not None for v in values):
            out[k] = ("scenario", np.asarray(values))
    for key in points[0]:
        labels = [json.dumps(p[key], sort_keys=True) if isinstance(p[key], (dict, list))
                  else str(p[key]) for p in points]
        out = out.assign_coords({key: ("scenario", np.asarray(labels))})
    out = out.assign_coords(scenario=np.arange(len(datasets)))
    out.attrs.update(attrs or {})
    return out


def write_netcdf(ds, path) -> Path:
    """Write ``ds`` as NetCDF-4 (h5netcdf) atomically: a temporary file in the same folder,
    renamed over ``path`` only once complete, so a crash or Ctrl-C never leaves a partial
    file (nor the temporary one)."""
    with Outputs() as outputs:
        outputs.netcdf(ds, path)
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


class Outputs:
    """Several output files written all or nothing (``warpe-cl run --out X.nc --plot X.png``).

    :meth:`stage` gives a hidden temporary path next to each destination; leaving the
    ``with`` block normally renames every staged file onto its destination, with SIGINT held
    back during the renames, so that Ctrl-C finds either none of the files or all of them.
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
        """A temporary path to write ``path``'s content to; its folder is created."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        self._staged.append((None, path))  # remembered before it exists: Ctrl-C while creating it
        tmp = _temporary_name(path)
        self._staged[-1] = (tmp, path)
        return tmp

    def netcdf(self, ds, path) -> None:
        """Stage ``path`` and write ``ds`` to it as NetCDF-4 (h5netcdf)."""
        ds.to_netcdf(self.stage(path), engine="h5netcdf", invalid_netcdf=False)

    def text(self, path, text: str) -> None:
        """Stage ``path`` and write ``text`` to it (UTF-8), flushed to disk."""
        with open(self.stage(path), "w", encoding="utf-8") as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())

    def __exit__(self, kind, value, tb) -> bool:
        try:
            if kind is None:
                with _sigint_held():
                    for tmp, path in self._staged:
                        os.replace(tmp, path)
        finally:
            for tmp, _ in self._staged:
                if tmp is not None and tmp.exists():
                    tmp.unlink()
            self._staged = []
        return False


class _sigint_held:
    """Hold SIGINT back (delivered on exit) in the main thread; a no-op elsewhere."""

    def __enter__(self):
        self._held = (hasattr(signal, "pthread_sigmask")
                      and threading.current_thread() is threading.main_thread())
        if self._held:
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        return self

    def __exit__(self, *exc):
        if self._held:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        return False
