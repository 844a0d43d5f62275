#!/usr/bin/env python3
"""The answers of docs/design.md §5 in one command: the bundled design studies run, and their
tables written with the tree that made them.

    python tools/design_answers.py --out DIR [--study NAME ...] [--reuse]

For each study of ``presets/design/`` named (default: ``wavelengths`` and ``paper``, the two
that docs/design.md §5.1 and §5.2 read), ``warpe-cl design presets/design/NAME.yaml --out
DIR/NAME`` sweeps its families (resumed: scenarios already in DIR/NAME/databases/ are not
walked again) and computes the expected widths; its design.nc, summary.txt and figures (the
detectability maps and the ranking) stay in DIR/NAME/. ``--reuse`` takes a study's
DIR/NAME/design.nc as it is where one exists (the tables of an earlier run, written again).

DIR/answers.txt then holds the tree it was written on (``git describe --dirty``) and, for
each study, the command, when its design.nc was made (and whether it was reused), and the
summary tables of ``warpe_cl.design.result.summary_markdown``: one table per family,
the median width ratio of every key and derived quantity over the family with the share of
its surfaces constrained, and the shares detected, told from their neighbours and from the
other families. docs/design.md §5 quotes those tables as they are. The sweeps and widths
take their time once (docs/design.md §5 gives it); ``--reuse`` writes the tables again in
seconds. Bad input: one line, exit 2.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import xarray as xr

from warpe_cl.catalog import presets_dir
from warpe_cl.cli import main as warpe_cl_main
from warpe_cl.design.result import summary_markdown

from figure_provenance import tree_name

#: The studies docs/design.md §5 answers from, in its order.
STUDIES = ("wavelengths", "paper")


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="folder of the studies and answers.txt")
    p.add_argument("--study", nargs="+", default=list(STUDIES),
                   help="study names of presets/design/ (default: wavelengths paper)")
    p.add_argument("--reuse", action="store_true",
                   help="take DIR/NAME/design.nc as it is where it exists")
    args = p.parse_args(argv)
    if Path(args.out).exists() and not Path(args.out).is_dir():
        print(f"design_answers: --out {args.out}: a file; give a folder (made if missing)",
              file=sys.stderr)
        raise SystemExit(2)
    known = sorted(f.stem for f in (presets_dir() / "design").glob("*.yaml"))
    for name in args.study:
        if name not in known:
            print(f"design_answers: --study {name!r}: not a study of presets/design/ "
                  f"(there: {', '.join(known)})", file=sys.stderr)
            raise SystemExit(2)
    return args


def run_study(name: str, out: Path, reuse: bool) -> tuple:
    """The design study ``name`` into ``out/name``: run (or, with ``reuse``, read); returns
    (its dataset, the command that made it, whether it was reused, seconds)."""
    study = presets_dir() / "design" / f"{name}.yaml"
    folder = out / name
    command = f"warpe-cl design presets/design/{name}.yaml --out {folder}"
    t0 = time.perf_counter()
    reused = reuse and (folder / "design.nc").is_file()
    if not reused:
        code = warpe_cl_main(["design", str(study), "--out", str(folder), "--overwrite"])
        if code != 0:
            raise SystemExit(code)
    with xr.open_dataset(folder / "design.nc", engine="h5netcdf") as ds:
        return ds.load(), command, reused, time.perf_counter() - t0


def answers_markdown(studies: list, tree: str) -> str:
    """answers.txt: per study, its command and when its design.nc was made (and whether this
    run reused it), then its summary tables (their title line dropped: the study's heading
    replaces it)."""
    out = ["# The design studies of docs/design.md §5", "",
           f"Written by `python tools/design_answers.py` on tree {tree}.", ""]
    for name, ds, command, reused in studies:
        body = summary_markdown(ds).split("\n", 1)[1].lstrip("\n")
        made = ds.attrs.get("created_utc", "at an unknown time")
        note = (f"design.nc of {made}, reused (--reuse), not computed by this run" if reused
                else f"computed by this run, design.nc of {made}")
        out += [f"## Study {name}", "", f"    {command}", "", f"({note}.)", "",
                body.replace("\n## ", "\n### ").rstrip(), ""]
    return "\n".join(out)


def main(argv=None) -> int:
    args = parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    done = []
    for name in args.study:
        ds, command, reused, seconds = run_study(name, out, args.reuse)
        print(f"design_answers: {name}: {seconds:.0f} s", flush=True)
        done.append((name, ds, command, reused))
    path = out / "answers.txt"
    path.write_text(answers_markdown(done, tree_name()) + "\n")
    print(f"design_answers: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
