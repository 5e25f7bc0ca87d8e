"""Online 3D pose tracker, frame by frame: ``associate``, optionally ``skeleton_prior``, then ``update`` (ids)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from data.assignment import solve_sparse_pairs
from data.bone_lengths import BONE_PAIRS, bone_lengths
from reconstruction.results import Reconstruction, SkeletonPrior
from tracking import track_kernels as kernels
from tracking.track_kernels import Bodies, Filters, Hits

# COCO-23 nose, eyes, ears, shoulders, hips: they move with the body; arms and legs swing by tens of cm a frame
CORE_JOINTS = np.array([0, 1, 2, 3, 4, 5, 6, 11, 12])
# m^2: variance of a joint no view sees, placed by the bone prior alone (a bone's direction is unknown: about 15 cm)
UNSEEN_VAR_M2 = 0.15**2
SKELETON_REFRESH = 5  # hits between two updates of a track's robust skeleton (it changes slowly)
COMPILED_PAIRS = 65536  # up to this many, mean_distances tests every pair in one compiled pass (no pair lists)
BODY_SPAN_M = 1.0  # m: the centres of any two subsets of one body's head and trunk joints lie this close


class Tracked(NamedTuple):
    """One frame's output of the tracker: ids (P,), poses (P, J, 4), and smoothed (P,) bool."""

    ids: np.ndarray
    poses3d: np.ndarray
    smoothed: np.ndarray  # the persons the motion model weighed in (a hit track, smoothing on, variances given)


class Association(NamedTuple):
    """A frame's pairing by :meth:`Tracker.associate`: frame, P poses paired, track ids (K,), their persons (K,)."""

    frame: int
    count: int
    tracks: np.ndarray
    persons: np.ndarray


class TrackState(NamedTuple):
    """All T tracks as arrays (T, ...); J joints, L bones, W the bone window."""

    ids: np.ndarray
    position: np.ndarray  # (T, J, 3)
    velocity: np.ndarray  # (T, J, 3)
    p00: np.ndarray  # (T, J): p00, p01, p11 the per-axis covariance of (position, velocity)
    p01: np.ndarray
    p11: np.ndarray
    seen: np.ndarray  # (T, J)
    last_frame: np.ndarray
    hits: np.ndarray
    confirmed: np.ndarray
    bones: np.ndarray  # (T, W, L) a ring of bone lengths (NaN: none)
    slot: np.ndarray  # its next slot
    sx: np.ndarray  # (T, J, 3) the smoothed joints
    sp: np.ndarray  # (T, J) m^2 their variance
    sq: np.ndarray  # (T, J) m^2 their process variance
    live: np.ndarray  # (T, J) measured at the last hit
    skel_median: np.ndarray  # (T, L): the robust skeleton
    skel_se: np.ndarray
    skel_count: np.ndarray

    def select(self, keep: np.ndarray, then: TrackState | None, pool: np.ndarray) -> TrackState:
        """The tracks of a mask (T,), then then's; the bone windows stay in pool (C, W, L), first rows self.bones."""
        if keep.all() and then is None:
            return self
        rows, added = np.flatnonzero(keep), 0 if then is None else len(then.ids)
        fields = {}
        for name, old in zip(self._fields, self):
            if name == "bones":
                shifted = np.flatnonzero(rows != np.arange(len(rows)))  # rows before the first drop stay
                moved = int(shifted[0]) if len(shifted) else len(rows)
                pool[moved : len(rows)] = old[rows[moved:]]  # (a fancy index reads all before the rows are written)
                if added:
                    pool[len(rows) : len(rows) + added] = then.bones
                fields[name] = pool[: len(rows) + added]
                continue
            out = np.empty((len(rows) + added, *old.shape[1:]), dtype=old.dtype)
            np.take(old, rows, axis=0, out=out[: len(rows)], mode="clip")  # rows are valid; "raise" buffers
            if added:
                out[len(rows) :] = getattr(then, name)
            fields[name] = out
        return TrackState(**fields)


def _core_mask(joints: int) -> np.ndarray:
    """The head and trunk joints among J: (J,) bool."""
    core = np.zeros(joints, dtype=bool)
    core[CORE_JOINTS[CORE_JOINTS < joints]] = True
    return core


