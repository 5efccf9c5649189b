"""The compiled engine: the loop's evaluation plan and its blocks' kernels turned into one numba-compiled module.

``blocks.simulate(..., engine="compiled")`` and ``simulate_batch(..., engine="compiled")``
run here.  numba is the optional extra ``dobkit[fast]``; without it every
engine but this one works, and ``engine="auto"`` (the default) uses the numpy
path.

How a loop becomes compiled code
--------------------------------
1. :func:`blocks.diagram.plan.make_plan` orders the blocks and records their input
   gathers and the outputs read from states (as for the numpy engine).
2. :mod:`blocks.kernels.trace` runs each block's kernels once on symbols
   and records the scalar operations they perform (a noise table is read in
   place at a traced index); a block whose kernels cannot be traced (the
   laceration path's phase logic) is called as the numba-compiled copy of
   its kernel (:mod:`blocks.engines.compiled.jit`), which returns a tuple.
3. :mod:`blocks.engines.compiled.codegen` writes the module: the loop's sources,
   right-hand side and outputs in plan order, the rows of
   :mod:`blocks.engines.compiled.rows` beside them (lumped disturbance, tracking
   errors), plus the integrators of :mod:`blocks.engines.compiled.dopri`
   (Dormand-Prince 5(4) with ``solve_ivp``'s step control and dense
   output; a batch's members in parallel, each with its own Dormand-Prince
   steps or all on one fixed-step RK4 schedule, metrics accumulated in the
   driver).  It is compiled by numba and cached on disk,
   keyed by its text and the kernels' source; :mod:`blocks.engines.compiled.cache`
   checks the cached files before numba reads them.

The same generated text, run by Python on floats, is the ``fast`` engine's
right-hand side (:mod:`blocks.engines.compiled.scalar`); that needs no numba.

A loop with the digital controller (a scenario's ``[controller]``, a
:class:`~blocks.engines.hybrid.HybridSystem`) is generated the same way by
:func:`blocks.engines.compiled.codegen.sampled_program` -- the tick (every block's
output, the sampled ones held, their updates), the plant's derivative with
the sampled outputs held, the outputs between ticks -- and run by
:class:`blocks.engines.compiled.sampled.SampledEngine`: the numpy hybrid engine's
semantics and numbers, Dormand-Prince restarted at every tick.
:func:`blocks.figure2.sampled_batch.simulate_sampled_batch` runs many members of it
side by side.

Nothing of the loop is written here by hand: a change to a kernel or to the
interconnection changes the generated module.
"""
from __future__ import annotations

from blocks.engines.compiled.cache import CompiledCacheWarning
from blocks.engines.compiled.codegen import CompiledUnavailable, cache_dir
from blocks.engines.compiled.engine import METHODS, CompiledLoopEngine, unavailable_reason
from blocks.engines.compiled.jit import numba_or_none
from blocks.engines.compiled.sampled import SampledEngine, sampled_unavailable_reason

__all__ = ["CompiledLoopEngine", "CompiledUnavailable", "unavailable_reason", "numba_or_none", "cache_dir",
           "CompiledCacheWarning", "METHODS", "SampledEngine", "sampled_unavailable_reason"]
