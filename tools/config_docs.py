"""Write docs/config.md, the preset reference, from the schema table of warpe_cl/config.py.

    python tools/config_docs.py           # rewrite docs/config.md
    python tools/config_docs.py --check   # exit 1 if docs/config.md is out of date

tests/test_config.py::test_docs_config_md_is_up_to_date runs the same comparison.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from warpe_cl.config import REFERENCE_PATH, reference_markdown  # noqa: E402


def main(argv=None) -> int:
    """Write (or with ``--check`` compare) the reference; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true",
                        help="compare instead of writing; exit 1 if the file differs")
    args = parser.parse_args(argv)
    path = REPO / REFERENCE_PATH
    text = reference_markdown()
    if args.check:
        if not path.is_file() or path.read_text(encoding="utf-8") != text:
            print(f"{REFERENCE_PATH} is out of date: run python tools/config_docs.py",
                  file=sys.stderr)
            return 1
        print(f"{REFERENCE_PATH} is up to date")
        return 0
    path.write_text(text, encoding="utf-8")
    print(f"wrote {REFERENCE_PATH}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
