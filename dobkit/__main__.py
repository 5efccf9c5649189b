"""``python -m dobkit``: the same as the ``dobkit`` command."""
import sys

from dobkit.cli import main

sys.exit(main())
