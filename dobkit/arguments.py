"""Argument types and flags the commands share, checked while the command line is parsed."""
from __future__ import annotations

import argparse
import math

from blocks.engines.budget import DEFAULT_MEMORY, DEFAULT_STEPS, ENVIRONMENT, format_bytes

__all__ = ["whole_number", "positive_number", "add_budget_flags"]


def whole_number(flag: str):
    """The type of a flag that takes a whole number >= 1 (``--workers 0``, ``-5``, ``1.5``, ``two`` are refused)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = 0
        if value < 1 or str(value) != text.strip().lstrip("+"):
            raise argparse.ArgumentTypeError(f"{flag} must be a whole number >= 1, got {text!r}")
        return value
    return parse


def positive_number(unit: str = ""):
    """The type of a flag that takes a finite number > 0 (in ``unit``)."""
    suffix = f" {unit}" if unit else ""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a number{suffix}, got {text!r}") from None
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"must be a finite number > 0{suffix}, got {text!r}")
        return value
    return parse


def add_budget_flags(parser: argparse.ArgumentParser, seconds_help: str) -> None:
    """``--max-memory``, ``--max-steps`` and ``--max-seconds`` (see :class:`blocks.engines.budget.Budget`)."""
    parser.add_argument("--max-memory", metavar="SIZE",
                        help=f"memory budget such as 8G (default {format_bytes(DEFAULT_MEMORY)}, or "
                             f"${ENVIRONMENT['memory']})")
    parser.add_argument("--max-steps", metavar="N",
                        help=f"integrator steps one run may take (default {DEFAULT_STEPS:.0e}, or "
                             f"${ENVIRONMENT['steps']})")
    parser.add_argument("--max-seconds", metavar="S",
                        help=f"wall-clock seconds; {seconds_help} (default: no limit, or ${ENVIRONMENT['seconds']})")