def mean_distances(guess: np.ndarray, seen: np.ndarray, poses3d: np.ndarray, max_m: float = np.inf) -> np.ndarray:
    """Mean head-and-trunk distance: guesses (T, J, 3), seen (T, J), poses (P, J, 4) -> (T, P) m, inf if far."""
    guess, seen = np.ascontiguousarray(guess, dtype=np.float64), np.ascontiguousarray(seen, dtype=bool)
    poses3d, J = np.ascontiguousarray(poses3d, dtype=np.float64), poses3d.shape[1]
    bodies = Bodies(guess=guess, seen=seen, poses3d=poses3d, valid=poses3d[..., 3] > 0, core=_core_mask(J))
    ca, cb = kernels.centres(guess, seen, bodies.core), kernels.centres(poses3d, bodies.valid, bodies.core)
    out, radius = np.full((len(guess), len(poses3d)), np.inf), max_m + BODY_SPAN_M
    if len(ca) * len(cb) <= COMPILED_PAIRS:
        kernels.near_mean_distances(bodies, ca, cb, float(radius), out)
        return out
    rows, cols = near_pairs(ca, cb, radius)
    kernels.pair_mean_distances(bodies, rows.astype(np.int64), cols.astype(np.int64), out)
    return out


def near_pairs(a: np.ndarray, b: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs of finite points a (T, 3) and b (P, 3) at most radius apart (KD-trees) -> rows (K,), cols (K,)."""
    ia, ib = np.flatnonzero(np.isfinite(a).all(axis=1)), np.flatnonzero(np.isfinite(b).all(axis=1))
    pairs = cKDTree(a[ia]).sparse_distance_matrix(cKDTree(b[ib]), radius, output_type="ndarray")
    return ia[pairs["i"]], ib[pairs["j"]]


def predicted_positions(position: np.ndarray, velocity: np.ndarray, live: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """Tracks moved by dt (T,) times their body velocity: position, velocity (T, J, 3), live (T, J) -> (T, J, 3)."""
    body = kernels.centres(velocity, live, _core_mask(live.shape[1]))
    return position + dt[:, None, None] * body[:, None, :]


@lru_cache(maxsize=1)
def warm_up() -> None:
    """Compile the tracker's kernels (or load them from numba's cache) once per process."""
    tracker, pose = Tracker(min_hits=1), np.ones((1, 23, 4))
    for frame in (0, 1):
        tracker.update(tracker.associate(frame, pose), Reconstruction(pose, np.ones(pose.shape[:2])))
    mean_distances(np.ones((257, 23, 3)), np.ones((257, 23), dtype=bool), np.ones((256, 23, 4)), 0.1)


@dataclass(eq=False)
class Tracker:
    """Frame-by-frame tracker of 3D poses; the parameters are those of configs/tracking/on.yaml."""

    max_distance_m: float = 0.5  # m: gate of the mean joint distance between a track's prediction and a person
    gate_growth_m: float = 0.1  # m per frame since the track was last seen
    min_hits: int = 3  # hits in a row that confirm a track
    max_age: int = 10  # frames without a hit after which a confirmed track dies
    accel_sd_m: float = 0.05  # m / frame^2: the motion filter's white acceleration
    measurement_sd_m: float = 0.03  # m: a joint's SD where the reconstruction gives no variance
    velocity_sd_m: float = 0.5  # m / frame: a new track's velocity SD
    bone_window: int = 100  # frames of bone lengths kept per track
    smooth: bool = True  # each joint also filtered over time (false: ids only)
    smooth_rate: float = 0.3  # rate of the smoother's process variance
    smooth_floor_m: float = 0.001  # m per frame: least process SD
    smooth_initial_m: float = 0.01  # m per frame: a new joint's process SD
    skeleton_min_frames: int = 5  # frames a bone is seen before the track offers it to the MAP (0: never)

    def __post_init__(self) -> None:
        sizes = (self.max_distance_m, self.accel_sd_m, self.measurement_sd_m, self.velocity_sd_m)
        sizes += (self.smooth_floor_m, self.smooth_initial_m)
        counts = int(self.min_hits) >= 1 and int(self.max_age) >= 0 and int(self.bone_window) >= 1
        if not (min(sizes) > 0 and self.gate_growth_m >= 0 and counts and 0 < self.smooth_rate <= 1):
            raise ValueError(
                "tracking: need max_distance_m, accel_sd_m, measurement_sd_m, velocity_sd_m, smooth_floor_m, "
                "smooth_initial_m > 0, gate_growth_m >= 0, min_hits >= 1, max_age >= 0, bone_window >= 1, "
                f"0 < smooth_rate <= 1; got {self}"
            )
        self.min_hits, self.max_age, self.bone_window = int(self.min_hits), int(self.max_age), int(self.bone_window)
        self.skeleton_min_frames, self.smooth = int(self.skeleton_min_frames), bool(self.smooth)
        self.r2, self.v2 = float(self.measurement_sd_m) ** 2, float(self.velocity_sd_m) ** 2
        self.filters = Filters(
            unseen_var=UNSEEN_VAR_M2,
            q=float(self.accel_sd_m) ** 2,
            r2=self.r2,
            rate=float(self.smooth_rate),
            floor2=float(self.smooth_floor_m) ** 2,
            q0=float(self.smooth_initial_m) ** 2,
            min_hits=self.min_hits,
            refresh=SKELETON_REFRESH,
        )
        self.state: TrackState | None = None
        self._pool: np.ndarray | None = None  # the tracks' bone windows and room for more (_bone_pool)
        self.last_frame: int | None = None
        self._next_id = 0

    def associate(self, frame: int, poses3d: np.ndarray) -> Association:
        """Pair a coming frame's persons (P, J, 4) with the tracks alive since the last frame, changing nothing."""
        frame, poses3d = self._checked(frame, poses3d)
        none, st = np.zeros(0, dtype=np.int64), self.state
        if st is None:
            return Association(frame, len(poses3d), none, none)
        rows = np.flatnonzero(self._alive(st, frame - 1))
        if not len(rows) or not len(poses3d):
            return Association(frame, len(poses3d), none, none)
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
        return Association(frame, len(poses3d), st.ids[rows[pick[keep]]], cols[keep].astype(np.int64))

    def skeleton_prior(self, association: Association) -> SkeletonPrior:
        """Robust bone lengths (P, L) m and standard errors (P, L) of each person's confirmed track (else NaN / inf)."""
        median = np.full((association.count, len(BONE_PAIRS)), np.nan)
        se = np.full(median.shape, np.inf)
        if not self.skeleton_min_frames or not len(association.tracks):
            return SkeletonPrior(median, se)
        st, tracks = self.state, self._indices(association)
        keep = st.confirmed[tracks]
        tracks, persons = tracks[keep], association.persons[keep]
        ok = st.skel_count[tracks] >= self.skeleton_min_frames
        median[persons] = np.where(ok, st.skel_median[tracks], np.nan)
        se[persons] = np.where(ok, st.skel_se[tracks], np.inf)
        return SkeletonPrior(median, se)

    def update(self, association: Association, reconstruction: Reconstruction) -> Tracked:
        """Correct the tracks with a Reconstruction's associated persons, start the others, drop the dead -> Tracked."""
        frame, poses3d = self._checked(association.frame, reconstruction.poses)
        if association.count != len(poses3d):
            raise ValueError(f"tracking: the association is of {association.count} poses, the update of {len(poses3d)}")
        variance = self._variance(reconstruction.joint_variance, poses3d)
        bones = self._bones(reconstruction.bone_lengths, poses3d, variance)
        if self.state is None:  # no track yet
            self.state = self._births(np.zeros(0, dtype=np.int64), frame, poses3d[:0], variance[:0], bones[:0])
        st, tracks, persons = self.state, self._indices(association), association.persons
        alive, self.last_frame = self._alive(st, frame - 1), frame
        ids, out = np.full(len(poses3d), -1, dtype=np.int64), poses3d.copy()
        smoothed = np.zeros(len(poses3d), dtype=bool)
        if len(tracks):  # the hit tracks corrected in place, then one select keeps the survivors
            hits = Hits(
                frame=frame,
                tracks=tracks,
                persons=association.persons,
                poses3d=poses3d,
                variance=variance,
                lengths=np.ascontiguousarray(bones),
                out=out,
                smooth=self.smooth and reconstruction.joint_variance is not None,  # without variances: ids only
            )
            kernels.correct_tracks(st, hits, self.filters)
            ids[persons], smoothed[persons] = st.ids[tracks], hits.smooth
        hit = np.zeros(len(st.ids), dtype=bool)
        hit[tracks] = True
        born, births = np.flatnonzero(ids < 0), None
        if len(born):
            ids[born] = np.arange(self._next_id, self._next_id + len(born))
            self._next_id += len(born)
            births = self._births(ids[born], frame, poses3d[born], variance[born], bones[born])
        keep = alive & (hit | self._alive(st, frame))
        self.state = st.select(keep, births, self._bone_pool(st, int(keep.sum()) + len(born)))
        return Tracked(ids, out, smoothed)

    def _checked(self, frame: int, poses3d: np.ndarray) -> tuple[int, np.ndarray]:
        """A coming frame's number and poses (P, J, 4) as float64, or a ValueError."""
        frame, poses3d = int(frame), np.ascontiguousarray(poses3d, dtype=np.float64)
        if self.last_frame is not None and frame <= self.last_frame:
            raise ValueError(
                f"tracking: frame {frame} comes after frame {self.last_frame}; frame numbers must "
                "increase (sort the sequence, remove repeated frames)"
            )
        if poses3d.ndim != 3 or poses3d.shape[-1] != 4:
            raise ValueError(f"tracking: poses must be (P, J, 4), got {poses3d.shape}")
        return frame, poses3d

    def _indices(self, association: Association) -> np.ndarray:
        """The rows (K,) of the associated tracks in the state (ids ascending), or a ValueError for a stale one."""
        ids = self.state.ids if self.state is not None else np.zeros(0, dtype=np.int64)
        rows = np.minimum(np.searchsorted(ids, association.tracks), max(len(ids) - 1, 0))
        if len(association.tracks) and not np.array_equal(ids[rows], association.tracks):
            raise ValueError("tracking: the association is not of the tracks now held (associate, then update)")
        return rows.astype(np.int64)

    @staticmethod
    def _bones(lengths: np.ndarray | None, poses3d: np.ndarray, variance: np.ndarray) -> np.ndarray:
        """Bone lengths (P, L) each person adds to its track: the given ones, else those of its measured joints."""
        if lengths is not None:
            lengths = np.asarray(lengths, dtype=np.float64)
            if lengths.shape != (len(poses3d), len(BONE_PAIRS)):
                raise ValueError(f"tracking: bone lengths {lengths.shape} do not match {len(poses3d)} poses")
            return lengths
        ok = (poses3d[..., 3] > 0) & (variance < UNSEEN_VAR_M2)
        return np.where(ok[:, BONE_PAIRS[:, 0]] & ok[:, BONE_PAIRS[:, 1]], bone_lengths(poses3d), np.nan)

    def _variance(self, variance: np.ndarray | None, poses3d: np.ndarray) -> np.ndarray:
        """Measurement variances (P, J) m^2: the given ones, at most UNSEEN_VAR_M2; without any, measurement_sd_m^2."""
        if variance is None:
            return np.full(poses3d.shape[:2], self.r2)
        variance = np.asarray(variance, dtype=np.float64)
        if variance.shape != poses3d.shape[:2]:
            raise ValueError(f"tracking: variances {variance.shape} do not match poses {poses3d.shape}")
        return np.where(np.isfinite(variance) & (variance > 0), np.minimum(variance, UNSEEN_VAR_M2), UNSEEN_VAR_M2)

    def _bone_pool(self, st: TrackState, tracks: int) -> np.ndarray:
        """The buffer (C, W, L), C >= tracks, whose first rows are st's bone windows (doubled when short)."""
        pool = self._pool
        inside = pool is not None and st.bones.base is pool and st.bones.ctypes.data == pool.ctypes.data
        if not inside or len(pool) < tracks:
            pool = np.empty((max(2 * tracks, 16), *st.bones.shape[1:]))
            pool[: len(st.ids)] = st.bones
            self._pool = pool
        return pool

    def _alive(self, st: TrackState, frame: int) -> np.ndarray:
        """(T,) bool: alive at frame without a new hit (tentative tracks die at once, confirmed ones after max_age)."""
        return frame - st.last_frame <= np.where(st.confirmed, self.max_age, 0)

    def _births(
        self, ids: np.ndarray, frame: int, poses3d: np.ndarray, variance: np.ndarray, lengths: np.ndarray
    ) -> TrackState:
        """Tentative tracks at persons' joints: ids (B,), poses (B, J, 4), joint variances (B, J), bones (B, L)."""
        (B, J), L = poses3d.shape[:2], len(BONE_PAIRS)
        seen = poses3d[..., 3] > 0
        bones = np.full((B, self.bone_window, L), np.nan)
        bones[:, 0] = lengths
        return TrackState(
            ids=ids.astype(np.int64),
            position=np.where(seen[..., None], poses3d[..., :3], 0.0),
            velocity=np.zeros((B, J, 3)),
            p00=np.full((B, J), self.r2),
            p01=np.zeros((B, J)),
            p11=np.full((B, J), self.v2),
            seen=seen,
            last_frame=np.full(B, frame, dtype=np.int64),
            hits=np.ones(B, dtype=np.int64),
            confirmed=np.full(B, self.min_hits <= 1),
            bones=bones,
            slot=np.ones(B, dtype=np.int64) % self.bone_window,
            sx=np.where(seen[..., None], poses3d[..., :3], 0.0),
            sp=np.where(seen, variance, 0.0),
            sq=np.full((B, J), self.filters.q0),
            live=seen & (variance < UNSEEN_VAR_M2),
            skel_median=np.full((B, L), np.nan),
            skel_se=np.full((B, L), np.inf),
            skel_count=np.zeros((B, L), dtype=np.int64),
        )
