"""How long numba takes to compile a loop's generated module, estimated from its length before it starts.

``engine="auto"`` compiles a loop not yet in the cache only when this
estimate is within :data:`AUTO_COMPILE_SECONDS`; a longer compile is left to
``engine="compiled"`` (the run goes on numpy meanwhile).

The estimate is linear in the generated lines: numba's type inference and
LLVM's passes cost about the same per straight-line statement, on top of the
integrators' fixed part (:mod:`blocks.engines.compiled.dopri`).  Measured on the
2-core development machine (CPU seconds of a first ``engine="compiled"`` run
with an empty ``DOBKIT_CACHE_DIR``, which is almost all compile; a least
squares fit gives 2.8 s + 1.37 ms per line, the constants below bound the
points from above but for the paper's loop, which also compiles called
kernels):

=====================================  ======  ===========  =========
loop                                   lines   measured s   estimate
=====================================  ======  ===========  =========
paper (RRPR, closed form)               1,132       5.6         4.7
scope4, M and h called                  1,980       5.3         6.0
scope4, M and h inlined                 3,022       7.1         7.5
UR5, M and h called                     5,114       9.0        10.7
UR5, M and h inlined                    8,064      13.6        15.1
Panda, M and h called                   7,669      12.6        14.5
Panda, M and h inlined                 14,250      23.1        24.4
=====================================  ======  ===========  =========

``benchmarks/bench_urdf_compile.py`` measures it again beside the estimate.
"""
from __future__ import annotations

__all__ = ["AUTO_COMPILE_SECONDS", "COMPILE_FIXED_S", "COMPILE_PER_LINE_S", "estimate_compile_seconds",
           "generated_lines"]

#: CPU seconds of compile ``engine="auto"`` spends on a loop that is not cached yet; a loop estimated longer runs
#: on numpy until ``engine="compiled"`` has compiled it once.  Every built-in scenario and every example arm
#: (`dobkit arms`: the largest, the Panda, about 14.5 s) is within it.
AUTO_COMPILE_SECONDS = 20.0
#: The part of a compile that does not grow with the loop (the integrators' functions), CPU s.
COMPILE_FIXED_S = 3.0
#: CPU seconds per generated line.
COMPILE_PER_LINE_S = 1.5e-3


def generated_lines(source: str) -> int:
    """Lines of a generated module's text (the loop's functions, without the integrators' template)."""
    return source.count("\n") + 1


def estimate_compile_seconds(lines: int) -> float:
    """Estimated CPU seconds numba takes to compile a loop of ``lines`` generated lines (and the integrators)."""
    return COMPILE_FIXED_S + COMPILE_PER_LINE_S * lines
