"""``python -m warpe_cl``: the same as the ``warpe-cl`` command."""
import sys

from .cli import main

sys.exit(main())
