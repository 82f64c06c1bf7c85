"""Relations audit: where a trajectory and the Freiburg relations disagree, which one do the two scans agree with?

The relations error (Kuemmerle et al. 2009) treats each relation as the truth. This script asks the laser data: for
every relation (t_i, t_j, R) between two scans of the log, it aligns scan j to scan i at the relation's relative
pose R and at the trajectory's own relative pose S (both robot poses, the scans in the robot frame with the log's
laser offset), and scores each by the mean distance from each scan's points to the other scan's nearest point,
truncated at ``--truncate`` (0.3 m), averaged over both directions. A relation the trajectory misses by more than
``--min-error`` (0.2 m) where the scans align better at S than at R by more than ``--margin`` (1 cm) is one the data
contradict; the script reports how many there are, how many the data side with the relation on, and the
trajectory's mean translational error with and without the contradicted ones.

It also asks which robot frame the relations describe: it scores the trajectory carried by an offset of
``--frame-offsets`` along the robot's x axis (the pose composed with (dx, 0, 0), the frame a sensor offset would
move), for all relations, those with Δt <= 10 s and > 60 s, and those whose two poses face more than 90 deg apart
(a place revisited the other way round: a frame offset d moves their relative pose by up to 2 d, a relation
between poses facing the same way by almost nothing).

It also scores the relations with dt <= 10 s as three sources have them: the raw wheel odometry, the two scans
alone (ICP of one to the other, no map) and the trajectory; the source they agree with most closely is the one
they were made from.

With ``--independent TUM`` (a trajectory of the log made without its odometry: ``hsmap slam --no-odometry``) it
also asks two independent sensors about each relation's rotation: a relation that the raw wheel odometry and the
scans alone both miss by more than ``--min-rotation`` (1 deg), while they agree with each other to half of what
each misses it by, is one that both sensors contradict. The check does not involve the trajectory audited, so it
cannot select relations in its favour; the script reports how many there are, where in the log, and the audited
trajectory's errors with and without them.

With ``--maps`` it also scores the long relations (dt > ``--maps-min-dt``, 60 s) map to map. A long relation
often joins a place and its revisit the other way round (a corridor driven back), and a 180 deg laser facing the
other way sees the other side of every pillar and alcove: the two scans barely overlap, and the scan-to-scan check
above cannot judge them (their costs sit near the truncation). Here the scans within ``--maps-window`` (15 s) of
each end, placed by the trajectory, make two maps; the second is scored against the first where the trajectory
puts it and moved rigidly by the correction that gives the trajectory's relative pose the relation's value.

It also counts the relations that are the raw odometry's relative pose to 3 mm and 0.02 deg (copied from it, not
measured: made by hand, a relation starts from the odometry and is kept where it looks right) and pairs the
relations with dt <= 10 s, the odometry and the trajectory, moving the trajectory's relative poses towards the
odometry's in steps to see which way the error goes.

It is a check of the benchmark, not a score: the published figures (Cartographer's 0.1078 m on fr-clinic) were
measured against every relation, in the bag's frame, and so is ``benchmarks/slam.py``. What it found on each log is
in ``docs/slam-results.md``.

    .venv/bin/python benchmarks/relations_audit.py fr-clinic reports/some-run/trajectory.tum \
        [--independent reports/no-odometry-run/trajectory.tum] [--maps]

Writes reports/benchmarks/relations_audit_<log>.json (atomically).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from _report import finish, machine  # noqa: E402  (benchmarks/_report.py)
from slam import FREIBURG  # noqa: E402

from hsmap.datasets.open import open_dataset  # noqa: E402
from hsmap.datasets.relations import Relations, read_relations  # noqa: E402
from hsmap.evaluation.trajectory import relation_errors, relations_error  # noqa: E402
from hsmap.geometry import compose, invert, pose_to_matrix, relative, transform_points, wrap_angle  # noqa: E402
from hsmap.slam import frame_points  # noqa: E402
from hsmap.study.paths import datasets_dir  # noqa: E402
from hsmap.trajectory import Trajectory, read_tum  # noqa: E402


def alignment_cost(a: np.ndarray, b: np.ndarray, tree_a: cKDTree, tree_b: cKDTree, pose: np.ndarray,
                   truncate: float) -> float:
    """Mean truncated nearest-point distance between scan ``a`` and scan ``b`` placed at ``pose`` in a's frame,
    both ways."""
    d_ab, _ = tree_a.query(transform_points(pose_to_matrix(pose), b), distance_upper_bound=truncate)
    d_ba, _ = tree_b.query(transform_points(pose_to_matrix(invert(pose)), a), distance_upper_bound=truncate)
    return 0.5 * (float(np.minimum(d_ab, truncate).mean()) + float(np.minimum(d_ba, truncate).mean()))


def audit(name: str, trajectory: Path, traj: Trajectory, rel: Relations, frames: list,
          odometry: Trajectory | None, truncate: float, min_error: float, margin: float) -> dict:
    stamps = np.array([f.stamp for f in frames])
    scans: dict[int, tuple[np.ndarray, cKDTree]] = {}

    def scan(k: int) -> tuple[np.ndarray, cKDTree]:
        if k not in scans:
            p = frame_points(frames[k], 3, 0.1, 30.0)
            scans[k] = (p, cKDTree(p))
        return scans[k]

    rows = []
    for t_i, t_j, R6 in zip(rel.t_i, rel.t_j, rel.poses, strict=True):
        i, j = int(np.argmin(np.abs(stamps - t_i))), int(np.argmin(np.abs(stamps - t_j)))
        pi, ok_i = traj.interpolate([t_i], max_dt=1.0)  # as the relations error interpolates
        pj, ok_j = traj.interpolate([t_j], max_dt=1.0)
        if abs(stamps[i] - t_i) > 0.01 or abs(stamps[j] - t_j) > 0.01 or not (ok_i[0] and ok_j[0]):
            continue
        R = np.asarray(R6, dtype=float)[[0, 1, 5]]
        S = relative(pi[0], pj[0])
        (a, ta), (b, tb) = scan(i), scan(j)
        e, _ = relation_errors(pose_to_matrix(S), pose_to_matrix(R))
        rows.append((t_i, t_j, float(e), alignment_cost(a, b, ta, tb, R, truncate),
                     alignment_cost(a, b, ta, tb, S, truncate)))
    r = np.array(rows)
    err, c_rel, c_traj = r[:, 2], r[:, 3], r[:, 4]
    far = err > min_error
    contradicted = far & (c_traj < c_rel - margin)
    supported = far & (c_rel < c_traj - margin)
    dt = np.abs(r[:, 1] - r[:, 0])
    out = {
        "log": name, "trajectory": str(trajectory), "relations_used": int(len(r)),
        "truncate_m": truncate, "min_error_m": min_error, "margin_m": margin,
        "mean_translation_error_m": float(err.mean()),
        "relations_missed_by_more_than_min_error": int(far.sum()),
        "of_which_the_scans_align_better_at_the_trajectory": int(contradicted.sum()),
        "of_which_the_scans_align_better_at_the_relation": int(supported.sum()),
        "mean_translation_error_without_the_contradicted_m": float(err[~contradicted].mean()),
        "share_of_the_mean_from_the_contradicted": float(err[contradicted].sum() / err.sum()),
        "contradicted": [{"t_i": float(a), "t_j": float(b), "dt_s": float(d), "error_m": float(e),
                          "cost_at_relation_m": float(x), "cost_at_trajectory_m": float(y)}
                         for (a, b, e, x, y), d in zip(r[contradicted], dt[contradicted], strict=True)],
    }
    out["short_relations_by_source"] = short_relations_by_source(name, frames, stamps, odometry, traj, rel, scan)
    print(f"{name}: {len(r)} relations, mean error {err.mean():.4f} m; {far.sum()} missed by > {min_error} m, of "
          f"which the scans align better at the trajectory on {contradicted.sum()} and at the relation on "
          f"{supported.sum()}; without the contradicted ones the mean is {out['mean_translation_error_without_the_contradicted_m']:.4f} m")
    return out


def short_relations_by_source(name: str, frames: list, stamps: np.ndarray, odometry: Trajectory | None,
                              traj: Trajectory, rel: Relations, scan) -> dict:
    """The relations with dt <= 10 s as three sources have them: the raw wheel odometry, the two scans alone
    (point-to-line ICP of scan j to scan i from the odometry's relative pose, no map), and the trajectory.

    Which source the relations agree with says what they were made from.
    """
    from hsmap.registration.icp import RegistrationConfig, RegistrationTarget, refine_icp

    keep = np.flatnonzero(np.abs(rel.t_j - rel.t_i) <= 10.0)
    errs: dict[str, list] = {"odometry": [], "scans_alone": [], "trajectory": []}
    targets: dict[int, RegistrationTarget] = {}
    for q in keep:
        t_i, t_j = rel.t_i[q], rel.t_j[q]
        i, j = int(np.argmin(np.abs(stamps - t_i))), int(np.argmin(np.abs(stamps - t_j)))
        pose, ok = traj.interpolate([t_i, t_j], max_dt=1.0)
        if odometry is None or not ok.all() or abs(stamps[i] - t_i) > 0.01 or abs(stamps[j] - t_j) > 0.01:
            continue
        od, ok_od = odometry.interpolate([t_i, t_j], max_dt=1.0)
        if not ok_od.all():
            continue
        if i not in targets:
            targets[i] = RegistrationTarget(scan(i)[0], RegistrationConfig())
            targets[i].prepare()
        R = np.asarray(rel.poses[q], dtype=float)[[0, 1, 5]]
        o = relative(od[0], od[1])
        icp = refine_icp(scan(j)[0], targets[i], o, max_distance=0.1, start_distance=0.5, iterations=60)
        for key, est in (("odometry", o), ("scans_alone", icp), ("trajectory", relative(pose[0], pose[1]))):
            t, r = relation_errors(pose_to_matrix(est), pose_to_matrix(R))
            errs[key].append((float(t), float(np.rad2deg(r))))
    out = {}
    print(f"{name}: relations with dt <= 10 s ({len(errs['trajectory'])}) as each source has them")
    print("    source          mean m  median m  mean deg  median deg")
    for key, v in errs.items():
        a = np.array(v).reshape(-1, 2)
        if not len(a):
            continue
        out[key] = {"n": int(len(a)), "mean_m": float(a[:, 0].mean()), "median_m": float(np.median(a[:, 0])),
                    "mean_deg": float(a[:, 1].mean()), "median_deg": float(np.median(a[:, 1]))}
        s = out[key]
        print(f"    {key:<14s} {s['mean_m']:7.4f}  {s['median_m']:8.4f}  {s['mean_deg']:8.3f}  {s['median_deg']:10.3f}")
    return out


def _relative_poses(traj: Trajectory, rel: Relations) -> tuple[np.ndarray, np.ndarray]:
    """Each relation's relative pose (x, y, yaw) as ``traj`` has it, interpolated as the relations error does,
    and which relations it covers."""
    pi, ok_i = traj.interpolate(rel.t_i, max_dt=1.0)
    pj, ok_j = traj.interpolate(rel.t_j, max_dt=1.0)
    return relative(pi, pj), ok_i & ok_j


def contradicted_by_two_sensors(name: str, traj: Trajectory, odometry: Trajectory | None, independent: Trajectory,
                                rel: Relations, min_rotation_deg: float) -> dict:
    """The relations whose rotation the raw wheel odometry and a trajectory made from the scans alone both miss by
    more than ``min_rotation_deg``, agreeing with each other to half of what each misses it by; the audited
    trajectory's relations error with and without them."""
    if odometry is None:
        raise SystemExit(f"{name}: the log has no odometry to compare with")
    R = pose_to_matrix(rel.poses[:, [0, 1, 5]])
    (o, ok_o), (s, ok_s), (t, ok_t) = (_relative_poses(x, rel) for x in (odometry, independent, traj))
    used = ok_o & ok_s & ok_t
    m_o, m_s, m_t = (pose_to_matrix(x[used]) for x in (o, s, t))
    _, r_o = relation_errors(m_o, R[used])
    _, r_s = relation_errors(m_s, R[used])
    _, r_os = relation_errors(m_o, m_s)
    r_o, r_s, r_os = np.rad2deg(r_o), np.rad2deg(r_s), np.rad2deg(r_os)
    c = (r_o > min_rotation_deg) & (r_s > min_rotation_deg) & (r_os < 0.5 * np.minimum(r_o, r_s))
    e_t, e_r = relation_errors(m_t, R[used])
    e_r = np.rad2deg(e_r)
    dt = (rel.t_j - rel.t_i)[used]
    t0 = float(min(rel.t_i.min(), rel.t_j.min()))
    when = rel.t_i[used][c] - t0
    bins = np.arange(0.0, float((rel.t_j - t0).max()) + 500.0, 500.0)

    def errors(m: np.ndarray) -> dict:
        out = {"n": int(m.sum())}
        for key, sel in (("all", m), ("dt_le_10s", m & (dt <= 10)), ("dt_gt_60s", m & (dt > 60))):
            out[f"{key}_m"] = float(e_t[sel].mean()) if sel.any() else None
            out[f"{key}_deg"] = float(e_r[sel].mean()) if sel.any() else None
        return out

    out = {"independent_relations_scored": int(used.sum()), "min_rotation_deg": min_rotation_deg,
           "contradicted_by_both": int(c.sum()), "dt_median_s": float(np.median(dt[c])) if c.any() else None,
           "per_500_s": [int(v) for v in np.histogram(when, bins=bins)[0]],
           "trajectory_all": errors(np.ones(len(c), bool)), "trajectory_without_them": errors(~c)}
    w, a = out["trajectory_without_them"], out["trajectory_all"]
    print(f"{name}: {c.sum()} of {used.sum()} relations missed by > {min_rotation_deg} deg by both the raw odometry and "
          f"the scans alone, which agree with each other (per 500 s: {out['per_500_s']}); the trajectory "
          f"{a['all_m']:.4f} m / {a['all_deg']:.3f} deg, without them {w['all_m']:.4f} m / {w['all_deg']:.3f} deg")
    return out


#: Two relative poses this close count as the same number written twice, not two measurements that agree
#: (m, deg): wheel odometry and scan matching of one scan pair differ by centimetres and tenths of a degree.
SAME_TRANSLATION, SAME_ROTATION_DEG = 0.003, 0.02


def odometry_copies(name: str, traj: Trajectory, odometry: Trajectory | None, rel: Relations,
                    max_dt: float = 10.0) -> dict:
    """How many relations are the raw wheel odometry's relative pose, and the short relations (dt <= ``max_dt``) as
    the relations, the odometry and the trajectory pair up.

    A relation within ``SAME_TRANSLATION`` and ``SAME_ROTATION_DEG`` of the odometry was copied from it (made by
    hand, a relation starts from the odometry and is kept where it looks right); on such relations any estimate
    that uses the scans is scored by how far it strays from the odometry. The three pairwise mean errors say
    which source the rest follow: where the odometry and the trajectory agree with each other more closely than
    either agrees with the relations, the relations hold something neither sensor sees. Also the trajectory's
    short relations moved part of the way to the odometry (its relative pose and the odometry's blended, weight
    ``w`` on the odometry): the error falling all the way to w = 1 means the relations side with the odometry
    over every mix of the two.
    """
    if odometry is None:
        raise SystemExit(f"{name}: the log has no odometry to compare with")
    R = rel.poses[:, [0, 1, 5]]
    (o, ok_o), (t, ok_t) = (_relative_poses(x, rel) for x in (odometry, traj))
    used = ok_o & ok_t
    e_o, r_o = relation_errors(pose_to_matrix(o[used]), pose_to_matrix(R[used]))
    r_o = np.rad2deg(r_o)
    copies = (e_o < SAME_TRANSLATION) & (r_o < SAME_ROTATION_DEG)
    # the rotation alone copied (a relation whose translation was matched, its heading kept from the odometry)
    rotation_copies = r_o < SAME_ROTATION_DEG
    short = (np.abs(rel.t_j - rel.t_i) <= max_dt)[used]
    Rs, os_, ts = R[used][short], o[used][short], t[used][short]

    def mean_error(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
        e, r = relation_errors(pose_to_matrix(a), pose_to_matrix(b))
        return float(e.mean()), float(np.rad2deg(r).mean())

    pairs = {"relations_odometry": mean_error(os_, Rs), "relations_trajectory": mean_error(ts, Rs),
             "odometry_trajectory": mean_error(ts, os_)}
    blend = {}
    for w in (0.0, 0.25, 0.5, 0.75, 1.0):
        b = ts.copy()
        b[:, :2] = (1.0 - w) * ts[:, :2] + w * os_[:, :2]
        b[:, 2] = ts[:, 2] + w * wrap_angle(os_[:, 2] - ts[:, 2])
        blend[str(w)] = mean_error(b, Rs)
    out = {"relations_scored": int(used.sum()), "odometry_copies": int(copies.sum()),
           "odometry_copies_short": int((copies & short).sum()), "short_relations": int(short.sum()),
           "odometry_rotation_copies": int(rotation_copies.sum()),
           "odometry_rotation_copies_short": int((rotation_copies & short).sum()),
           "same_translation_m": SAME_TRANSLATION, "same_rotation_deg": SAME_ROTATION_DEG,
           "short_pairs_mean_m_deg": pairs, "short_blend_with_odometry_m_deg": blend}
    print(f"{name}: {out['odometry_copies']} of {used.sum()} relations equal the raw odometry's relative pose to "
          f"{SAME_TRANSLATION * 1000:.0f} mm and {SAME_ROTATION_DEG} deg ({out['odometry_copies_short']} of the "
          f"{short.sum()} with dt <= {max_dt:g} s), {out['odometry_rotation_copies']} its rotation to "
          f"{SAME_ROTATION_DEG} deg ({out['odometry_rotation_copies_short']} short); the short ones, pairwise mean m / deg: "
          + ", ".join(f"{k.replace('_', '-')} {v[0]:.4f} / {v[1]:.3f}" for k, v in pairs.items())
          + "; the trajectory moved towards the odometry by w: "
          + ", ".join(f"{k} {v[0]:.4f}" for k, v in blend.items()))
    return out


def _thin(points: np.ndarray, cell: float = 0.05) -> np.ndarray:
    """One point per ``cell`` square (the first), so a stretch's many scans of one wall weigh as one."""
    _, first = np.unique(np.floor(points / cell).astype(np.int64), axis=0, return_index=True)
    return points[np.sort(first)]


def _maps_window_error(window: float, min_dt: float) -> str | None:
    """Why ``--maps-window`` does not suit ``--maps-min-dt``, or None: two stretches that share scans align where the
    trajectory puts them, whatever the relation says."""
    if 0 < 2 * window < min_dt:
        return None
    return f"--maps-window must be positive and under half of --maps-min-dt ({min_dt:g} s), got {window:g} s"


def maps_audit(name: str, frames: list, traj: Trajectory, rel: Relations, window: float, min_dt: float,
               truncate: float, min_error: float, margin: float) -> dict:
    """For each relation with dt > ``min_dt``: the scans within ``window`` s of t_i and of t_j, each stretch placed
    by the trajectory, make two maps; the map of j's stretch is scored against i's (:func:`alignment_cost`, both
    ways) where the trajectory places it and moved rigidly by the correction that makes the trajectory's relative
    pose the relation's. Two scans taken facing opposite ways (a corridor driven back) barely overlap, so the
    scan-to-scan check cannot judge such relations; two stretches of tens of scans do. ``frames``: the log's
    frames (:class:`hsmap.datasets.frames.Frame`, with their 2D scans and the laser's offset)."""
    problem = _maps_window_error(window, min_dt)
    if problem:
        raise SystemExit(problem)
    stamps = np.array([f.stamp for f in frames])
    poses, ok = traj.interpolate(stamps, max_dt=1.0)
    world: dict[int, np.ndarray] = {}

    def stretch(t: float) -> np.ndarray:
        ks = np.flatnonzero((np.abs(stamps - t) <= window) & ok)
        for k in ks:
            if k not in world:
                world[k] = transform_points(pose_to_matrix(poses[k]), frame_points(frames[k], 3, 0.1, 30.0))
        return _thin(np.concatenate([world[k] for k in ks])) if len(ks) else np.zeros((0, 2))

    rows = []
    for t_i, t_j, R6 in zip(rel.t_i, rel.t_j, rel.poses, strict=True):
        if abs(t_j - t_i) <= min_dt:
            continue
        (pi, oi), (pj, oj) = traj.interpolate([t_i], max_dt=1.0), traj.interpolate([t_j], max_dt=1.0)
        if not (oi[0] and oj[0]):
            continue
        a, b = stretch(t_i), stretch(t_j)
        if len(a) < 10 or len(b) < 10:
            continue
        S = relative(pi[0], pj[0])
        R = np.asarray(R6, dtype=float)[[0, 1, 5]]
        e, _ = relation_errors(pose_to_matrix(S), pose_to_matrix(R))
        move = pose_to_matrix(compose(pi[0], R)) @ np.linalg.inv(pose_to_matrix(pj[0]))  # world, j's stretch
        ta = cKDTree(a)
        c_traj = alignment_cost(a, b, ta, cKDTree(b), np.zeros(3), truncate)
        moved = transform_points(move, b)
        c_rel = alignment_cost(a, moved, ta, cKDTree(moved), np.zeros(3), truncate)
        rows.append((t_i, t_j, float(e), c_rel, c_traj))
    if not rows:
        return {"relations_scored": 0}
    r = np.array(rows)
    err, c_rel, c_traj = r[:, 2], r[:, 3], r[:, 4]
    far = err > min_error
    contradicted = far & (c_traj < c_rel - margin)
    supported = far & (c_rel < c_traj - margin)
    t0 = float(min(rel.t_i.min(), rel.t_j.min()))
    out = {"window_s": window, "min_dt_s": min_dt, "relations_scored": int(len(r)),
           "mean_translation_error_m": float(err.mean()),
           "missed_by_more_than_min_error": int(far.sum()),
           "of_which_the_maps_align_better_at_the_trajectory": int(contradicted.sum()),
           "of_which_the_maps_align_better_at_the_relation": int(supported.sum()),
           "mean_translation_error_without_the_contradicted_m": (float(err[~contradicted].mean())
                                                                  if (~contradicted).any() else None),
           "rows": [{"t_i": float(a - t0), "t_j": float(b - t0), "error_m": float(e), "cost_at_relation_m": float(x),
                     "cost_at_trajectory_m": float(y)} for a, b, e, x, y in r]}
    rest = out["mean_translation_error_without_the_contradicted_m"]
    print(f"{name}: {len(r)} relations with dt > {min_dt:g} s, mean error {err.mean():.4f} m; {far.sum()} missed by "
          f"> {min_error} m, of which the maps of +-{window:g} s align better at the trajectory on "
          f"{contradicted.sum()} and at the relation on {supported.sum()}; without the contradicted ones the mean is "
          + ("n/a (all contradicted)" if rest is None else f"{rest:.4f} m"))
    return out


def evaluation_frames(name: str, traj: Trajectory, rel: Relations, offsets: list[float]) -> list[dict]:
    """The relations error of the trajectory carried by each offset along the robot's x axis, by class."""
    dt = np.abs(rel.t_j - rel.t_i)
    classes = {"all": np.ones(len(dt), bool), "dt_le_10s": dt <= 10, "dt_gt_60s": dt > 60,
               "facing_more_than_90deg_apart": np.abs(wrap_angle(rel.poses[:, 5])) > np.pi / 2}
    out = []
    for dx in offsets:
        t = relations_error(Trajectory(traj.stamps, compose(traj.poses, [dx, 0.0, 0.0])), rel).translation
        row = {"offset_x_m": float(dx)}
        row.update({f"{k}_m": float(t[m].mean()) if m.any() else None for k, m in classes.items()})
        row.update({f"{k}_n": int(m.sum()) for k, m in classes.items()})
        out.append(row)
    print(f"{name}: relations error (m) with the trajectory's frame moved along x")
    print("    dx     all  dt<=10   dt>60  facing>90")
    for r in out:
        cells = (f"{r[f'{k}_m']:7.4f}" if r[f"{k}_m"] is not None else "    n/a" for k in classes)
        print(f"{r['offset_x_m']:+6.2f} " + " ".join(cells))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", choices=list(FREIBURG))
    ap.add_argument("trajectory", type=Path, help="a TUM trajectory of the log (hsmap slam's trajectory.tum)")
    ap.add_argument("--truncate", type=float, default=0.3)
    ap.add_argument("--min-error", type=float, default=0.2)
    ap.add_argument("--margin", type=float, default=0.01)
    ap.add_argument("--frame-offsets", type=float, nargs="*",
                    default=[-0.5, -0.4, -0.3, -0.25, -0.2, -0.15, -0.1, 0.0, 0.1, 0.2, 0.3])
    ap.add_argument("--independent", type=Path, default=None,
                    help="a TUM trajectory of the log made without its odometry (hsmap slam --no-odometry)")
    ap.add_argument("--min-rotation", type=float, default=1.0, help="degrees, for --independent")
    ap.add_argument("--maps", action="store_true",
                    help="also score the long relations (dt > --maps-min-dt) map to map: stretches of +-"
                         "--maps-window s of scans around each end")
    ap.add_argument("--maps-window", type=float, default=15.0, help="seconds, for --maps")
    ap.add_argument("--maps-min-dt", type=float, default=60.0, help="seconds, for --maps")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    if a.maps and (problem := _maps_window_error(a.maps_window, a.maps_min_dt)):
        ap.error(problem)  # before anything is computed
    host = machine()
    datasets = datasets_dir()  # $HSMAP_DATASETS, else what hsmap data fetch downloaded, else ../shared/datasets
    traj = read_tum(a.trajectory, dof=3)
    rel = read_relations(datasets / "slam2d" / FREIBURG[a.log]["relations"])
    spec = FREIBURG[a.log]
    ds = open_dataset(datasets / "slam2d" / spec["bag"], extrinsic2d=spec["extrinsic2d"])
    frames = list(ds.frames(clouds=False))  # read once, for every check below
    out = audit(a.log, a.trajectory, traj, rel, frames, ds.odometry, a.truncate, a.min_error, a.margin)
    out["evaluation_frames"] = evaluation_frames(a.log, traj, rel, a.frame_offsets)
    out["odometry_copies"] = odometry_copies(a.log, traj, ds.odometry, rel)
    if a.independent is not None:
        out["contradicted_by_two_sensors"] = contradicted_by_two_sensors(
            a.log, traj, ds.odometry, read_tum(a.independent, dof=3), rel, a.min_rotation)
    if a.maps:
        out["maps"] = maps_audit(a.log, frames, traj, rel, a.maps_window, a.maps_min_dt, a.truncate, a.min_error,
                                 a.margin)
    out["machine"] = host
    path = a.out or ROOT / "reports" / "benchmarks" / f"relations_audit_{a.log}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    finish(out, path)


if __name__ == "__main__":
    main()
