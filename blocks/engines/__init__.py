"""The engines: one simulator (:mod:`~blocks.engines.simulator`) stepping a diagram and a context, its monitor,
divergence rule and budget; the numpy, compiled (numba, C), GPU and sampled engines.  Nothing here imports a
scenario."""
from blocks.lazy import lazy_exports

__getattr__, __dir__ = lazy_exports(__name__, {}, globals())
