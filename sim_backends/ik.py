"""Inverse kinematics that really reaches the target, on a private PyBullet model of the arm.

PyBullet's ``calculateInverseKinematics`` stops centimetres short of many targets. Here it
only supplies a starting guess; a damped least-squares (Levenberg-Marquardt) refinement with
PyBullet's Jacobian then drives the error to ~1e-7 m, and the answer is accepted only after
forward kinematics confirms the reached pose within ``POSITION_TOL_M`` and
``ROTATION_TOL_DEG``. When the seed fails, seeded random restarts try again; when every try
fails, :class:`robots.interfaces.UnreachableError` says by how much it missed and what to do.

The model is the *controller's* kinematic model: nominal URDF, base frame at the identity,
joint angles as the controller reports them. It lives in its own DIRECT client so that
solving never moves the arm that cameras see in the world.
"""

from __future__ import annotations

import itertools
import weakref
from pathlib import Path

import numpy as np
import pybullet as p

from robots.geometry import (
    as_pose,
    pose_from_quat_xyzw,
    quat_xyzw_from_rotation,
    rotation_angle_deg,
    rotvec_from_rotation,
)
from robots.interfaces import UnreachableError

__all__ = ["POSITION_TOL_M", "ROTATION_TOL_DEG", "KinematicModel", "pose_error"]

POSITION_TOL_M = 1e-4  # 0.1 mm: every IK answer is verified to this
ROTATION_TOL_DEG = 0.05


def pose_error(reached: np.ndarray, target: np.ndarray) -> tuple[float, float]:
    """Position miss (m) and rotation miss (deg) between two (4, 4) poses."""
    dp = float(np.linalg.norm(target[:3, 3] - reached[:3, 3]))
    dr = rotation_angle_deg(target[:3, :3] @ reached[:3, :3].T)
    return dp, dr


def _error_vector(reached: np.ndarray, target: np.ndarray) -> np.ndarray:
    # Position error and rotation error as a base-frame rotation vector, the quantities the
    # (base-frame) geometric Jacobian maps joint steps to.
    rot = rotvec_from_rotation(target[:3, :3] @ reached[:3, :3].T)
    return np.concatenate([target[:3, 3] - reached[:3, 3], rot])


