"""dobkit's command line: ``dobkit ...`` or ``python -m dobkit ...``.

The toolkit itself is three packages, ``blocks``, ``analysis`` and ``fmu``;
this package only composes them into commands.
"""
from blocks import __version__

__all__ = ["__version__"]
