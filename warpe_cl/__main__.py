"""``python -m warpe_cl``: the same as the ``warpe-cl`` command.

Ctrl-C before :func:`warpe_cl.cli.main` has started (while the interpreter loads it) is one
line and exit 130 too, not a traceback.
"""
import sys

try:
    from .cli import main
except KeyboardInterrupt:
    print("warpe-cl: interrupted", file=sys.stderr)
    sys.exit(130)

sys.exit(main())
