"""Screenshots of rerun recordings in the headless viewer: every view at the start, middle and end.

    .venv/bin/python tools/rrd_screenshots.py reports/ --out reports/screenshots

Takes .rrd files or folders (searched recursively). Needs a graphics stack: a GPU, or Mesa's software Vulkan
renderer (apt-get install mesa-vulkan-drivers). Prints, per recording, each view's share of drawn pixels and
any error a view reports; exits 1 when a recording fails the check (hsmap.viz.viewer.check_recording).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hsmap.viz.viewer import HeadlessViewer, viewer_unavailable


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("paths", nargs="+", type=Path, help=".rrd files or folders holding them")
    ap.add_argument("--out", type=Path, default=Path("reports/screenshots"), help="folder for the PNGs")
    a = ap.parse_args(argv)
    reason = viewer_unavailable()
    if reason:
        print(f"rrd_screenshots: {reason}", file=sys.stderr)
        return 2
    files = sorted({f for p in a.paths for f in ([p] if p.is_file() else p.rglob("*.rrd"))})
    if not files:
        print("rrd_screenshots: no .rrd files found", file=sys.stderr)
        return 2
    failed = 0
    with HeadlessViewer() as v:
        for f in files:
            check = v.screenshots(f, a.out / f.parent.name)
            print(f"{f}: {'ok' if check.ok else 'FAILED'}")
            for s in check.shots:
                print(f"  {s.position:6s} {s.view:28s} {s.view_class:12s} drawn {100 * s.content:5.1f} %"
                      + (f"  {'; '.join(s.reports)}" if s.reports else ""))
            for e in check.errors:
                print(f"  error: {e}")
            failed += not check.ok
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
