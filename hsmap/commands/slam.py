"""hsmap slam (not implemented yet)."""

from __future__ import annotations

import argparse

NAME = "slam"
HELP = "(not implemented yet)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    pass


def run(args: argparse.Namespace) -> int:
    from ..errors import HsmapError

    raise HsmapError("'hsmap slam' is not implemented yet")
