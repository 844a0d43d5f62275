"""Outputs are never clobbered nor lost (docs/interface.md §2.3): every output's format, folder
and name checked before any work; an existing file replaced only with ``--overwrite`` (its
permission bits kept, a symbolic link written through), an input never; the NetCDF result
written before the figure, so that a figure that fails does not cost it; a full disk one line
and exit 2, with no temporary file left."""
from __future__ import annotations

import errno
import os
import shutil
import stat
from collections import namedtuple

import pytest
import xarray as xr

from conftest import REPO, synthetic_database, synthetic_surface
from warpe_cl.cli import main

PRESET = REPO / "presets" / "radiative" / "slab_co2_1m.yaml"
RUN = ["--photons", "200", "--device", "numpy", "--quiet"]
KEY = "medium.thickness"


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


def _left(folder) -> list:
    """The names in ``folder``, hidden temporary files included."""
    return sorted(p.name for p in folder.iterdir())


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A surface result, BELA's shots of it (4 shots), and a 3-scenario database of
    synthetic surfaces swept along medium.thickness."""
    from warpe_cl.instrument import apply_instrument
    d = tmp_path_factory.mktemp("inputs")
    synthetic_database(d / "db.nc", KEY)
    surface = synthetic_surface(diffuse_integral=0.05, tau=2.0)
    surface.to_netcdf(d / "surface.nc", engine="h5netcdf")
    apply_instrument(surface, "bela", shots=4, seed=4).to_netcdf(d / "obs.nc",
                                                                 engine="h5netcdf")
    return d


def _argv(verb, files, out, *extra):
    """A command line of ``verb`` writing ``out`` (its inputs from ``files``)."""
    if verb == "run":
        return ["run", str(PRESET), "--out", str(out), *RUN, *extra]
    if verb == "instrument":
        return ["instrument", str(files / "surface.nc"), "--instrument", "bela", "--shots", "4",
                "--out", str(out), "--quiet", *extra]
    return ["invert", str(files / "obs.nc"), "--database", str(files / "db.nc"),
            "--out", str(out), "--quiet", *extra]


# --------------------------------------------------------------------------- formats, order

@pytest.mark.parametrize("verb", ["run", "instrument", "invert"])
@pytest.mark.parametrize("figure", ["x.pnng", "c", "x.nc"])
def test_a_figure_name_matplotlib_cannot_write_is_refused_before_any_work(
        tmp_path, capsys, files, monkeypatch, verb, figure):
    """`--plot X.pnng` (or `c`, or `X.nc`) used to walk every ray, then exit 1 with
    "Format 'pnng' is not supported" and write nothing."""
    import warpe_cl.api
    import warpe_cl.instrument
    import warpe_cl.inversion.invert

    def no_work(*args, **kwargs):
        raise AssertionError("the work started before the outputs were checked")
    for module, name in ((warpe_cl.api, "simulate"), (warpe_cl.instrument, "apply_instrument"),
                         (warpe_cl.inversion.invert, "invert")):
        monkeypatch.setattr(module, name, no_work)
    out = tmp_path / "out"
    out.mkdir()
    rc = main(_argv(verb, files, out / "r.nc", "--plot", str(out / figure)))
    err = _one_line(capsys)
    assert rc == 2, err
    assert f"--plot: {out / figure}:" in err and ".png, " in err and ".pdf" in err, err
    assert _left(out) == []


def test_plot_out_must_be_a_figure_format(tmp_path, capsys, files):
    """`plot --out X.txt` used to draw the figure, then exit 1."""
    rc = main(["plot", str(files / "surface.nc"), "--out", str(tmp_path / "x.txt")])
    err = _one_line(capsys)
    assert rc == 2 and "--out: " in err and "'.txt' is not a figure format" in err, err
    assert _left(tmp_path) == []


def test_a_figure_that_fails_does_not_cost_the_result(tmp_path, capsys, monkeypatch):
    """The NetCDF file is written, renamed into place, before the figure is drawn: a figure
    that fails is exit 1 with one line saying the result was written, and no figure and no
    temporary file are left."""
    import warpe_cl.plot

    def broken(ds, path, title=None):
        with open(path, "wb") as stream:
            stream.write(b"\x89PNG half")
        raise RuntimeError("no font\nfound")
    monkeypatch.setattr(warpe_cl.plot, "plot_waveform", broken)
    rc = main(["run", str(PRESET), "--out", str(tmp_path / "x.nc"), "--plot",
               str(tmp_path / "x.png"), *RUN])
    err = _one_line(capsys)
    assert rc == 1, err
    assert f"the figure {tmp_path / 'x.png'} could not be drawn (RuntimeError: no font found)" \
        in err and f"the result {tmp_path / 'x.nc'} was written" in err, err
    assert _left(tmp_path) == ["x.nc"]
    assert int(xr.load_dataset(tmp_path / "x.nc").photons) == 200


# --------------------------------------------------------------------------- never clobbered

@pytest.mark.parametrize("verb", ["run", "instrument", "invert"])
def test_an_existing_output_needs_overwrite(tmp_path, capsys, files, verb):
    """`run --out X.nc` over an existing X.nc used to replace it without a word."""
    out, png = tmp_path / "x.nc", tmp_path / "x.png"
    out.write_bytes(b"an older result")
    rc = main(_argv(verb, files, out))
    err = _one_line(capsys)
    assert rc == 2 and f"--out: {out} exists; give --overwrite" in err, err
    assert out.read_bytes() == b"an older result" and _left(tmp_path) == ["x.nc"]
    png.write_bytes(b"an older figure")            # --plot too, even with a new --out
    rc = main(_argv(verb, files, tmp_path / "y.nc", "--plot", str(png)))
    err = _one_line(capsys)
    assert rc == 2 and f"--plot: {png} exists; give --overwrite" in err, err
    assert _left(tmp_path) == ["x.nc", "x.png"]


def test_overwrite_keeps_the_mode_and_writes_through_a_link(tmp_path, capsys):
    """--overwrite replaces the file whole, keeps its permission bits (a private file stays
    600) and, for a symbolic link, replaces its target (the link stays a link)."""
    out = tmp_path / "x.nc"
    out.write_bytes(b"an older result")
    out.chmod(0o600)
    assert main(["run", str(PRESET), "--out", str(out), *RUN, "--overwrite"]) == 0
    assert stat.S_IMODE(out.stat().st_mode) == 0o600
    assert int(xr.load_dataset(out).photons) == 200
    target = tmp_path / "store" / "kept.nc"
    target.parent.mkdir()
    target.write_bytes(b"an older result")
    target.chmod(0o640)
    link = tmp_path / "link.nc"
    link.symlink_to(target)
    assert main(["run", str(PRESET), "--out", str(link), *RUN, "--overwrite"]) == 0
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert stat.S_IMODE(target.stat().st_mode) == 0o640
    assert int(xr.load_dataset(target).photons) == 200
    assert _left(target.parent) == ["kept.nc"] and _left(tmp_path) == ["link.nc", "store",
                                                                         "x.nc"]
    capsys.readouterr()


@pytest.mark.parametrize("verb", ["instrument", "invert"])
@pytest.mark.parametrize("how", ["same", "link", "plot"])
@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_an_input_is_never_an_output(tmp_path, capsys, files, verb, how, overwrite):
    """`invert OBS.nc --out OBS.nc` and `instrument S.nc --out S.nc` used to replace their own
    input; refused even with --overwrite, whatever the name used for it."""
    source = tmp_path / ("surface.nc" if verb == "instrument" else "obs.nc")
    shutil.copy(files / source.name, source)
    before = source.read_bytes()
    if how == "link":
        (tmp_path / "alias.nc").symlink_to(source)
    name = {"same": source, "link": tmp_path / "alias.nc", "plot": tmp_path / "y.nc"}[how]
    argv = [verb, str(source)] + (["--instrument", "bela", "--shots", "4"]
                                  if verb == "instrument" else
                                  ["--database", str(files / "db.nc")])
    argv += ["--out", str(name), *overwrite, "--quiet"]
    if how == "plot":         # a figure named as the input (a NetCDF file named .png)
        os.replace(source, tmp_path / "in.png")
        source = tmp_path / "in.png"
        argv[1] = str(source)
        argv += ["--plot", str(source)]
    rc = main(argv)
    err = _one_line(capsys)
    assert rc == 2 and "is an input of this command" in err, err
    assert "--plot: " in err if how == "plot" else "--out: " in err, err
    assert source.read_bytes() == before
    assert not (tmp_path / "y.nc").exists()


def test_plot_refuses_an_existing_figure_without_overwrite(tmp_path, capsys, files):
    png = tmp_path / "x.png"
    png.write_bytes(b"an older figure")
    rc = main(["plot", str(files / "surface.nc"), "--out", str(png)])
    err = _one_line(capsys)
    assert rc == 2 and f"--out: {png} exists; give --overwrite" in err, err
    assert png.read_bytes() == b"an older figure"


def test_sweep_takes_overwrite(tmp_path, capsys, monkeypatch):
    """`sweep --overwrite` reaches run_sweep (which refuses an existing unrelated X.nc or a
    non-empty folder without it)."""
    import warpe_cl.sweep
    seen = {}

    def run_sweep(preset, out, **kwargs):
        seen.update(kwargs)
        raise KeyboardInterrupt
    monkeypatch.setattr(warpe_cl.sweep, "run_sweep", run_sweep)
    assert main(["sweep", str(PRESET), "--out", str(tmp_path / "db"), "--overwrite"]) == 130
    assert seen["overwrite"] is True
    assert main(["sweep", str(PRESET), "--out", str(tmp_path / "db")]) == 130
    assert seen["overwrite"] is False
    capsys.readouterr()


# --------------------------------------------------------------------------- full disk

def test_a_full_disk_is_one_line_before_writing(tmp_path, capsys, monkeypatch):
    """A result larger than the free space is refused before HDF5 writes it (HDF5 used to
    crash on a full tmpfs, exit 139, hundreds of lines, a temporary file left)."""
    Usage = namedtuple("Usage", "total used free")
    real = shutil.disk_usage
    monkeypatch.setattr(shutil, "disk_usage", lambda path: Usage(real(path).total,
                                                                  real(path).total, 100_000))
    rc = main(["run", str(PRESET), "--out", str(tmp_path / "x.nc"), *RUN])
    err = _one_line(capsys)
    assert rc == 2, err
    assert f"--out: not enough space in {tmp_path}: the result needs about " in err, err
    assert " MB, 0.1 MB free" in err, err
    assert _left(tmp_path) == []


@pytest.mark.parametrize("number", [errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES])
def test_a_write_the_system_refuses_is_one_line(tmp_path, capsys, monkeypatch, number):
    """No space left, a quota, a read-only file system or a permission refused while the file
    is written (HDF5 writes into memory; Python writes that to the disk, and gets the OSError):
    one line, exit 2, no file and no temporary file left."""
    def fails(fd):
        raise OSError(number, os.strerror(number))
    monkeypatch.setattr(os, "fsync", fails)
    rc = main(["run", str(PRESET), "--out", str(tmp_path / "x.nc"), *RUN])
    err = _one_line(capsys)
    assert rc == 2, err
    assert f"--out: cannot write {tmp_path / 'x.nc'}: {os.strerror(number)} " \
           f"({errno.errorcode[number]}); nothing was written" in err, err
    assert _left(tmp_path) == []


def test_another_write_error_still_leaves_nothing(tmp_path, capsys, monkeypatch):
    def fails(fd):
        raise OSError(errno.EIO, "Input/output error")
    monkeypatch.setattr(os, "fsync", fails)
    rc = main(["run", str(PRESET), "--out", str(tmp_path / "x.nc"), *RUN])
    err = _one_line(capsys)
    assert rc == 1 and "OSError: [Errno 5] Input/output error" in err, err
    assert _left(tmp_path) == []
