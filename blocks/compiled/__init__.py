"""The compiled engine: the loop's evaluation plan and its blocks' kernels turned into one numba-compiled module.

``blocks.simulate(..., engine="compiled")`` and ``simulate_batch(..., engine="compiled")``
run here.  numba is the optional extra ``dobkit[fast]``; without it every
engine but this one works, and ``engine="auto"`` (the default) uses the numpy
path.

How a loop becomes compiled code
--------------------------------
1. :func:`blocks.plan.make_plan` orders the blocks and records their input
   gathers and the outputs read from states (as for the numpy engine).
2. :mod:`blocks.compiled.trace` runs each block's kernels once on symbols
   and records the scalar operations they perform (a noise table is read in
   place at a traced index); a block whose kernels cannot be traced (the
   laceration path's phase logic) is called as the numba-compiled copy of
   its kernel (:mod:`blocks.compiled.jit`), which returns a tuple.
3. :mod:`blocks.compiled.codegen` writes the module: the loop's sources,
   right-hand side and outputs in plan order, the rows of
   :mod:`blocks.compiled.rows` beside them (lumped disturbance, tracking
   errors), plus the integrators of :mod:`blocks.compiled.dopri`
   (Dormand-Prince 5(4) with ``solve_ivp``'s step control and dense
   output; a batch's members in parallel, each with its own Dormand-Prince
   steps or all on one fixed-step RK4 schedule, metrics accumulated in the
   driver).  It is compiled by numba and cached on disk,
   keyed by its text and the kernels' source; :mod:`blocks.compiled.cache`
   checks the cached files before numba reads them.

The same generated text, run by Python on floats, is the ``fast`` engine's
right-hand side (:mod:`blocks.compiled.scalar`); that needs no numba.

A loop with the digital controller (a scenario's ``[controller]``, a
:class:`~blocks.hybrid.HybridSystem`) is generated the same way by
:func:`blocks.compiled.codegen.sampled_program` -- the tick (every block's
output, the sampled ones held, their updates), the plant's derivative with
the sampled outputs held, the outputs between ticks -- and run by
:class:`blocks.compiled.sampled.SampledEngine`: the numpy hybrid engine's
semantics and numbers, Dormand-Prince restarted at every tick.
:func:`blocks.sampled_batch.simulate_sampled_batch` runs many members of it
side by side.

Nothing of the loop is written here by hand: a change to a kernel or to the
interconnection changes the generated module.
"""
from __future__ import annotations

from .cache import CompiledCacheWarning
from .codegen import CompiledUnavailable, cache_dir
from .engine import METHODS, CompiledLoopEngine, unavailable_reason
from .jit import numba_or_none
from .sampled import SampledEngine, sampled_unavailable_reason

__all__ = ["CompiledLoopEngine", "CompiledUnavailable", "unavailable_reason", "numba_or_none", "cache_dir",
           "CompiledCacheWarning", "METHODS", "SampledEngine", "sampled_unavailable_reason"]
