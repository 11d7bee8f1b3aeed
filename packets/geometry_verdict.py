"""The geometry verdict of a camera: its LiDAR-edge score against a shuffled-pairs null (pure math).

Input: a score matrix S (n, n) float64 over n views of one camera, S[i, j] = the LiDAR-edge
alignment score (`packets.edges.alignment_score`) of view i's LiDAR edge points, placed by
view i's recorded geometry, read on view j's image edges. The diagonal holds the real pairs;
an off-diagonal entry is what the score is when the geometry says nothing about the image.
`allowed` (n, n) bool marks the off-diagonal pairs fit for the null: views far enough apart in
time and whose images differ (a static robot's views are all alike, and the LiDAR of one then
fits the image of another as well as its own).

The null: T_null = mean over the null rows i of S[i, J_i], J_i drawn uniformly from the allowed
j of row i, independently per row ("the LiDAR of view i against the image of a random other
view"). Its mean and standard deviation are exact (`null_moments`); its tail probability is
counted over `draws` seeded draws: p = (1 + #{T_null >= T}) / (1 + draws), a tie counting
against the observed value T = mean over the same rows of S[i, i].

The verdict (`decide`): `failed` when, with ample edge points, a small search of the geometry
(`best`: a rotation, a clock offset) scores far higher than the recorded one (T < `below_best` x
best, the best significant: the camera's own data allow more; the likely cause is what the
search moved), or T is indistinguishable from the null (z < `z_fail`, and fewer than
`wins_fail` of the views beat the median of their null row); `ok` when T stands out of the
null (z >= `Thresholds.z_ok` and p <= `p_ok`); `inconclusive` otherwise, with the reason.
Cross-view consistency (`packets.view_overlap.CrossView`, where given) enters too: with ample
overlap, a score that stands out on each view's own image but falls to the null across views
(z < `z_fail` and below `below_best` x the views' own score) is `failed`, the cause the pose
source / frames (only the motion between views sees a wrong odometry: a view's own score
hardly depends on it); an `ok` whose views overlap nowhere is `inconclusive` (no overlap), and
one a searched geometry beats by more than `1 - near_best` is `inconclusive` naming it.
Thin evidence (too few views, textureless images, a static robot; too few edge points or too
coarse a scan to fail) is never `failed`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from packets.null_stats import z_score
from packets.view_overlap import CrossView

F64 = npt.NDArray[np.float64]
B = npt.NDArray[np.bool_]

OK, INCONCLUSIVE, FAILED = "ok", "inconclusive", "failed"
VERDICTS = (OK, INCONCLUSIVE, FAILED)
"""The verdicts, best first."""


@dataclass(frozen=True)
class NullTest:
    """The observed mean diagonal score T, the null's exact mean and standard deviation, the
    tail probability p of T under the null, z = (T - mean) / std (+inf when std is 0 and T
    above the mean, 0 when equal, -inf below), the share of null rows whose own score is
    above the median of their allowed row (`wins`, ties are losses), and the rows used."""

    observed: float
    null_mean: float
    null_std: float
    p_value: float
    z: float
    wins: float
    rows: int


def null_rows(allowed: B, min_pairs: int) -> npt.NDArray[np.int64]:
    """Rows (views) with at least `min_pairs` allowed null pairs, the diagonal never allowed."""
    a = np.asarray(allowed, bool) & ~np.eye(len(allowed), dtype=bool)
    out: npt.NDArray[np.int64] = np.flatnonzero(a.sum(1) >= min_pairs)
    return out


def null_moments(S: F64, allowed: B, rows: npt.NDArray[np.int64]) -> tuple[float, float]:
    """Exact mean and standard deviation of T_null over `rows` (module docstring): the mean of
    the row means of the allowed entries, and sqrt(sum of the rows' population variances) / n."""
    means, variances = [], []
    for i in rows:
        vals = S[i, allowed[i] & (np.arange(len(S)) != i)]
        means.append(vals.mean())
        variances.append(vals.var())
    n = len(rows)
    return float(np.mean(means)), float(np.sqrt(np.sum(variances)) / n)


def null_draws(S: F64, allowed: B, rows: npt.NDArray[np.int64], draws: int,
               seed: int = 0) -> F64:
    """`draws` values (draws,) of T_null, one allowed column per row drawn uniformly (seeded)."""
    rng = np.random.default_rng(seed)
    total = np.zeros(draws)
    for i in rows:
        vals = S[i, allowed[i] & (np.arange(len(S)) != i)]
        total += vals[rng.integers(0, len(vals), draws)]
    out: F64 = total / len(rows)
    return out


def tail_p(observed: float, null: F64) -> float:
    """(1 + #{null >= observed}) / (1 + len(null)): ties count against the observed value."""
    return float((1 + np.count_nonzero(null >= observed)) / (1 + len(null)))


def win_share(S: F64, allowed: B, rows: npt.NDArray[np.int64]) -> float:
    """Share of `rows` whose own score S[i, i] is strictly above the median of their allowed
    row (0 without rows)."""
    if not len(rows):
        return 0.0
    wins = [S[i, i] > np.median(S[i, allowed[i] & (np.arange(len(S)) != i)]) for i in rows]
    return float(np.mean(wins))


def null_test(S: npt.ArrayLike, allowed: npt.ArrayLike, min_pairs: int = 3,
              draws: int = 2000, seed: int = 0) -> NullTest | None:
    """The shuffled-pairs null test of score matrix S (n, n) with its `allowed` (n, n) null
    pairs (module docstring); None when no row has `min_pairs` allowed pairs."""
    s = np.asarray(S, np.float64)
    a = np.asarray(allowed, bool)
    if s.ndim != 2 or s.shape[0] != s.shape[1] or a.shape != s.shape:
        raise ValueError(f"score matrix {s.shape} and allowed {a.shape} must be one (n, n)")
    rows = null_rows(a, min_pairs)
    if not len(rows):
        return None
    observed = float(np.mean(s[rows, rows]))
    mean, std = null_moments(s, a, rows)
    p = tail_p(observed, null_draws(s, a, rows, draws, seed))
    return NullTest(observed, mean, std, p, z_score(observed, mean, std),
                    win_share(s, a, rows), len(rows))


@dataclass(frozen=True)
class Thresholds:
    """Where the verdict changes. ok: z >= z_ok and p <= p_ok; failed when indistinguishable:
    z < z_fail and fewer than wins_fail of the views beat their null median (chance: half);
    failed when far below the searched best: observed < below_best x best while
    the best is significant (z >= z_ok); not ok below near_best x a significant best.
    Cross-view failed needs >= min_pairs overlapping view pairs. Any verdict but inconclusive
    needs >= min_views null rows; failed also >= min_points edge points and a LiDAR angular
    step <= max_step_deg (a sparser scan places its edges too coarsely to blame the geometry:
    a 2048-point sweep of 64 columns, 5.6 deg, scored at the null on good synthetic plaza
    views; a 32 x 32 sweep, 11 deg columns, "found" a pitch of +8 deg on good views)."""

    z_ok: float = 4.0
    p_ok: float = 0.01
    z_fail: float = 2.0
    wins_fail: float = 0.65
    below_best: float = 0.75
    near_best: float = 0.9
    min_pairs: int = 8
    min_views: int = 8
    min_points: int = 300
    max_step_deg: float = 1.5


@dataclass(frozen=True)
class Evidence:
    """What the test saw: views scored, LiDAR edge points over them, views whose image has no
    edges (flat), why the null could not be built (empty when it could), and the LiDAR's
    angular step (deg; 0 when unknown): its azimuth step or, when coarser, the density bound
    of `packets.scan_resolution`."""

    views: int
    points: int
    flat_views: int = 0
    null_problem: str = ""
    step_deg: float = 0.0


@dataclass(frozen=True)
class Search:
    """The best score a small search of the geometry reached, its z against the same null,
    and what it moved (one line: 'extrinsic rotation 4.9 deg', 'clock offset +120 ms')."""

    score: float
    z: float
    moved: str


@dataclass(frozen=True)
class Verdict:
    """One camera's verdict (`ok`, `inconclusive`, `failed`), the reason in one line, and the
    likely cause of a failure (empty otherwise)."""

    verdict: str
    reason: str
    cause: str = ""


POSE_CAUSE = "pose source / frames (the odometry or a frame of the chain is not the robot's)"
"""The cause named when no searched rotation or clock offset brings the score up."""


def evidence_problem(ev: Evidence, th: Thresholds) -> str:
    """Why the evidence is too thin for `ok` or `failed` ('' when it is not): the null could
    not be built, or fewer than `min_views` views."""
    if ev.null_problem:
        return ev.null_problem
    if ev.views < th.min_views:
        flat = f", {ev.flat_views} without image edges (textureless)" if ev.flat_views else ""
        return f"{ev.views} view(s) with LiDAR and image edges{flat}; {th.min_views} needed"
    return ""


def _numbers(t: NullTest) -> str:
    """The test in words: score, null mean +- std, z, p."""
    return (f"LiDAR-edge score {t.observed:.4f} vs null {t.null_mean:.4f} +- {t.null_std:.4f} "
            f"(z {t.z:.1f}, p {t.p_value:.3g}, {t.rows} views)")


def decide(test: NullTest | None, ev: Evidence, best: Search | None = None,
           th: Thresholds | None = None, cross: CrossView | None = None) -> Verdict:
    """The verdict of one camera (module docstring): inconclusive without a null test or with
    too few views; failed when, with enough edge points of a fine enough scan, a searched geometry
    scores far higher (the cause: what it moved), the views disagree with each other (`cross`;
    the cause `POSE_CAUSE`) or the score is indistinguishable from the null (z < `z_fail`, fewer
    than `wins_fail` of the views beating their null median; the cause: what a significant search
    moved, else `POSE_CAUSE`); ok when the score stands out, no searched geometry comes near
    beating it and the views agree where they overlap; inconclusive otherwise."""
    th = th or Thresholds()
    thin = evidence_problem(ev, th) or ("no view pair fit for the null" if test is None else "")
    if test is None or thin:
        return Verdict(INCONCLUSIVE, thin)
    said = _numbers(test) + (f"; {cross.line()}" if cross is not None else "")
    sparse = (f"{ev.points} LiDAR edge point(s), {th.min_points} needed to fail it"
              if ev.points < th.min_points else
              f"the LiDAR's angular step {ev.step_deg:.2f} deg is too coarse to fail it "
              f"({th.max_step_deg} at most)" if ev.step_deg > th.max_step_deg else "")
    ample = not sparse
    strong = best is not None and best.z >= th.z_ok
    if ample and best is not None and strong and test.observed < th.below_best * best.score:
        return Verdict(FAILED, f"{said}; {best.moved} reaches {best.score:.4f} (z "
                       f"{best.z:.1f})", best.moved)
    if ample and cross is not None and _disagree(cross, th):
        return Verdict(FAILED, f"{said}: the views disagree with each other", POSE_CAUSE)
    if test.z >= th.z_ok and test.p_value <= th.p_ok:
        if best is not None and strong and test.observed < th.near_best * best.score:
            return Verdict(INCONCLUSIVE, f"{said}; {best.moved} scores higher: "
                           f"{best.score:.4f} (z {best.z:.1f})", best.moved)
        if cross is not None and cross.problem:
            return Verdict(INCONCLUSIVE, said)
        return Verdict(OK, said)
    if not ample:
        return Verdict(INCONCLUSIVE, f"{said}: {sparse}")
    if test.z < th.z_fail and test.wins < th.wins_fail:
        cause = best.moved if best is not None and strong else POSE_CAUSE
        return Verdict(FAILED, f"{said}: indistinguishable from the null", cause)
    return Verdict(INCONCLUSIVE, f"{said}: above the null, not clearly")


def _disagree(cross: CrossView, th: Thresholds) -> bool:
    """Whether views that overlap disagree: enough overlapping pairs, the cross score not
    above the null (z < z_fail) and below `below_best` x the views' own score."""
    return (not cross.problem and cross.pairs >= th.min_pairs and cross.z < th.z_fail
            and cross.score < th.below_best * cross.own)
