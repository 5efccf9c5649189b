"""What the command line needs around a run: result files, progress lines, worker counts."""
from blocks.lazy import lazy_exports

__getattr__, __dir__ = lazy_exports(__name__, {}, globals())
