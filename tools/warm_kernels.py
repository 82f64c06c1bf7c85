"""Compile hsmap's numba kernels into their on-disk cache, so that a command's first run does not pay for it.

Runs ``hsmap segment`` on a small synthetic 3D map (two rooms and a door, written as an OctoMap ``.bt``) and on
its band as a 2D map image, in a temporary folder. ``make setup`` calls it once after installing.
"""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile
from pathlib import Path


def main() -> int:
    from hsmap.cli import main as hsmap_main
    from hsmap.testing import two_rooms_octree

    with tempfile.TemporaryDirectory(prefix="hsmap-warm-") as tmp:
        root = Path(tmp)
        two_rooms_octree(root / "rooms.bt")
        with contextlib.redirect_stdout(io.StringIO()):
            status = hsmap_main(["segment", str(root / "rooms.bt"), "--band", "1.0,1.2", "--out", str(root / "a")])
            if status == 0:
                status = hsmap_main(["segment", str(root / "a" / "grid.yaml"), "--out", str(root / "b")])
    print("numba kernels compiled" if status == 0 else "warming the kernels failed (they compile on first use)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
