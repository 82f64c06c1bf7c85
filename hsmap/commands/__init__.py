"""Sub-commands of the ``hsmap`` command line, one module each.

Each module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``; modules import
their heavy dependencies inside ``run`` so that ``hsmap --help`` stays fast.
"""

COMMANDS = ["simulate", "slam", "map", "segment", "align", "evaluate", "reproduce", "data", "benchmark", "config"]
