"""Online 3D pose tracker: ``Tracker.update(frame, poses3d[, variance]) -> (ids, poses3d)``, frame by frame
(a live rig or a file).

Motion model: every joint of a track moves with constant velocity, filtered by a Kalman filter with
white-acceleration process noise (``accel_sd_m`` per frame^2), isotropic measurement noise
(``measurement_sd_m``) and a new track's velocity unknown (``velocity_sd_m`` per frame: any walking
speed at 5 frames per second); the three axes share one 2x2 covariance per joint. Time is counted in frames, so
a gap in the frame numbers is a longer prediction (missed frames), never a jump the velocity believes.

Association: the frame's persons against the tracks' predictions (the whole body moved with the mean
velocity of its head and trunk joints: limbs swing, the trunk moves steadily) by gated Hungarian assignment
(the most pairs under the gate, then the least cost: the sparse solver of the matcher, scipy's algorithm over
the pairs under the gate) on the mean distance over the head and trunk joints both have (all
shared joints where they share none of those), to the prediction or to the last position, whichever is
nearer (a person may stop or turn at any frame: the velocity guides, it does not bind), gated at
``max_distance_m`` (widened by ``gate_growth_m`` per frame since the track was last seen). A person no
track takes starts a tentative track; it is confirmed after ``min_hits`` consecutive hits, and a
tentative track missed once is dropped. A confirmed track dies after ``max_age`` frames without a hit,
so a person who comes back later gets a new id. Ids are given at birth and never reused.

Temporal evidence (``smooth``): each joint of a track is also filtered as a random walk whose process
variance follows the innovations (an exponential average, rate ``smooth_rate``, of how far the joint
moves beyond what its variances explain, at least ``smooth_floor_m`` squared; ``smooth_initial_m`` for a
new joint), updated with the reconstruction's joint and its variance (``variance``: the likelihood's
per-joint variance of the MAP, so exact 2D keeps the triangulated point and a joint the views do not fix
comes from the motion). A joint the reconstruction does not see in this frame moves on with its
velocity in the motion filter. A slow person is smoothed over many frames, a fast one over few: one default serves a band
playing at 30 fps and a crowd walking at 5 fps.

Each track also keeps its person's bone lengths: a robust running estimate (median and MAD-based SD of
the lengths seen in the last ``bone_window`` frames where both ends were reconstructed).

The state of all tracks is held in arrays over tracks (:class:`TrackState`), so a frame of a hundred
persons costs a few vectorised operations, not a hundred small ones; :attr:`Tracker.tracks` gives
per-track views (:class:`Track`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from data.assignment import solve_sparse_pairs
from data.bone_lengths import BONE_PAIRS, bone_lengths
from tracking.track_kernels import MAD_TO_SD, centres, correct_tracks, near_mean_distances, pair_mean_distances

# Joints of the association distance and the body's velocity: head and trunk (COCO-23 nose, eyes, ears,
# shoulders, hips) move with the body; arms and legs swing by tens of cm between frames at 5 fps.
CORE_JOINTS = np.array([0, 1, 2, 3, 4, 5, 6, 11, 12])
# m^2: variance of a joint no view sees, placed by the reconstruction's bone prior alone (a bone's direction is
# unknown: about 15 cm); the motion filter does not take such a joint as a measurement
UNSEEN_VAR_M2 = 0.15**2
SKELETON_REFRESH = 5  # hits between two updates of a track's robust skeleton (it changes slowly)
DENSE_PAIRS = 4096  # up to this many track x pose pairs, near_pairs measures them all (trees cost ~20 us)
COMPILED_PAIRS = 65536  # up to this many (400 x 200: even), mean_distances tests every pair in one compiled pass
BODY_SPAN_M = 1.0  # m: the centres of any two subsets of one body's head and trunk joints lie this close


class Tracked(NamedTuple):
    """One frame's output of the tracker: ids (P,) and poses (P, J, 4), smoothed where the tracker smooths."""

    ids: np.ndarray
    poses3d: np.ndarray


