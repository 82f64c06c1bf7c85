"""hsmap reproduce (not implemented yet)."""

from __future__ import annotations

import argparse

NAME = "reproduce"
HELP = "(not implemented yet)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    pass


def run(args: argparse.Namespace) -> int:
    from ..errors import HsmapError

    raise HsmapError("'hsmap reproduce' is not implemented yet")
