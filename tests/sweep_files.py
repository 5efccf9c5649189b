"""Files and the command line for the sweep tests: a short scenario, a sweep file that refers to it, ``dobkit sweep``."""
from __future__ import annotations

import argparse
from pathlib import Path

import blocks
from dobkit.sweep_commands import add_sweep_subcommand


def write_short_scenario(folder: Path, t_final: float) -> Path:
    """The first ``t_final`` seconds of the paper scenario (its 10 s path) as ``short.toml`` in ``folder``."""
    path = folder / "short.toml"
    short = blocks.load_scenario("paper").replace(simulation={"t_final": t_final}, trajectory={"duration": 10.0})
    path.write_text(short.to_toml(), encoding="utf-8")
    return path


def write_sweep(folder: Path, text: str, name: str = "s", scenario: str = "short.toml") -> Path:
    """A sweep file ``<name>.toml`` in ``folder``: ``scenario = ...`` followed by ``text``."""
    path = folder / f"{name}.toml"
    path.write_text(f'scenario = "{scenario}"\n' + text, encoding="utf-8")
    return path


def run_sweep_command(argv):
    """``dobkit sweep ...`` through its own subparser; returns the command's exit status."""
    parser = argparse.ArgumentParser(prog="dobkit")
    add_sweep_subcommand(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    return args.func(args)