class KinematicModel:
    """Forward kinematics, Jacobian and verified IK for one arm (base frame = identity).

    ``urdf_path``: the arm's URDF; ``joint_names``: the controlled joints in controller order;
    ``flange_link``: name of the tool0 link; ``limits``: (n, 2) rad used by the solver;
    ``rest_pose``: (n,) rad, a comfortable configuration tried early; ``reach``: metres from
    the first joint axis, used only for the "too far" hint; ``other_joints``: fixed values
    for any other movable joints in the URDF (the Panda's fingers).
    """

    def __init__(self, urdf_path, joint_names, flange_link: str, limits, rest_pose,
                 reach: float, other_joints: dict[str, float] | None = None, name: str = "arm"):
        self.name = name
        self.client = p.connect(p.DIRECT)
        # Disconnect the private client even if close() is never called.
        self._finalizer = weakref.finalize(self, _disconnect, self.client)
        self.body = p.loadURDF(str(Path(urdf_path)), useFixedBase=True, physicsClientId=self.client)
        index = {}
        movable = []
        for j in range(p.getNumJoints(self.body, physicsClientId=self.client)):
            info = p.getJointInfo(self.body, j, physicsClientId=self.client)
            index[info[1].decode()] = j
            index["link:" + info[12].decode()] = j
            if info[2] != p.JOINT_FIXED:
                movable.append(j)
        missing = [n for n in joint_names if n not in index]
        if missing or "link:" + flange_link not in index:
            raise ValueError(f"{urdf_path} lacks joints {missing} or link {flange_link!r}")
        self.joints = [index[n] for n in joint_names]
        self.n = len(self.joints)
        self.flange = index["link:" + flange_link]
        self._movable = movable
        # Columns of PyBullet's all-DOF vectors that belong to the controlled joints.
        self._cols = [movable.index(j) for j in self.joints]
        self._full_q = np.zeros(len(movable))
        for jname, value in (other_joints or {}).items():
            p.resetJointState(self.body, index[jname], value, physicsClientId=self.client)
            self._full_q[movable.index(index[jname])] = value
        self.limits = np.asarray(limits, dtype=float)
        self.rest_pose = np.asarray(rest_pose, dtype=float)
        self.reach = float(reach)
        # calculateJacobian wants the point in the link's centre-of-mass frame; we want the
        # Jacobian of the link frame origin (the flange centre).
        state = p.getLinkState(self.body, self.flange, physicsClientId=self.client)
        link_T_com = pose_from_quat_xyzw(state[3], state[2])
        self._flange_in_com = list(np.linalg.inv(link_T_com)[:3, 3])
        self._full_lo = np.full(len(movable), -np.pi)
        self._full_hi = np.full(len(movable), np.pi)
        self._full_lo[self._cols], self._full_hi[self._cols] = self.limits[:, 0], self.limits[:, 1]
        for col, j in enumerate(movable):
            if j not in self.joints:
                self._full_lo[col] = self._full_hi[col] = self._full_q[col]
        # A hard bound for the early "too far" error: the joint-2 origin lies on the joint-1
        # axis for every arm here, so it does not move, and the flange can be no further from
        # it than the sum of the (fixed) distances between the following joint origins.
        self._set(np.zeros(self.n))
        origins = [np.asarray(p.getLinkState(self.body, j, computeForwardKinematics=True,
                                             physicsClientId=self.client)[4])
                   for j in self.joints[1:] + [self.flange]]
        self._shoulder = origins[0]
        self._max_distance = float(sum(np.linalg.norm(b - a) for a, b in itertools.pairwise(origins)))

    # --------------------------------------------------------------------- kinematics

    def _set(self, q: np.ndarray) -> None:
        for j, qi in zip(self.joints, q):
            p.resetJointState(self.body, j, float(qi), physicsClientId=self.client)

    def fk(self, q) -> np.ndarray:
        """``base_T_flange`` (4, 4) for joint angles ``q`` (n,) rad."""
        self._set(q)
        s = p.getLinkState(self.body, self.flange, computeForwardKinematics=True,
                           physicsClientId=self.client)
        return pose_from_quat_xyzw(s[5], s[4])

    def jacobian(self, q) -> np.ndarray:
        """(6, n) geometric Jacobian of the flange origin in the base frame: rows vx vy vz wx wy wz."""
        full = self._full_q.copy()
        full[self._cols] = q
        zeros = [0.0] * len(full)
        lin, ang = p.calculateJacobian(self.body, self.flange, self._flange_in_com, list(full),
                                       zeros, zeros, physicsClientId=self.client)
        return np.vstack([np.asarray(lin)[:, self._cols], np.asarray(ang)[:, self._cols]])

    # --------------------------------------------------------------------- IK

    def refine(self, target: np.ndarray, q0, max_iters: int = 60,
               limited: bool = True) -> tuple[np.ndarray, float, float]:
        """Damped least squares (Levenberg-Marquardt) from ``q0``; returns (q, miss m, miss deg).

        ``limited``: keep every iterate inside the joint limits (clip). Unlimited iterations
        converge far more often, and since a revolute joint at q and q +- 2 pi is the same
        pose, their answer can often be wrapped into the limits afterwards (see ``solve``).
        """
        lo, hi = (self.limits[:, 0], self.limits[:, 1]) if limited else (-np.inf, np.inf)
        q = np.clip(np.asarray(q0, dtype=float), lo, hi)
        lam = 1e-2
        err = _error_vector(self.fk(q), target)
        cost = err @ err
        for _ in range(max_iters):
            if np.linalg.norm(err[:3]) < 1e-7 and np.linalg.norm(err[3:]) < 1e-7:
                break
            J = self.jacobian(q)
            step = J.T @ np.linalg.solve(J @ J.T + lam**2 * np.eye(6), err)
            # Big steps leave the region where the linearisation holds; cap them.
            norm = np.linalg.norm(step)
            if norm > 0.4:
                step *= 0.4 / norm
            q_new = np.clip(q + step, lo, hi)
            err_new = _error_vector(self.fk(q_new), target)
            cost_new = err_new @ err_new
            if cost_new < cost:  # accept, trust the linear model more
                q, err, cost = q_new, err_new, cost_new
                lam = max(lam * 0.3, 1e-6)
            else:  # reject, damp harder
                lam = min(lam * 5.0, 1.0)
                if lam >= 1.0 and norm < 1e-9:
                    break
        dp, dr = pose_error(self.fk(q), target)
        return q, dp, dr

    def wrap_into_limits(self, q, near=None) -> np.ndarray:
        """``q`` with each joint shifted by a multiple of 2 pi into its limits where possible.

        Of several in-limit choices (UR joints span +-2 pi) the one nearest ``near`` wins.
        Joints that cannot be wrapped in are left as they are (the caller checks).
        """
        q = np.array(q, dtype=float)
        near = q if near is None else np.asarray(near, dtype=float)
        for j, (lo, hi) in enumerate(self.limits):
            candidates = q[j] + 2 * np.pi * np.arange(-3, 4)
            ok = candidates[(candidates >= lo - 1e-12) & (candidates <= hi + 1e-12)]
            if ok.size:
                q[j] = ok[np.argmin(np.abs(ok - near[j]))]
        return q

    def within_limits(self, q) -> bool:
        return bool(np.all((q >= self.limits[:, 0] - 1e-12) & (q <= self.limits[:, 1] + 1e-12)))

    def _pybullet_guess(self, target: np.ndarray, seed: np.ndarray) -> np.ndarray:
        full = self._full_q.copy()
        full[self._cols] = seed
        quat = quat_xyzw_from_rotation(target[:3, :3])
        sol = p.calculateInverseKinematics(
            self.body, self.flange, list(target[:3, 3]), list(quat),
            lowerLimits=list(self._full_lo), upperLimits=list(self._full_hi),
            jointRanges=list(np.maximum(self._full_hi - self._full_lo, 1e-3)),
            restPoses=list(full), currentPositions=list(full),
            maxNumIterations=200, residualThreshold=1e-6, physicsClientId=self.client)
        return np.asarray(sol)[self._cols]

    def random_configuration(self, rng: np.random.Generator) -> np.ndarray:
        """A uniformly random configuration inside the solver's joint limits."""
        return rng.uniform(self.limits[:, 0], self.limits[:, 1])

    def solve(self, base_T_flange, q_seed=None, max_restarts: int = 24, seed: int = 0) -> np.ndarray:
        """Joint angles (n,) rad that put the flange at ``base_T_flange``, verified by FK.

        Tries, in order: refinement straight from ``q_seed`` (keeps the configuration when the
        target is close), PyBullet's IK from ``q_seed`` then refinement, the rest pose, then
        ``max_restarts`` random in-limit starts drawn from ``np.random.default_rng(seed)``
        (so the answer depends only on the inputs). Raises UnreachableError with the smallest
        miss in mm and degrees when none reaches ``POSITION_TOL_M`` / ``ROTATION_TOL_DEG``.
        """
        target = as_pose(base_T_flange, "base_T_flange target")
        seed_q = self.rest_pose if q_seed is None else np.asarray(q_seed, dtype=float)
        if seed_q.shape != (self.n,) or not np.all(np.isfinite(seed_q)):
            raise ValueError(f"q_seed must be {self.n} finite joint angles (rad), got {q_seed!r}")
        distance = float(np.linalg.norm(target[:3, 3] - self._shoulder))
        if distance > self._max_distance:
            raise UnreachableError(
                f"{self.name}: the target flange position is {distance:.3f} m from the shoulder "
                f"(joint 2), but no configuration puts the flange further than "
                f"{self._max_distance:.3f} m from it (published reach {self.reach:.3f} m); "
                "move the target closer to the base")
        rng = np.random.default_rng(seed)
        # Each start: (configuration, pass it through PyBullet's IK first?).
        starts = [(seed_q, False), (seed_q, True), (self.rest_pose, True)]
        starts += [(self.random_configuration(rng), k % 2 == 0) for k in range(max_restarts)]
        best = (None, np.inf, np.inf)

        def score(dp, dr):  # misses in units of the tolerances
            return dp / POSITION_TOL_M + dr / ROTATION_TOL_DEG

        for k, (start, use_pybullet) in enumerate(starts):
            q0 = self._pybullet_guess(target, start) if use_pybullet else start
            if k > 0:
                # Converge freely, then wrap the angles into the limits; the limited polish
                # below then only has to fix what wrapping cannot (the Panda's odd limits).
                # From the seed itself (k == 0) stay on its branch instead.
                q0 = self.wrap_into_limits(self.refine(target, q0, limited=False)[0], near=seed_q)
            q, dp, dr = self.refine(target, q0, limited=True)
            if dp <= POSITION_TOL_M and dr <= ROTATION_TOL_DEG and self.within_limits(q):
                return self._verified(q, target)
            if score(dp, dr) < score(best[1], best[2]):
                best = (q, dp, dr)
        _, dp, dr = best
        raise UnreachableError(
            f"{self.name}: no joint configuration within the joint limits reaches the target; "
            f"the best try missed by {dp * 1e3:.2f} mm and {dr:.3f} deg (tolerance "
            f"{POSITION_TOL_M * 1e3:.1f} mm, {ROTATION_TOL_DEG} deg). The position may be at the "
            "edge of the workspace or the orientation beyond the wrist's limits: move the target "
            "closer to the base, or turn it (e.g. tool z pointing down)")

    def _verified(self, q: np.ndarray, target: np.ndarray) -> np.ndarray:
        # Accepted answers can sit anywhere inside the tolerance; polish them (cheap, already
        # close) so IK errors do not eat into the error budgets of the labs, then check again.
        q_polished, dp, dr = self.refine(target, q, limited=True)
        if dp <= POSITION_TOL_M and dr <= ROTATION_TOL_DEG and self.within_limits(q_polished):
            q = q_polished
        dp, dr = pose_error(self.fk(q), target)
        if dp > POSITION_TOL_M or dr > ROTATION_TOL_DEG:  # pragma: no cover - refine() checked
            raise UnreachableError(f"{self.name}: IK verification failed ({dp * 1e3:.3f} mm, {dr:.3f} deg)")
        return q.copy()

    def close(self) -> None:
        """Disconnect the private PyBullet client. Idempotent."""
        self._finalizer()


def _disconnect(client: int) -> None:
    try:
        p.disconnect(physicsClientId=client)
    except p.error:  # already gone
        pass