@dataclass
class Track:
    """A snapshot of one track: id, joint positions (J, 3), velocities (J, 3) m / frame, joints ever seen
    (J,), last frame with a hit, hits, confirmed, and the bone lengths of its last observations (n, L)."""

    id: int
    position: np.ndarray
    velocity: np.ndarray
    seen: np.ndarray
    last_frame: int
    hits: int
    confirmed: bool
    bones: np.ndarray

    def bone_lengths(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Robust bone lengths of the track: median (L,) m, SD (L,) m (MAD-based) and count (L,); NaN unseen."""
        return robust_lengths(self.bones)


def robust_lengths(lengths: np.ndarray, axis: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Median, MAD-based SD and count along an axis, NaN = not observed: e.g. (n, L) -> (L,) x3, or
    (K, n, L) with axis 1 -> (K, L) x3; median and SD NaN where nothing was observed."""
    lengths = np.moveaxis(np.asarray(lengths, dtype=np.float64), axis, -1)
    count = np.isfinite(lengths).sum(axis=-1)
    median = _sorted_median(lengths, count)
    mad = _sorted_median(np.abs(lengths - median[..., None]), count)
    return median, np.where(count > 1, MAD_TO_SD * mad, np.nan), count


def _sorted_median(values: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Median of the finite values along the last axis, NaN last after sorting: (..., n), (...) -> (...)."""
    ordered = np.sort(values, axis=-1)  # NaN sort to the end
    lo = np.maximum(count - 1, 0) // 2
    hi = np.minimum(count // 2, max(values.shape[-1] - 1, 0))
    if values.shape[-1] == 0:
        return np.full(count.shape, np.nan)
    pick = lambda k: np.take_along_axis(ordered, k[..., None], axis=-1)[..., 0]  # noqa: E731
    return np.where(count > 0, 0.5 * (pick(lo) + pick(hi)), np.nan)


@dataclass
class TrackState:
    """All tracks as arrays: ids (T,), position / velocity (T, J, 3), per-axis covariance entries p00, p01,
    p11 (T, J) of (position, velocity), seen (T, J), last_frame, hits (T,), confirmed (T,), bones (T, W, L)
    ring buffer of bone lengths (NaN = none) with its next slot (T,); the smoothed joints sx (T, J, 3), their
    per-axis variance sp (T, J) and adaptive process variance sq (T, J) m^2 per frame; live (T, J): measured at
    the last hit (association and the body's velocity use these: a joint unmeasured for a while drifts); the
    skeleton's robust bone lengths skel_median, standard errors skel_se and counts skel_count (T, L), refreshed
    every SKELETON_REFRESH hits."""

    ids: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    p00: np.ndarray
    p01: np.ndarray
    p11: np.ndarray
    seen: np.ndarray
    last_frame: np.ndarray
    hits: np.ndarray
    confirmed: np.ndarray
    bones: np.ndarray
    slot: np.ndarray
    sx: np.ndarray
    sp: np.ndarray
    sq: np.ndarray
    live: np.ndarray
    skel_median: np.ndarray
    skel_se: np.ndarray
    skel_count: np.ndarray

    @classmethod
    def empty(cls, joints: int, window: int) -> "TrackState":
        """No track, for poses of J joints and a bone window W."""
        z = lambda *shape, dtype=np.float64: np.zeros((0, *shape), dtype=dtype)  # noqa: E731
        return cls(
            z(dtype=np.int64),
            z(joints, 3),
            z(joints, 3),
            z(joints),
            z(joints),
            z(joints),
            z(joints, dtype=bool),
            z(dtype=np.int64),
            z(dtype=np.int64),
            z(dtype=bool),
            z(window, len(BONE_PAIRS)),
            z(dtype=np.int64),
            z(joints, 3),
            z(joints),
            z(joints),
            z(joints, dtype=bool),
            z(len(BONE_PAIRS)),
            z(len(BONE_PAIRS)),
            z(len(BONE_PAIRS), dtype=np.int64),
        )

    def __len__(self) -> int:
        return len(self.ids)

    def select(
        self, keep: np.ndarray, then: "TrackState | None" = None, pool: np.ndarray | None = None
    ) -> "TrackState":
        """The tracks of a boolean mask (T,), followed by then's tracks if given, each field copied once; these
        tracks themselves when the mask keeps all and nothing follows.

        A track's bone window is most of its bytes (100 tracks: 2 MB). With ``pool`` (C, W, L), whose first T rows
        are this state's bone windows (self.bones is pool[:T]) and C >= the tracks out, the windows stay in it:
        the kept ones after the first track dropped move up, then's are written after them (self is spent)."""
        if keep.all() and then is None:
            return self
        rows = np.flatnonzero(keep)
        added = 0 if then is None else len(then)
        fields = []
        for f in self.__dataclass_fields__:
            old = getattr(self, f)
            if f == "bones" and pool is not None:
                shifted = np.flatnonzero(rows != np.arange(len(rows)))  # rows before the first drop stay
                moved = int(shifted[0]) if len(shifted) else len(rows)
                pool[moved : len(rows)] = old[rows[moved:]]  # (a fancy index reads all before the rows are written)
                if added:
                    pool[len(rows) : len(rows) + added] = then.bones
                fields.append(pool[: len(rows) + added])
                continue
            out = np.empty((len(rows) + added, *old.shape[1:]), dtype=old.dtype)
            np.take(old, rows, axis=0, out=out[: len(rows)], mode="clip")  # rows are valid; "raise" buffers
            if added:
                out[len(rows) :] = getattr(then, f)
            fields.append(out)
        return TrackState(*fields)

    def arrays(self) -> tuple[np.ndarray, ...]:
        """The arrays of the compiled correction (track_kernels.correct_tracks): every field but ids, in order."""
        return tuple(getattr(self, f) for f in self.__dataclass_fields__ if f != "ids")


def bone_lengths_of(poses3d: np.ndarray) -> np.ndarray:
    """Bone lengths of poses, NaN where an end is missing: (P, J, 4) -> (P, L) m."""
    ok = (poses3d[:, BONE_PAIRS[:, 0], 3] > 0) & (poses3d[:, BONE_PAIRS[:, 1], 3] > 0)
    return np.where(ok, bone_lengths(poses3d), np.nan)


def _core_mask(joints: int) -> np.ndarray:
    """The head and trunk joints among J: (J,) bool."""
    core = np.zeros(joints, dtype=bool)
    core[CORE_JOINTS[CORE_JOINTS < joints]] = True
    return core


def mean_distances(guess: np.ndarray, seen: np.ndarray, poses3d: np.ndarray, max_m: float = np.inf) -> np.ndarray:
    """Mean distance over the head and trunk joints both have (all shared joints where they share none):
    guesses (T, J, 3) with seen (T, J), poses (P, J, 4) -> (T, P) m, inf where nothing is shared. Pairs
    whose head-and-trunk centres are farther apart than max_m + BODY_SPAN_M are inf without computing."""
    guess, seen = np.ascontiguousarray(guess, dtype=np.float64), np.ascontiguousarray(seen, dtype=bool)
    poses3d = np.ascontiguousarray(poses3d, dtype=np.float64)
    valid = poses3d[..., 3] > 0
    core = _core_mask(poses3d.shape[1])
    ca, cb, radius = _centres(guess, seen, core), _centres(poses3d, valid, core), max_m + BODY_SPAN_M
    out = np.full((len(guess), len(poses3d)), np.inf)
    if len(ca) * len(cb) <= COMPILED_PAIRS:  # every pair in one compiled pass
        near_mean_distances(guess, seen, poses3d, valid, core, ca, cb, float(radius), out)
        return out
    rows, cols = near_pairs(ca, cb, radius)
    pair_mean_distances(
        guess, seen, poses3d, valid, core, rows.astype(np.int64, copy=False), cols.astype(np.int64, copy=False), out
    )
    return out


def near_pairs(a: np.ndarray, b: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j) of points a (T, 3) and b (P, 3) at most radius apart -> rows (K,), cols (K,); points
    with a non-finite coordinate have none. KD-trees (scipy): a dense (T, P) distance matrix of 400 people's
    tracks and poses took 2.6 ms, the trees 0.3 ms."""
    ia, ib = np.flatnonzero(np.isfinite(a).all(axis=1)), np.flatnonzero(np.isfinite(b).all(axis=1))
    if len(ia) * len(ib) <= DENSE_PAIRS or not np.isfinite(radius):  # few: building trees costs more
        d = a[ia][:, None] - b[ib][None]
        rows, cols = np.nonzero(np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2 + d[..., 2] ** 2) <= radius)
        return ia[rows], ib[cols]
    pairs = cKDTree(a[ia]).sparse_distance_matrix(cKDTree(b[ib]), radius, output_type="ndarray")
    return ia[pairs["i"]], ib[pairs["j"]]


def predicted_positions(position: np.ndarray, velocity: np.ndarray, live: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """Each track moved by dt (T,) times its body velocity, the mean velocity of its live head and trunk joints (of
    all its live joints without any; 0 without any): position, velocity (T, J, 3), live (T, J) -> (T, J, 3)."""
    body = _centres(velocity, live, _core_mask(live.shape[1]))  # the compiled mean, summed as numpy's sum would
    return position + dt[:, None, None] * body[:, None, :]


def _centres(points: np.ndarray, ok: np.ndarray, core: np.ndarray) -> np.ndarray:
    """Mean of the valid head and trunk joints (of all valid joints without any): (N, J, >= 3), (N, J) -> (N, 3)."""
    out = np.empty((len(points), 3))
    centres(points, ok, core, out)
    return out


@lru_cache(maxsize=1)
def warm_up() -> None:
    """Compile the tracker's kernels (or load them from numba's cache) once per process, on one person and one
    guess (a track's correction on none), so that a first frame is not timed with the compiler."""
    J = len(CORE_JOINTS)
    pose, none = np.ones((1, J, 4)), np.zeros(0, dtype=np.int64)
    mean_distances(np.ones((1, J, 3)), np.ones((1, J), dtype=bool), pose)  # the compiled pass over every pair
    core, one = _core_mask(J), np.zeros(1, dtype=np.int64)  # ... and the large crowds' pairs from the KD-trees
    pair_mean_distances(
        pose[..., :3].copy(), pose[..., 3] > 0, pose, pose[..., 3] > 0, core, one, one, np.empty((1, 1))
    )
    filters, counts = (UNSEEN_VAR_M2, 1.0, 1.0, 1.0, 1.0, 1.0), (1, SKELETON_REFRESH)
    lengths = np.ones((1, len(BONE_PAIRS)))
    correct_tracks(
        TrackState.empty(J, 1).arrays(),
        none,
        none,
        1,
        pose,
        np.ones((1, J)),
        lengths,
        filters,
        counts,
        pose.copy(),
        True,
    )


class Tracker:
    """Frame-by-frame tracker of 3D poses: ``update(frame, poses3d (P, J, 4), ...) -> Tracked(ids (P,), poses3d)``."""

    def __init__(
        self,
        max_distance_m: float = 0.5,
        gate_growth_m: float = 0.1,
        min_hits: int = 3,
        max_age: int = 10,
        accel_sd_m: float = 0.05,
        measurement_sd_m: float = 0.03,
        velocity_sd_m: float = 0.5,
        bone_window: int = 100,
        smooth: bool = True,
        smooth_rate: float = 0.3,
        smooth_floor_m: float = 0.001,
        smooth_initial_m: float = 0.01,
        skeleton_min_frames: int = 5,
    ) -> None:
        if not min(max_distance_m, accel_sd_m, measurement_sd_m, velocity_sd_m) > 0 or not gate_growth_m >= 0:
            raise ValueError(
                "tracking: max_distance_m, accel_sd_m, measurement_sd_m, velocity_sd_m must be > 0 and "
                f"gate_growth_m >= 0; got {max_distance_m}, {accel_sd_m}, {measurement_sd_m}, "
                f"{velocity_sd_m}, {gate_growth_m}"
            )
        if int(min_hits) < 1 or int(max_age) < 0 or int(bone_window) < 1:
            raise ValueError(
                f"tracking: need min_hits >= 1, max_age >= 0, bone_window >= 1; got {min_hits}, "
                f"{max_age}, {bone_window}"
            )
        self.max_distance_m, self.gate_growth_m = float(max_distance_m), float(gate_growth_m)
        self.min_hits, self.max_age, self.bone_window = int(min_hits), int(max_age), int(bone_window)
        self.q, self.r2, self.v2 = float(accel_sd_m) ** 2, float(measurement_sd_m) ** 2, float(velocity_sd_m) ** 2
        if not (0 < smooth_rate <= 1 and smooth_floor_m > 0 and smooth_initial_m > 0):
            raise ValueError(
                f"tracking: need 0 < smooth_rate <= 1, smooth_floor_m > 0, smooth_initial_m > 0; got "
                f"{smooth_rate}, {smooth_floor_m}, {smooth_initial_m}"
            )
        self.smooth, self.smooth_rate = bool(smooth), float(smooth_rate)
        self.skeleton_min_frames = int(skeleton_min_frames)  # 0: the tracks' skeletons are never offered
        self.smooth_floor2, self.smooth_q0 = float(smooth_floor_m) ** 2, float(smooth_initial_m) ** 2
        self.state: TrackState | None = None
        self._pairing: tuple | None = None  # (frame, persons, track ids, person indices) of skeletons()
        self._pool: np.ndarray | None = None  # the tracks' bone windows and room for more (_bone_pool)
        self.last_frame: int | None = None
        self._next_id = 0

    @property
    def tracks(self) -> list[Track]:
        """Snapshots of the live tracks, oldest first."""
        st = self.state
        if st is None:
            return []
        return [
            Track(
                int(st.ids[t]),
                st.position[t].copy(),
                st.velocity[t].copy(),
                st.seen[t].copy(),
                int(st.last_frame[t]),
                int(st.hits[t]),
                bool(st.confirmed[t]),
                st.bones[t][np.isfinite(st.bones[t]).any(axis=1)],
            )
            for t in range(len(st))
        ]

    def update(
        self,
        frame: int,
        poses3d: np.ndarray,
        variance: np.ndarray | None = None,
        bone_lengths: np.ndarray | None = None,
    ) -> Tracked:
        """Associate one frame's persons with the tracks and update them: (P, J, 4), per-joint variance (P, J)
        m^2 of the reconstruction -> Tracked(ids (P,), poses3d (P, J, 4)), the poses smoothed over time where
        ``smooth`` and variances are given (a new track's as given). Without variances (a reconstruction that
        has none, e.g. reconstruction=vanilla) the poses pass through and the motion filter takes
        ``measurement_sd_m`` for every joint. ``bone_lengths`` (P, L) m, NaN where unmeasured: the bones the
        reconstruction measured (before its prior), which the tracks keep instead of the output poses'.

        Frame numbers must increase; a gap counts as missed frames for every track.
        """
        frame = int(frame)
        if self.last_frame is not None and frame <= self.last_frame:
            raise ValueError(
                f"tracking: frame {frame} comes after frame {self.last_frame}; frame numbers must "
                "increase (sort the sequence, remove repeated frames)"
            )
        poses3d = np.ascontiguousarray(poses3d, dtype=np.float64)
        if poses3d.ndim != 3 or poses3d.shape[-1] != 4:
            raise ValueError(f"tracking: poses must be (P, J, 4), got {poses3d.shape}")
        smooth = self.smooth and variance is not None  # without variances nothing to weigh: ids only
        variance = self._variance(variance, poses3d)
        bones = self._bones(bone_lengths, poses3d, variance)
        if self.state is None:
            self.state = TrackState.empty(poses3d.shape[1], self.bone_window)
        self.last_frame = frame
        # the tracks alive since the last frame (the others are gone during a gap) are matched and corrected in
        # place, then one select keeps the survivors: each copy of the tracks copies their bone windows (2 MB at 100)
        st, alive = self.state, self._alive(self.state, frame - 1)
        tracks, persons = self._reused_pairing(st, frame, len(poses3d)) or self._associate(st, frame, poses3d, alive)
        ids = np.full(len(poses3d), -1, dtype=np.int64)
        out = poses3d.copy()
        if len(tracks):
            self._correct(st, tracks, persons, frame, poses3d, variance, bones, out if smooth else None)
            ids[persons] = st.ids[tracks]
        hit = np.zeros(len(st), dtype=bool)
        hit[tracks] = True
        born, births = np.flatnonzero(ids < 0), None
        if len(born):
            ids[born] = np.arange(self._next_id, self._next_id + len(born))
            self._next_id += len(born)
            births = self._births(ids[born], frame, poses3d[born], variance[born], bones[born])
        keep = alive & (hit | self._alive(st, frame))
        self.state = st.select(keep, births, self._bone_pool(st, int(keep.sum()) + len(born)))  # survivors, then births
        return Tracked(ids, out)

    def skeletons(self, frame: int, poses3d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The bone lengths of the confirmed track each person of a coming frame would join, without updating:
        (P, J, 4) -> median (P, L) m and its standard error (P, L) m (MAD-based SD / sqrt(count)); NaN / inf
        where the person joins no confirmed track or a bone was seen in fewer than skeleton_min_frames frames."""
        median = np.full((len(poses3d), len(BONE_PAIRS)), np.nan)
        se = np.full(median.shape, np.inf)
        stale = self.last_frame is not None and frame <= self.last_frame
        if self.state is None or not len(self.state) or not self.skeleton_min_frames or stale:
            return median, se
        st = self.state
        tracks, persons = self._associate(st, frame, np.asarray(poses3d, dtype=np.float64), self._alive(st, frame - 1))
        self._pairing = (frame, len(poses3d), st.ids[tracks], persons)  # update() reuses it for this frame
        keep = st.confirmed[tracks]
        tracks, persons = tracks[keep], persons[keep]
        if len(tracks):
            ok = st.skel_count[tracks] >= self.skeleton_min_frames
            median[persons] = np.where(ok, st.skel_median[tracks], np.nan)
            se[persons] = np.where(ok, st.skel_se[tracks], np.inf)
        return median, se

    @staticmethod
    def _bones(lengths: np.ndarray | None, poses3d: np.ndarray, variance: np.ndarray) -> np.ndarray:
        """The bone lengths each person adds to its track (P, L): the given ones, else those of the joints the
        reconstruction measured (variance below UNSEEN_VAR_M2)."""
        if lengths is not None:
            lengths = np.asarray(lengths, dtype=np.float64)
            if lengths.shape != (len(poses3d), len(BONE_PAIRS)):
                raise ValueError(f"tracking: bone lengths {lengths.shape} do not match {len(poses3d)} poses")
            return lengths
        return bone_lengths_of(np.where((variance < UNSEEN_VAR_M2)[..., None], poses3d, 0.0))

    def _variance(self, variance: np.ndarray | None, poses3d: np.ndarray) -> np.ndarray:
        """The joints' measurement variances (P, J) m^2: the given ones where finite and > 0 (at most
        UNSEEN_VAR_M2), UNSEEN_VAR_M2 where no view fixes the joint; without any, measurement_sd_m squared."""
        if variance is None:
            return np.full(poses3d.shape[:2], self.r2)
        variance = np.asarray(variance, dtype=np.float64)
        if variance.shape != poses3d.shape[:2]:
            raise ValueError(f"tracking: variances {variance.shape} do not match poses {poses3d.shape}")
        return np.where(np.isfinite(variance) & (variance > 0), np.minimum(variance, UNSEEN_VAR_M2), UNSEEN_VAR_M2)

    def _reused_pairing(self, st: TrackState, frame: int, persons: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The assignment :meth:`skeletons` made for this frame's persons (from the MLE poses, before the MAP
        moved them by millimetres), as track indices of st and person indices; None if there is none."""
        pairing, self._pairing = self._pairing, None
        if pairing is None or pairing[0] != frame or pairing[1] != persons:
            return None
        index = {int(i): t for t, i in enumerate(st.ids)}
        tracks = np.array([index.get(int(i), -1) for i in pairing[2]], dtype=np.int64)
        return (tracks, pairing[3]) if np.all(tracks >= 0) else None

    def _bone_pool(self, st: TrackState, tracks: int) -> np.ndarray:
        """The buffer of the tracks' bone windows (C, W, L), C >= tracks, whose first rows are st's (moved into a
        larger one, twice the tracks, when it is short): TrackState.select keeps the windows in it."""
        pool = self._pool
        inside = pool is not None and st.bones.base is pool and st.bones.ctypes.data == pool.ctypes.data
        if not inside or len(pool) < tracks:
            pool = np.empty((max(2 * tracks, 16), *st.bones.shape[1:]))
            pool[: len(st)] = st.bones
            self._pool = pool
        return pool

    def _alive(self, st: TrackState, frame: int) -> np.ndarray:
        """Which tracks not hit after their last frame survive up to this frame: tentative ones die at once,
        confirmed ones after max_age frames without a hit: (T,) bool."""
        return frame - st.last_frame <= np.where(st.confirmed, self.max_age, 0)

    def _associate(
        self, st: TrackState, frame: int, poses3d: np.ndarray, alive: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Gated Hungarian assignment of the alive tracks (a mask (T,)) to persons: -> track indices of st (K,),
        person indices (K,)."""
        none = np.zeros(0, dtype=np.int64)
        rows = np.flatnonzero(alive)
        if not len(rows) or not len(poses3d):
            return none, none
        position, live, seen = st.position[rows], st.live[rows], st.seen[rows]
        dt = (frame - st.last_frame[rows]).astype(np.float64)
        predicted = predicted_positions(position, st.velocity[rows], live, dt)
        gate = self.max_distance_m + self.gate_growth_m * (dt - 1.0)
        live = np.where(live.any(axis=1, keepdims=True), live, seen)
        both = mean_distances(  # the prediction and the last position in one pass: (2T, P)
            np.concatenate([predicted, position]), np.concatenate([live, live]), poses3d, gate.max()
        )
        cost = np.minimum(both[: len(rows)], both[len(rows) :])
        # row-major (rows ascending, as the solver wants them) and contiguous (np.nonzero's are strided views)
        pick, cols = np.divmod(np.flatnonzero(cost <= gate[:, None]), cost.shape[1])
        keep = solve_sparse_pairs(np.array([0, len(pick)]), np.array([cost.shape]), pick, cols, cost[pick, cols])
        return rows[pick[keep]].astype(np.int64), cols[keep].astype(np.int64)

    def _births(
        self, ids: np.ndarray, frame: int, poses3d: np.ndarray, variance: np.ndarray, lengths: np.ndarray
    ) -> TrackState:
        """Tentative tracks at persons' joints: ids (B,), (B, J, 4), joint variances (B, J) -> B tracks."""
        (B, J), L = poses3d.shape[:2], len(BONE_PAIRS)
        seen = poses3d[..., 3] > 0
        bones = np.full((B, self.bone_window, L), np.nan)
        bones[:, 0] = lengths
        return TrackState(
            ids.astype(np.int64),
            np.where(seen[..., None], poses3d[..., :3], 0.0),
            np.zeros((B, J, 3)),
            np.full((B, J), self.r2),
            np.zeros((B, J)),
            np.full((B, J), self.v2),
            seen,
            np.full(B, frame, dtype=np.int64),
            np.ones(B, dtype=np.int64),
            np.full(B, self.min_hits <= 1),
            bones,
            np.ones(B, dtype=np.int64) % self.bone_window,
            np.where(seen[..., None], poses3d[..., :3], 0.0),
            np.where(seen, variance, 0.0),
            np.full((B, J), self.smooth_q0),
            seen & (variance < UNSEEN_VAR_M2),
            np.full((B, L), np.nan),
            np.full((B, L), np.inf),
            np.zeros((B, L), dtype=np.int64),
        )

    def _correct(
        self,
        st: TrackState,
        tracks: np.ndarray,
        persons: np.ndarray,
        frame: int,
        poses3d: np.ndarray,
        variance: np.ndarray,
        lengths: np.ndarray,
        out: np.ndarray | None,
    ) -> None:
        """Kalman predict over the frames since each track's last hit, then update with the observed joints
        (a joint seen for the first time starts there), and the smoother of each joint: a random walk whose process
        variance follows the innovations (a joint the reconstruction does not see moves on with its motion-filter
        velocity), updated with the reconstruction's joint (its variance); then the bone lengths: tracks (K,) hit by
        persons (K,) of poses (P, J, 4), variances (P, J), lengths (P, L); st changed in place (the smoother, then the
        motion filter, then the bones); out (P, J, 4), unless None, takes the smoothed joints of confirmed tracks
        (a new one may be a wrong match)."""
        filters = (UNSEEN_VAR_M2, self.q, self.r2, self.smooth_rate, self.smooth_floor2, self.smooth_q0)
        correct_tracks(
            st.arrays(),
            tracks.astype(np.int64, copy=False),
            persons.astype(np.int64, copy=False),
            frame,
            poses3d,
            variance,
            np.ascontiguousarray(lengths),
            filters,
            (self.min_hits, SKELETON_REFRESH),
            poses3d if out is None else out,
            out is not None,
        )
