"""A block's maths as kernel functions with bound parameters: :class:`blocks.kernels.bound.Kernels`, by the name the
diagram layer has always used."""
from __future__ import annotations

from blocks.kernels.bound import Kernels

__all__ = ["Kernels"]
