"""OpenCL platforms and devices: listing, probing, and building programs.

The kernels live in ``cl/`` (installed as the package data ``warpe_cl.cl``). A program is
the concatenation of its files in a fixed order (those of its precision, lane width and
driver picked by the host from its build options, :func:`program_files`), each preceded by a
``#line 1 "file"`` directive so that compiler messages name the real file and line (the
sasmodels way); the hash of the files' contents and the build options (:func:`source_hash`, not of that text, which
carries the install path) identifies the kernel in every output file.

This module knows what a device is, never whether to trust it: choosing one
(:func:`warpe_cl.qualify.select_device`) and its verdicts live in :mod:`warpe_cl.qualify`,
which builds on this one. A device is *usable* only once it has compiled our self-test
program (:func:`probe`) and passed the known-answer walk of :mod:`warpe_cl.qualify` (ray by
ray against the NumPy reference, in a child process, cached per user): an OpenCL driver that
lists a device but cannot build for it, or builds kernels that compute wrong numbers (PoCL 3.0 from pip on AVX-512 CPUs that its
LLVM 14 does not know: every ray "specular" at 8 lanes, an abort at 16), is skipped or held to
the lane widths that pass, with its reason.
"""
from __future__ import annotations

import hashlib
import os
import warnings
from dataclasses import dataclass
from functools import lru_cache
from importlib.resources import files
from pathlib import Path

from .drivers import register
from .errors import DeviceError

SELFTEST_FILES = ("real.h", "lanes.h", "philox.h", "fresnel.h", "scatter.h", "score.h",
                  "selftest.cl")

INSTALL_HINT = (
    "install an OpenCL driver: on Linux x86-64 `pip install intel-opencl-rt intel-cmplr-lib-rt` "
    "(Intel's CPU runtime, also on AMD CPUs; warpe-cl registers it), or `pip install "
    "pocl-binary-distribution` (PoCL 3.0), or on Debian/Ubuntu `sudo apt-get install "
    "pocl-opencl-icd`, or your GPU vendor's driver; `--device numpy` runs the slow reference "
    "walk without OpenCL (docs/devices.md)")


def kernel_dir() -> Path:
    """Folder holding the OpenCL sources of this very package: ``warpe_cl/cl/`` when installed
    (package data), ``cl/`` beside ``warpe_cl/`` in a checkout. The package's own location
    comes first, so that a checkout imported through ``PYTHONPATH`` reads its own kernels even
    where another checkout is installed in development mode; the import system is the last
    resort (a zipped install)."""
    here = Path(__file__).resolve().parent
    for folder in (here / "cl", here.parent / "cl"):
        if (folder / "walk.cl").is_file():
            return folder
    try:
        path = Path(str(files("warpe_cl.cl")))
        if (path / "walk.cl").is_file():
            return path
    except (ImportError, ModuleNotFoundError, TypeError):
        pass
    raise DeviceError(f"the OpenCL sources (walk.cl) are missing beside {here}")


#: The lane widths that have their files (cl/lanes_N.h); 1 is cl/lanes_scalar.h
VECTOR_WIDTHS = (2, 4, 8, 16)


def build_switches(options=()) -> tuple:
    """The switches of a build that pick its files (:func:`program_files`): its precision
    (``"single"``, or ``"double"`` with ``-DWARPE_DOUBLE``), its lane width
    (``-DWARPE_LANES=N``, 1 without it) and whether it keeps OpenCL's built-ins
    (``-DWARPE_BUILTINS``, warpe_cl/engine.py ``driver_options``)."""
    precision, lanes, builtins = "single", 1, False
    for option in options:
        if option == "-DWARPE_DOUBLE":
            precision = "double"
        elif option.startswith("-DWARPE_LANES="):
            lanes = int(option.split("=", 1)[1])
        elif option == "-DWARPE_BUILTINS":
            builtins = True
    return precision, lanes, builtins


