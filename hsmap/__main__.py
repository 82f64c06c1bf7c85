"""``python -m hsmap``: the ``hsmap`` command (see :mod:`hsmap.cli`)."""

import sys

from .cli import main

sys.exit(main())
