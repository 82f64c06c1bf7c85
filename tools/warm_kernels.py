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

import numpy as np


def _two_rooms_tree(path: Path) -> None:
    import octomap

    res = 0.1
    tree = octomap.OcTree(res)
    step = res / 2
    xs, ys, zs = np.arange(0.0, 8.0 + 1e-9, step), np.arange(0.0, 3.0 + 1e-9, step), np.arange(0.05, 2.5, step)
    walls = []
    for y in (0.0, 3.0):
        X, Z = np.meshgrid(xs, zs, indexing="ij")
        walls.append(np.stack([X.ravel(), np.full(X.size, y), Z.ravel()], 1))
    for x in (0.0, 4.0, 8.0):
        Y, Z = np.meshgrid(ys, zs, indexing="ij")
        keep = ~((x == 4.0) & (Y.ravel() > 1.05) & (Y.ravel() < 1.95) & (Z.ravel() < 2.0))
        walls.append(np.stack([np.full(Y.size, x), Y.ravel(), Z.ravel()], 1)[keep])
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    floor = np.stack([X.ravel(), Y.ravel(), np.full(X.size, -0.05)], 1)
    cloud = np.vstack([*walls, floor])
    for origin in ((2.0, 1.5, 1.2), (6.0, 1.5, 1.2)):
        near = np.abs(cloud[:, 0] - origin[0]) <= 2.05
        tree.insertPointCloud(cloud[near], np.array(origin))
    tree.writeBinary(str(path).encode())


def main() -> int:
    from hsmap.cli import main as hsmap_main

    with tempfile.TemporaryDirectory(prefix="hsmap-warm-") as tmp:
        root = Path(tmp)
        _two_rooms_tree(root / "rooms.bt")
        with contextlib.redirect_stdout(io.StringIO()):
            status = hsmap_main(["segment", str(root / "rooms.bt"), "--band", "1.0,1.2", "--out", str(root / "a")])
            if status == 0:
                status = hsmap_main(["segment", str(root / "a" / "grid.yaml"), "--out", str(root / "b")])
    print("numba kernels compiled" if status == 0 else "warming the kernels failed (they compile on first use)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