def _parts(name: str, precision: str, lanes: int, builtins: bool) -> tuple:
    """The files of ``name`` in a build with these switches, in order (docs/walk.md §5.1)."""
    driver = "builtins" if builtins else "inline"
    if name == "real.h":
        return ("real.h", f"real_{precision}.h")
    if name == "lanes.h":
        if lanes == 1:
            shape = ("lanes_scalar.h",)
        elif lanes in VECTOR_WIDTHS:
            shape = (f"lanes_{lanes}.h", "lanes_vector.h", f"lanes_vector_{driver}.h")
        else:
            raise ValueError(f"no kernel files for {lanes} lanes (1, 2, 4, 8 or 16)")
        return ("lanes.h",) + shape + (f"lanes_{driver}.h",)
    if name in ("scatter.h", "tally.h"):      # their functions call the precision's parts
        return (f"{name[:-2]}_{precision}.h", name)
    if name == "score.h":                     # its parts use score.h's SCORE_STEP
        return (name, f"score_{precision}.h")
    return (name,)


def program_files(names, options=()) -> tuple:
    """The files compiled for the program ``names`` (such as ``WALK_FILES``) with the build
    ``options``, in order: each name, with the parts of the build's precision, lane width and
    driver that the host picks for it (:func:`build_switches`), where the preprocessor used to
    (docs/walk.md §5.1): ``real.h`` and ``real_single.h`` or ``real_double.h``; ``lanes.h``
    and ``lanes_scalar.h`` or ``lanes_N.h``, ``lanes_vector.h`` and ``lanes_vector_builtins.h``
    or ``lanes_vector_inline.h``, then ``lanes_builtins.h`` or ``lanes_inline.h``;
    ``scatter_P.h`` and ``tally_P.h`` before, ``score_P.h`` after their headers."""
    switches = build_switches(options)
    return tuple(part for name in names for part in _parts(name, *switches))


def every_program_file(names) -> tuple:
    """Every file that some build of the program ``names`` compiles (:func:`program_files` of
    every precision, lane width and driver), each once, in order: what :func:`source_hash`
    covers."""
    out = {}
    for name in names:
        for precision in ("single", "double"):
            for lanes in (1,) + VECTOR_WIDTHS:
                for builtins in (False, True):
                    out.update(dict.fromkeys(_parts(name, precision, lanes, builtins)))
    return tuple(out)


def assemble_source(names, folder: Path | None = None) -> str:
    """Join the named files of ``folder`` (default :func:`kernel_dir`) with ``#line``
    directives, which name each file by its absolute path for the compiler's messages. The
    names are files, as :func:`program_files` gives them for a build."""
    folder = Path(folder) if folder is not None else kernel_dir()
    parts = []
    for name in names:
        path = folder / name
        parts.append(f'#line 1 "{path}"\n{path.read_text()}\n')
    return "".join(parts)


def source_hash(names, options=(), folder: Path | None = None) -> str:
    """SHA-256 of a program: its files' names and contents, in order, then its build options.

    It identifies what is compiled -- the sources, and the ``-D`` options given -- and nothing
    else. The files are every file of the program that some build compiles
    (:func:`every_program_file`: the parts of every precision, lane width and driver), so that
    one hash serves every build and changes with any file a build may read; not the folder
    the sources were read from (the ``#line`` paths of
    :func:`assemble_source`), so the same kernel has the same hash in every checkout and
    installation. The ``kernel_sha256`` of the output files is this hash of the walk's files
    and its layout macros (warpe_cl/engine.py ``walk_source_hash``).

    Parameters
    ----------
    names : sequence of str
        The program's files, as the program lists them (``WALK_FILES``), in order.
    options : sequence of str
        Its build options (``()``: the sources alone).
    folder : Path, optional
        Where the files are (default :func:`kernel_dir`).

    Returns
    -------
    str
        64 hexadecimal digits.
    """
    folder = Path(folder) if folder is not None else kernel_dir()
    h = hashlib.sha256()
    for name in every_program_file(names):
        data = (folder / name).read_bytes()
        h.update(f"file {name} {len(data)}\n".encode())
        h.update(data)
    for option in options:
        h.update(f"option {len(option)}\n{option}".encode())
    return h.hexdigest()


