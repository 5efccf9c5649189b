"""The diagram: blocks and what they promise the engines (:mod:`~blocks.diagram.contract`), the evaluation plan,
and the Figure-2 blocks themselves (trajectory, controller, plant, observer; their sampled forms)."""
from blocks.lazy import lazy_exports

__getattr__, __dir__ = lazy_exports(__name__, {}, globals())
