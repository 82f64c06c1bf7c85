"""hsmap simulate (not implemented yet)."""

from __future__ import annotations

import argparse

NAME = "simulate"
HELP = "(not implemented yet)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    pass


def run(args: argparse.Namespace) -> int:
    from ..errors import HsmapError

    raise HsmapError("'hsmap simulate' is not implemented yet")