@dataclass(frozen=True)
class DeviceInfo:
    """What a user needs to know about one OpenCL device."""

    platform_index: int
    device_index: int
    platform: str
    platform_version: str
    device: str
    kind: str           # "cpu", "gpu" or "other"
    driver: str
    compute_units: int
    fp64: bool
    #: the driver's preferred vector widths (CL_DEVICE_PREFERRED_VECTOR_WIDTH_FLOAT, _DOUBLE):
    #: 1 where it vectorises scalar code itself (Intel's CPU runtime), the SIMD register's
    #: width where it wants vectors written out (PoCL: 8 floats with AVX2, 16 with AVX-512)
    vector_float: int = 1
    vector_double: int = 1

    @property
    def spec(self) -> str:
        """The ``--device`` spelling that picks this device."""
        return f"{self.platform_index}:{self.device_index}"

    def preferred_width(self, precision: str) -> int:
        """The driver's preferred vector width for ``precision`` (``single`` or ``double``)."""
        return self.vector_double if precision == "double" else self.vector_float

    def describe(self) -> str:
        return (f"{self.spec}  {self.kind}  {self.device} | {self.platform} {self.platform_version} "
                f"| driver {self.driver} | {self.compute_units} compute units"
                f"{'' if self.fp64 else ' | no fp64'}")


def _cl():
    register()          # pip-installed drivers (Intel's CPU runtime), before the first CL call
    import pyopencl as cl
    return cl


def list_devices():
    """Every OpenCL device as ``(DeviceInfo, pyopencl.Device)``; empty when there is no platform."""
    cl = _cl()
    try:
        platforms = cl.get_platforms()
    except cl.Error:
        return []
    out = []
    for pi, platform in enumerate(platforms):
        try:
            devices = platform.get_devices()
        except cl.Error:
            continue
        for di, dev in enumerate(devices):
            kind = ("gpu" if dev.type & cl.device_type.GPU else
                    "cpu" if dev.type & cl.device_type.CPU else "other")
            info = DeviceInfo(pi, di, platform.name.strip(), platform.version.strip(),
                              dev.name.strip(), kind, dev.driver_version.strip(),
                              int(dev.max_compute_units), bool(dev.double_fp_config),
                              int(dev.preferred_vector_width_float),
                              int(dev.preferred_vector_width_double))
            out.append((info, dev))
    return out


@lru_cache(maxsize=None)
def context_and_queue(device):
    """One context and in-order queue per device, kept for the process."""
    cl = _cl()
    ctx = cl.Context([device])
    return ctx, cl.CommandQueue(ctx)


@lru_cache(maxsize=None)
def build_program(device, names: tuple, options: tuple):
    """Build the program made of ``names`` with ``-D`` options for ``device`` and return it:
    the files of :func:`program_files` for those options.

    pyopencl and PoCL cache binaries on disk (keyed by the source text and the options), so a
    second process rebuilds nothing. What identifies the kernel in output files is
    :func:`source_hash` (computed once per process by its users, not per build).
    """
    ctx, _ = context_and_queue(device)
    return build_source(ctx, assemble_source(program_files(names, options)), options)


#: Single-precision division and square root correctly rounded: OpenCL allows 2.5 and 3 ulp
#: without it, and NVIDIA's driver takes that freedom, so that its walks left the CPUs' bits
#: (issue 43: ray counts of the paper's presets one ray off). Given to every program built on
#: a device that offers it (CL_FP_CORRECTLY_ROUNDED_DIVIDE_SQRT); CPUs round so already.
EXACT_DIVIDE_SQRT = "-cl-fp32-correctly-rounded-divide-sqrt"


def exact_options(device) -> tuple:
    """The build options that make ``device`` (a pyopencl Device) round single-precision
    division and square root as IEEE 754 does: :data:`EXACT_DIVIDE_SQRT` where the device
    offers it, nothing elsewhere (its results may then leave other devices' bits)."""
    cl = _cl()
    exact = cl.device_fp_config.CORRECTLY_ROUNDED_DIVIDE_SQRT
    return (EXACT_DIVIDE_SQRT,) if device.single_fp_config & exact else ()


