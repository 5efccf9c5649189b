"""Scenarios: the TOML files shipped here, the scenario object and its one key checker, gains."""
from blocks.lazy import lazy_exports

__getattr__, __dir__ = lazy_exports(__name__, {}, globals())
