"""The Figure-2 layer: a scenario turned into diagram + context + bounds + estimate, its runs (continuous and
sampled), batches of members, the derived signals and the tracking metrics."""
from blocks.lazy import lazy_exports

__getattr__, __dir__ = lazy_exports(__name__, {}, globals())