def build_source(ctx, source: str, options=()):
    """``pyopencl.Program(ctx, source).build(options)``, quiet: without pyopencl's "Non-empty
    compiler output" warning (Intel's compiler always reports its vectorisation), and with the
    OpenCL option ``-w``, no compiler warnings (PoCL's clang, on a CPU without AVX-512, warns
    that every 16-wide vector handed to a built-in "changes the ABI", a few hundred times per
    kernel, and prints "N warnings generated." on the terminal itself). ``-w`` changes no code.
    Every program gets :func:`exact_options` of its device: division and square root
    correctly rounded, as the walk's same bits on every device need.
    The kernels' correctness is what the qualification checks (docs/devices.md).
    ``WARPE_CL_DEBUG=1`` shows both."""
    cl = _cl()
    options = list(options) + [o for o in exact_options(ctx.devices[0]) if o not in options]
    debug = os.environ.get("WARPE_CL_DEBUG", "") == "1"
    if not debug:
        options.append("-w")
    with warnings.catch_warnings():
        if not debug:
            warnings.filterwarnings("ignore", message="Non-empty compiler output")
        return cl.Program(ctx, source).build(options=options)


def _explain_build_failure(err: Exception) -> str:
    text = str(err)
    if "unknown target CPU" in text:
        return ("its compiler does not know this CPU (\"unknown target CPU 'generic'\": PoCL 3.0 "
                "from pip is built on LLVM 14, older than this processor)")
    lines = [ln.strip() for ln in text.splitlines() if "error" in ln.lower()]
    return "it failed to build the self-test kernels: " + (lines[0] if lines else text.splitlines()[0])


_probe_cache = {}


def probe(device) -> str | None:
    """Build the self-test program on ``device``; ``None`` if it works, else the reason."""
    key = device.int_ptr
    if key not in _probe_cache:
        cl = _cl()
        try:
            options = ("-DWARPE_DOUBLE",) if device.double_fp_config else ()
            build_program(device, SELFTEST_FILES, options)
            _probe_cache[key] = None
        except (cl.Error, RuntimeError) as err:
            _probe_cache[key] = _explain_build_failure(err)
    return _probe_cache[key]


def candidates(spec: str, devices):
    """The devices matching ``spec``, in order of preference, without probing them.

    Parameters
    ----------
    spec : str
        ``auto`` (GPUs, then CPUs, then the others), ``cpu``, ``gpu``, ``P`` or ``P:D``
        (platform and device index), or a substring of the device or platform name.
    devices : list
        ``(DeviceInfo, pyopencl.Device)`` pairs, as :func:`list_devices` gives them.

    Returns
    -------
    list
        The pairs of ``devices`` that match (empty when none does).
    """
    s = spec.strip()
    if s == "auto":
        gpus = [d for d in devices if d[0].kind == "gpu"]
        cpus = [d for d in devices if d[0].kind == "cpu"]
        others = [d for d in devices if d[0].kind == "other"]
        return gpus + cpus + others
    if s in ("cpu", "gpu"):
        return [d for d in devices if d[0].kind == s]
    parts = s.split(":")
    if all(p.isdigit() for p in parts) and len(parts) in (1, 2):
        pi = int(parts[0])
        di = int(parts[1]) if len(parts) == 2 else 0
        return [d for d in devices if d[0].platform_index == pi and d[0].device_index == di]
    low = s.lower()
    return [d for d in devices if low in d[0].device.lower() or low in d[0].platform.lower()]


def resolve_spec(spec: str | None = None) -> str:
    """The device spec in force: the argument, else $WARPE_CL_DEVICE, else $PYOPENCL_CTX, else auto."""
    for value in (spec, os.environ.get("WARPE_CL_DEVICE"), os.environ.get("PYOPENCL_CTX")):
        if value is not None and str(value).strip() != "":
            return str(value).strip()
    return "auto"
