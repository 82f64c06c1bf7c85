"""``python -m hsmap``: the ``hsmap`` command (see :mod:`hsmap.cli`)."""

import sys

from .cli import main

if __name__ == "__main__":  # not when multiprocessing's spawn re-imports the main module (Dask's workers)
    sys.exit(main())
