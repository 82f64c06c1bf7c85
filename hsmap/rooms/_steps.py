"""The steps of :func:`hsmap.rooms.segmentation.segment_rooms` on pixel grids (their primitives, the skeleton's
graph and its filters, in :mod:`hsmap.rooms._pixels`): the free space's width along a line, obstacle corners and
the wall-gap lines between them, the door candidates (the paper's band, critical points), merging regions across
narrowings and small ones into their neighbours. Images are (row, col)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage as ndi

from ._kernels import (
    chord_median,
    edt,
    free_between,
    ray_hit,
    wall_steps,
)
from ._pixels import (
    EIGHT,
    FOUR,
    OFFSETS,
    UnionFind,
    basis_points_at,
    geodesic_filter,
    line_pixels_between,
    march,
    region_borders,
    skeleton_graph,
)

__all__ = [
    "skeleton_graph",
    "geodesic_filter",
    "march",
    "basis_points_at",
    "line_pixels_between",
    "UnionFind",
    "region_borders",
    "corner_points",
    "runs_along_wall",
    "wall_run",
    "free_width",
    "free_run",
    "extension",
    "wall_gap_lines",
    "middle_of_wall",
    "paper_candidates",
    "critical_candidates",
    "plateau_centre",
    "pieces_between",
    "separated_regions",
    "merge_by_narrowing",
    "relabel",
    "fill_from_neighbours",
    "merge_small",
    "assign_furniture",
    "FOUR",
    "EIGHT",
    "OFFSETS",
]


# ----------------------------------------------------------------------------------------------------------
# wall gaps: lines between two obstacle corners that close a gap in a wall
# ----------------------------------------------------------------------------------------------------------


def corner_points(angles: NDArray[np.float64], min_angle: float) -> NDArray[np.int64]:
    """(K, 2) rows and columns of the corners: per 8-connected group of obstacle pixels whose wedge is at
    least ``min_angle`` degrees, the pixel of the group nearest to its centroid (the first in scan order
    among equals)."""
    lab, n = ndi.label(angles >= min_angle, structure=EIGHT)
    if n == 0:
        return np.zeros((0, 2), dtype=np.int64)
    flat = np.flatnonzero(lab)
    g = lab.ravel()[flat]
    r, c = np.divmod(flat, lab.shape[1])
    cnt = np.bincount(g, minlength=n + 1).astype(float)
    mr = np.bincount(g, r, minlength=n + 1) / np.maximum(cnt, 1)
    mc = np.bincount(g, c, minlength=n + 1) / np.maximum(cnt, 1)
    d2 = (r - mr[g]) ** 2 + (c - mc[g]) ** 2
    order = np.lexsort((flat, d2, g))
    first = np.r_[True, g[order][1:] != g[order][:-1]]
    return np.stack([r[order][first], c[order][first]], 1).astype(np.int64)


def runs_along_wall(filtered: NDArray[np.bool_], a: NDArray[np.float64], u: NDArray[np.float64],
                     steps: int, side: int = 2) -> bool:
    """Whether a wall runs on from obstacle pixel ``a`` in direction ``u`` for ``steps`` pixels: the line
    (shifted by at most one pixel across) stays on obstacle pixels while free space lies 2 to ``side`` pixels
    to one side of it (a wall's face, a thin wall, or the middle of a wall at most 2 ``side`` pixels thick;
    not the inside of a thick wall or of a pillar entered at an angle), for 80 % of the steps."""
    table = wall_steps(filtered, float(a[0]), float(a[1]), float(u[0]), float(u[1]), steps, side)
    return bool((table.sum(1) >= 0.8 * steps).any())


def wall_run(filtered: NDArray[np.bool_], a: NDArray[np.float64], u: NDArray[np.float64], max_steps: int) -> int:
    """How many pixels a wall runs on from obstacle pixel ``a`` in direction ``u`` (at most ``max_steps``), as
    :func:`runs_along_wall` sees it, until three steps in a row fail."""
    table = wall_steps(filtered, float(a[0]), float(a[1]), float(u[0]), float(u[1]), max_steps, 2)
    best = 0
    for good in table:
        bad = np.convolve(~good, np.ones(3), mode="valid") >= 3
        best = max(best, int(np.argmax(bad)) if bad.any() else max_steps)
    return best


def free_width(filtered: NDArray[np.bool_], mid: NDArray[np.float64], u: NDArray[np.float64],
                n: NDArray[np.float64], depths: NDArray[np.float64], reach: int) -> float:
    """Median over the depths ``t`` of the free chord (pixels) parallel to ``u`` through ``mid + t n``, each
    side of the centre followed up to ``reach`` pixels."""
    return float(chord_median(filtered, float(mid[0]), float(mid[1]), float(u[0]), float(u[1]), float(n[0]),
                              float(n[1]), depths.astype(np.float64), int(reach)))


def free_run(filtered: NDArray[np.bool_], a: NDArray[np.float64], b: NDArray[np.float64], end_px: float) -> bool:
    """Whether the straight line from obstacle pixel ``a`` to obstacle pixel ``b`` is free from the first free
    pixel after ``a`` to the last before ``b``, and these lie within ``end_px`` of the ends (a corner is the
    middle of the wall end it rounds)."""
    return bool(free_between(filtered, float(a[0]), float(a[1]), float(b[0]), float(b[1]), float(end_px)))


def extension(filtered: NDArray[np.bool_], a: NDArray[np.int64], e: NDArray[np.float64], max_px: float,
               end_px: float) -> NDArray[np.int64] | None:
    """The first obstacle pixel met by the ray from corner ``a`` along ``e`` once it has left the corner's
    obstacle (within ``end_px``), at most ``max_px`` away; None if there is none."""
    r, c = ray_hit(filtered, float(a[0]), float(a[1]), float(e[0]), float(e[1]), float(max_px), float(end_px))
    return None if r < 0 else np.array([r, c], dtype=np.int64)


def _corner_pair_gaps(filtered: NDArray[np.bool_], corners: NDArray[np.int64], max_px: float, end_px: float,
                      steps: int) -> list[tuple[NDArray[np.int64], NDArray[np.int64]]]:
    """Gaps between two corners, along a free line, where a wall runs on beyond one end at least."""
    from scipy.spatial import cKDTree

    segs = []
    pairs = cKDTree(corners).query_pairs(max_px + 1.0, output_type="ndarray") if len(corners) > 1 else []
    for i, j in pairs:
        a, b = corners[i], corners[j]
        af, bf = a.astype(float), b.astype(float)
        L = float(np.hypot(*(bf - af)))
        if L < 3.0:
            continue
        u = (bf - af) / L
        if free_run(filtered, af, bf, end_px) and (runs_along_wall(filtered, af, -u, steps)
                                                    or runs_along_wall(filtered, bf, u, steps)):
            segs.append((a, b))
    return segs


def _wall_end_gaps(filtered: NDArray[np.bool_], corners: NDArray[np.int64], angles: NDArray[np.float64],
                   starts: NDArray[np.int64], nbins: int, max_px: float, end_px: float,
                   ext_steps: int) -> list[tuple[NDArray[np.int64], NDArray[np.int64]]]:
    """Gaps from a corner along the wall it ends, continued, to the first obstacle, no longer than that wall.

    The free wedge of a corner is bounded by the faces that meet there, so a face continued runs along an edge
    of the wedge."""
    segs = []
    sector = 2.0 * np.pi / nbins
    for a in corners:
        s0 = int(starts[a[0], a[1]])
        if s0 < 0:
            continue
        lo = s0 * sector - np.pi
        hi = lo + np.deg2rad(angles[a[0], a[1]])
        for th in (lo + np.pi / 2, hi - np.pi / 2):
            e = np.array([np.sin(th), np.cos(th)])
            if not runs_along_wall(filtered, a.astype(float), -e, ext_steps):
                continue
            b = extension(filtered, a, e, max_px, end_px)
            # a gap no longer than the wall it continues
            if b is not None and 3.0 <= np.hypot(*(b - a)) <= wall_run(filtered, a.astype(float), -e,
                                                                       int(max_px) + 1):
                segs.append((a, b))
    return segs


def _narrow_sides(walls: NDArray[np.bool_], a: NDArray[np.int64], b: NDArray[np.int64],
                  gap_ratio: float) -> list[bool]:
    """Whether the line a-b is at most ``gap_ratio`` times the free chord parallel to it, on each side."""
    af, bf = a.astype(float), b.astype(float)
    L = float(np.hypot(*(bf - af)))
    u = (bf - af) / L
    nrm = np.array([-u[1], u[0]])
    depths = np.arange(2.0, max(L / 2, 3.0) + 1.0)
    reach = int(np.ceil(L / gap_ratio)) + 2
    centre = (af + bf) / 2
    return [L - 1.0 <= gap_ratio * free_width(walls, centre, u, side * nrm, depths, reach) for side in (1.0, -1.0)]


def wall_gap_lines(filtered: NDArray[np.bool_], dist_px: NDArray[np.float64], corners: NDArray[np.int64],
                    angles: NDArray[np.float64], starts: NDArray[np.int64], nbins: int, res: float,
                    cfg: Any) -> list[tuple[NDArray[np.int64], NDArray[np.int64], float, bool]]:
    """Lines across gaps in walls, at most ``max_gap_width`` long, along a free straight line with no obstacle
    in the disc it is the diameter of:

    * between two corners (obstacle pixels with a wide wedge of free space) when a wall runs on beyond one
      end at least;
    * from a corner along the wall it ends (a face of the wall, continued) to the first obstacle.

    A line is narrow on a side where it is at most ``gap_ratio`` times the free chord parallel to it there (the
    median over depths up to half its length), every other candidate drawn in as a wall (so that a line across
    a corridor sees the corridor's width even where rooms open onto it). Narrow on both sides, it is a room
    border (firm); on one side only (the mouth of a corridor, into a room or into another corridor), the
    narrowing test decides. Returns (a, b, width in metres, firm) per line narrow on a side at least.
    """
    if not len(corners):
        return []
    steps = max(2, int(round(cfg.wall_continuation / res)))
    end_px = max(2.0, 0.15 / res)
    max_px = cfg.max_gap_width / res
    segs = _corner_pair_gaps(filtered, corners, max_px, end_px, steps)
    segs += _wall_end_gaps(filtered, corners, angles, starts, nbins, max_px, end_px,
                           max(steps, int(round(1.0 / res))))
    if not segs:
        return []
    # nothing nearer to the middle than the two ends (the Gabriel condition)
    keep = []
    for a, b in segs:
        L = float(np.hypot(*(b - a)))
        mid = np.rint((a + b) / 2.0).astype(np.int64)
        if filtered[mid[0], mid[1]] and dist_px[mid[0], mid[1]] >= 0.9 * L / 2 - 1.0:
            keep.append((a, b))
    if not keep:
        return []
    walls = filtered.copy()
    for a, b in keep:
        lr, lc = line_pixels_between(a, b)
        walls[lr, lc] = False
    out = []
    for a, b in keep:
        narrow = _narrow_sides(walls, a, b, cfg.gap_ratio)
        if any(narrow):
            L = float(np.hypot(*(b.astype(float) - a.astype(float))))
            out.append((a, b, max(L - 1.0, 0.0) * res, all(narrow)))
    return out


def middle_of_wall(free: NDArray[np.bool_], centre: NDArray[np.int64], a: NDArray[np.int64],
                    b: NDArray[np.int64], max_px: int) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """A door line (obstacle end pixels ``a``, ``b``) moved across itself to the middle of the wall it passes
    through: the stretch along its normal over which both ends stay on obstacle pixels, if at most ``max_px``
    to either side."""
    d = (b - a).astype(float)
    L = float(np.hypot(*d))
    if L == 0:
        return centre, a, b
    nrm = np.array([-d[1], d[0]]) / L
    H, W = free.shape

    def on_obstacle(p):
        q = np.rint(p).astype(np.int64)
        return 0 <= q[0] < H and 0 <= q[1] < W and not free[q[0], q[1]]

    ext = []
    for sgn in (1.0, -1.0):
        t = 0
        while t <= max_px and on_obstacle(a + (t + 1) * sgn * nrm) and on_obstacle(b + (t + 1) * sgn * nrm):
            t += 1
        ext.append(t)
    if max(ext) > max_px:  # not a wall but a passage (a corridor's mouth): leave it
        return centre, a, b
    shift = np.rint((ext[0] - ext[1]) / 2.0 * nrm).astype(np.int64)
    return centre + shift, a + shift, b + shift


def paper_candidates(skel, product, rr, cc, nbr, dvals, cfg, res):
    """Centres of the skeleton segments inside the band of half door widths; directions perpendicular."""
    lo = cfg.door_half_width - cfg.door_half_width_tolerance
    hi = cfg.door_half_width + cfg.door_half_width_tolerance
    band = skel & (product >= lo) & (product <= hi)
    seg, n = ndi.label(band, structure=EIGHT)
    centres, dirs = [], []
    if n == 0:
        return centres, dirs
    coms = ndi.center_of_mass(band, seg, np.arange(1, n + 1))
    br, bc = np.nonzero(band)
    bl = seg[br, bc]
    for k, com in enumerate(coms, start=1):
        m = bl == k
        pr, pc = br[m], bc[m]
        j = int(np.argmin((pr - com[0]) ** 2 + (pc - com[1]) ** 2))
        centre = (int(pr[j]), int(pc[j]))
        # local skeleton direction: principal axis of skeleton pixels within 4 px
        near = (np.abs(rr - centre[0]) <= 4) & (np.abs(cc - centre[1]) <= 4)
        pts = np.stack([rr[near], cc[near]], 1).astype(float)
        if len(pts) < 2:
            continue
        pts -= pts.mean(0)
        _, _, vt = np.linalg.svd(pts, full_matrices=False)
        t = vt[0]
        centres.append(centre)
        dirs.append(np.array([-t[1], t[0]]))
    return centres, dirs


def critical_candidates(rr, cc, nbr, dvals, cfg, res):
    """Critical points: skeleton pixels with the least clearance within ``critical_radius`` along it."""
    from scipy.spatial import cKDTree

    steps = max(1, int(round(cfg.critical_radius / res)))
    gmin = geodesic_filter(dvals, nbr, steps, np.minimum)
    degree = (nbr >= 0).sum(1)
    cand = (dvals <= gmin + 1e-9) & (degree >= 2)
    cand &= (dvals >= cfg.min_door_half_width) & (dvals <= cfg.max_door_half_width)
    idx = np.nonzero(cand)[0]
    if not len(idx):
        return [], []
    # non-maximum suppression of ties (plateaus): greedily keep the lowest, drop the others within the radius
    order = idx[np.argsort(dvals[idx], kind="stable")]
    pos = np.stack([rr[order], cc[order]], 1).astype(float)
    tree = cKDTree(pos)
    close = tree.query_ball_point(pos, r=steps - 1e-6)
    alive = np.ones(len(order), dtype=bool)
    centres = []
    for k in range(len(order)):
        if not alive[k]:
            continue
        alive[close[k]] = False
        j = plateau_centre(int(order[k]), rr, cc, nbr, dvals, 0.5 * res, steps)
        centres.append((int(rr[j]), int(cc[j])))
    return centres, [None] * len(centres)


def plateau_centre(i: int, rr, cc, nbr: NDArray[np.int64], dvals: NDArray[np.float64], tol: float,
                    steps: int) -> int:
    """The middle of the run of skeleton pixels around ``i`` whose clearance is within ``tol`` of its own
    (a doorway through a thick wall is such a run; its middle is the door's centre)."""
    level = dvals[i] + tol
    seen = {i}
    frontier = [i]
    for _ in range(steps):
        nxt = []
        for a in frontier:
            for b in nbr[a]:
                if b >= 0 and b not in seen and dvals[b] <= level:
                    seen.add(int(b))
                    nxt.append(int(b))
        if not nxt:
            break
        frontier = nxt
    if len(seen) < 3:
        return i
    m = np.fromiter(seen, dtype=np.int64)
    pr, pc = rr[m].astype(float), cc[m].astype(float)
    k = int(np.argmin((pr - pr.mean()) ** 2 + (pc - pc.mean()) ** 2))
    return int(m[k])


def pieces_between(px: NDArray[np.int64], a: NDArray[np.int64], b: NDArray[np.int64],
                    block: NDArray[np.bool_]) -> list[NDArray[np.int64]]:
    """The runs of a line's pixels ``px`` (from ``a`` to ``b``) outside ``block``, in order along the line."""
    if not block[px[:, 0], px[:, 1]].any():
        return [px]
    d = (b - a).astype(float)
    order = np.argsort((px - a) @ d, kind="stable")
    p = px[order]
    out = block[p[:, 0], p[:, 1]]
    runs, start = [], None
    for i, o in enumerate(np.append(out, True)):
        if not o and start is None:
            start = i
        elif o and start is not None:
            if i - start >= 2:
                runs.append(p[start:i])
            start = None
    return runs


def separated_regions(lab: NDArray[np.int64], px: NDArray[np.int64]) -> tuple[int, int]:
    """The two regions a door line (pixels ``px``) separates: the two most frequent labels around it."""
    nb = (px[:, None, :] + OFFSETS[None, :, :]).reshape(-1, 2)
    ok = (nb[:, 0] >= 0) & (nb[:, 0] < lab.shape[0]) & (nb[:, 1] >= 0) & (nb[:, 1] < lab.shape[1])
    v = lab[nb[ok, 0], nb[ok, 1]]
    v = v[v > 0]
    if not len(v):
        return (0, 0)
    u, cnt = np.unique(v, return_counts=True)
    o = np.argsort(-cnt)
    return (int(u[o[0]]), int(u[o[1]])) if len(u) > 1 else (int(u[0]), int(u[0]))


def merge_by_narrowing(half: NDArray[np.float64], pairs: NDArray[np.int64], peak: NDArray[np.float64],
                        uf: UnionFind, cfg) -> None:
    """Merge the regions of each pair (``pairs`` (K, 2), across an opening of half width ``half`` (K,), in
    metres) unless the opening is a narrowing: half width at most ``narrowing_ratio`` times the geometric mean
    of the two regions' largest clearances ``peak``; least door-like first, a merged region takes the larger
    clearance."""
    if not len(half):
        return
    root = np.arange(len(peak))
    pk = peak.copy()
    while True:
        ra, rb = root[pairs[:, 0]], root[pairs[:, 1]]
        live = (ra != rb) & (ra > 0) & (rb > 0)
        if not live.any():
            break
        ratio = np.where(live, half / np.maximum(np.sqrt(pk[ra] * pk[rb]), 1e-9), -1.0)
        j = int(np.argmax(ratio))
        if ratio[j] <= cfg.narrowing_ratio:
            break
        a, b = int(ra[j]), int(rb[j])
        root[root == b] = a
        pk[a] = max(pk[a], pk[b])
    for i in range(1, len(root)):
        if root[i] != i:
            uf.union(int(root[i]), i)


def relabel(lab: NDArray[np.int64], uf: UnionFind) -> NDArray[np.int64]:
    n = len(uf.parent)
    roots = np.array([uf.find(i) for i in range(n)])
    roots[0] = 0
    return roots[lab]


def fill_from_neighbours(lab: NDArray[np.int64], free: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Give unlabelled free pixels (door lines, filtered-out specks) the label of a labelled neighbour within
    three pixels; free specks further away stay unlabelled."""
    out = lab.copy()
    H, W = out.shape
    for _ in range(3):
        hr, hc = np.nonzero(free & (out == 0))
        if not len(hr):
            return out
        grown = np.zeros(len(hr), dtype=out.dtype)
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                r = np.clip(hr + dr, 0, H - 1)
                c = np.clip(hc + dc, 0, W - 1)
                np.maximum(grown, out[r, c], out=grown)
        out[hr, hc] = grown
    return out


def merge_small(lab: NDArray[np.int64], res: float, min_area: float, min_isolated: float) -> NDArray[np.int64]:
    """Merge regions under ``min_area`` m^2 into the neighbour with the longest shared border; isolated ones
    (no neighbour) are kept if at least ``min_isolated`` m^2, else dropped; renumber 1..R in scan order."""
    lab = lab.copy()
    min_px = min_area / (res * res)
    min_iso_px = min_isolated / (res * res)
    while True:
        n = int(lab.max(initial=0))
        if n == 0:
            return lab
        size = np.bincount(lab.ravel(), minlength=n + 1)
        small = np.nonzero((size < min_px) & (size > 0))[0]
        small = small[small > 0]
        if not len(small):
            break
        borders = region_borders(lab)
        best: dict[int, tuple[int, int]] = {}
        for (a, b), m in borders.items():
            for x, y in ((a, b), (b, a)):
                if size[x] < min_px and (x not in best or m > best[x][1]
                                          or (m == best[x][1] and size[y] > size[best[x][0]])):
                    best[x] = (y, m)
        remap = np.arange(n + 1)
        changed = False
        # merge the smallest first; a small region merging into another small one is fine (iterates)
        for x in sorted(small, key=lambda k: size[k]):
            if x in best:
                tgt = best[x][0]
                while remap[tgt] != tgt:
                    tgt = remap[tgt]
                if tgt != x:
                    remap[x] = tgt
                    changed = True
            elif size[x] < min_iso_px:
                remap[x] = 0
                changed = True
        # resolve chains
        for i in range(n + 1):
            j = i
            while remap[j] != j:
                j = remap[j]
            remap[i] = j
        lab = remap[lab]
        if not changed:
            break
    u = np.unique(lab)
    u = u[u > 0]
    remap = np.zeros(int(lab.max(initial=0)) + 1, dtype=np.int64)
    remap[u] = np.arange(1, len(u) + 1)
    return remap[lab]


def assign_furniture(lab: NDArray[np.int64], free: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Occupied blobs entirely surrounded by one room get that room's label."""
    occ, n = ndi.label(~free, structure=EIGHT)
    if n == 0:
        return lab
    # labels of the pixels bordering each occupied blob
    ring = ndi.binary_dilation(~free, structure=EIGHT) & free
    _, ind_r, ind_c = edt(free)
    owner = occ[ind_r[ring], ind_c[ring]]
    room = lab[ring]
    out = lab.copy()
    touches_edge = np.zeros(n + 1, dtype=bool)
    edge = np.concatenate([occ[0], occ[-1], occ[:, 0], occ[:, -1]])
    touches_edge[edge] = True
    pair = np.stack([owner, room], 1)
    u = np.unique(pair, axis=0)
    kinds = np.bincount(u[:, 0], minlength=n + 1)
    only = np.zeros(n + 1, dtype=np.int64)
    only[u[:, 0]] = u[:, 1]
    ok = (kinds == 1) & ~touches_edge & (only > 0)
    ok[0] = False
    m = ok[occ]
    out[m] = only[occ[m]]
    return out


