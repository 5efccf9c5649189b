"""What the resumable job commands (``dobkit sweep``, ``dobkit tune``) share: their common flags, and how a job
command ends -- one line on standard error for a bad file or budget (exit 2), an interrupt (130: every finished
piece of work is kept and the same command resumes) or memory running out (1)."""
from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from blocks.engines.budget import Budget, BudgetError, format_bytes
from blocks.scenarios.scenario import ScenarioError
from dobkit.arguments import add_budget_flags, whole_number

__all__ = ["add_job_parser", "add_job_flags", "run_job"]


def add_job_parser(subparsers, name: str, help: str, description: str, file: str,
                   file_help: str) -> argparse.ArgumentParser:
    """The job command's parser (``dobkit NAME FILE ...``) in ``subparsers``."""
    parser = subparsers.add_parser(name, help=help, description=description)
    parser.add_argument(file, help=file_help)
    return parser


def add_job_flags(parser: argparse.ArgumentParser, workers: str, check: str, restart: str, seconds: str) -> None:
    """``--workers``, ``--scheduler``, ``--no-progress``, ``--check``, ``--restart`` and the budget flags, with the
    job's words."""
    parser.add_argument("--workers", type=whole_number("--workers"), help=workers)
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="run the batches on the workers of this Dask distributed scheduler (tcp://host:8786) "
                             "instead of this machine's cores, or start one here with local[:N] (N worker "
                             "processes on 127.0.0.1, default one per core; closed when the command ends); needs "
                             "dask[distributed] (the 'cluster' extra)")
    parser.add_argument("--no-progress", action="store_true", help="no progress display")
    parser.add_argument("--check", action="store_true", help=check)
    parser.add_argument("--restart", action="store_true", help=restart)
    add_budget_flags(parser, seconds)


def run_job(command: str, args: argparse.Namespace, body: Callable[[argparse.Namespace, Budget, dict], int],
            errors: tuple[type[Exception], ...], work: str, where: str) -> int:
    """Run ``body(args, budget, state)`` and end as a job command ends (module docstring).

    Parameters
    ----------
    command : str
        ``"sweep"`` or ``"tune"``, for the messages.
    body : callable
        The command; it puts the job's log or folder in ``state[where]`` as soon as it is known.
    errors : tuple of exception types
        The job's own errors of a bad file or setting (exit 2), besides scenario, budget and value errors.
    work : str
        One piece of the job's work, for the messages: ``"run"``, ``"evaluation"``.
    """
    state: dict = {}
    try:
        budget = state["budget"] = Budget.from_env(memory=args.max_memory, steps=args.max_steps,
                                                   seconds=args.max_seconds)
        return body(args, budget, state)
    except (*errors, ScenarioError, BudgetError, ValueError) as err:     # ValueError: a budget that is not a number
        print(f"dobkit {command}: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        if where in state and not Path(state[where]).exists():       # stopped before its log was made
            print(f"dobkit {command}: interrupted before any {work} finished; nothing was written", file=sys.stderr)
            return 130
        at = f" in {state[where]}" if where in state else ""
        print(f"dobkit {command}: interrupted; every finished {work} is kept{at}, and the same command resumes",
              file=sys.stderr)
        return 130
    except MemoryError:
        limit = f" within the memory budget of {format_bytes(state['budget'].memory)}" if "budget" in state else ""
        print(f"dobkit {command}: out of memory{limit}: this machine has less to give; lower --max-memory (smaller "
              f"batches) or use fewer --workers; finished {work}s are kept and the same command resumes",
              file=sys.stderr)
        return 1
