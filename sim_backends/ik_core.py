"""Inverse kinematics that really reaches the target, on any engine's forward kinematics.

A damped least-squares (Levenberg-Marquardt) refinement with the flange's geometric Jacobian
drives the error to ~1e-7 m, and an answer is accepted only after forward kinematics confirms
the reached pose within ``POSITION_TOL_M`` and ``ROTATION_TOL_DEG``. When the seed fails, a
guess from the engine's own IK (if it has one) and seeded random restarts try again; when
every try fails, :class:`robots.interfaces.UnreachableError` says by how much it missed and
what to do.

:class:`KinematicSolver` is the algorithm; an engine's model (``sim_backends.ik``'s PyBullet
``KinematicModel``, ``sim_backends.mujoco_arm``'s ``MujocoKinematics``) supplies ``fk``,
``jacobian`` and optionally ``_guess``, and sets the attributes listed on the class.
"""

from __future__ import annotations

import numpy as np

from robots.geometry import as_pose, rotation_angle_deg, rotvec_from_rotation
from robots.interfaces import UnreachableError

__all__ = ["POSITION_TOL_M", "ROTATION_TOL_DEG", "KinematicSolver", "pose_error"]

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


class KinematicSolver:
    """Verified IK over an engine's kinematics (base frame = identity).

    A subclass sets ``name``, ``n`` (number of controlled joints), ``limits`` ((n, 2) rad),
    ``rest_pose`` ((n,) rad), ``reach`` (m, for the "too far" hint), ``_shoulder`` (the
    joint-2 origin, (3,) m) and ``_max_distance`` (m, the furthest the flange can be from it),
    and implements ``fk(q) -> base_T_flange`` and ``jacobian(q) -> (6, n)`` (rows vx vy vz wx
    wy wz, base frame, at the flange origin).
    """

    def fk(self, q) -> np.ndarray:
        raise NotImplementedError

    def jacobian(self, q) -> np.ndarray:
        raise NotImplementedError

    def _guess(self, target: np.ndarray, seed: np.ndarray) -> np.ndarray:
        """A starting configuration for ``target`` from the engine's own IK (default: ``seed``)."""
        return seed

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

    def random_configuration(self, rng: np.random.Generator) -> np.ndarray:
        """A uniformly random configuration inside the solver's joint limits."""
        return rng.uniform(self.limits[:, 0], self.limits[:, 1])

    def solve(self, base_T_flange, q_seed=None, max_restarts: int = 24, seed: int = 0) -> np.ndarray:
        """Joint angles (n,) rad that put the flange at ``base_T_flange``, verified by FK.

        Tries, in order: refinement straight from ``q_seed`` (keeps the configuration when the
        target is close), the engine's own IK guess (``_guess``) from ``q_seed`` then refinement, the rest pose, then
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
            q0 = self._guess(target, start) if use_pybullet else start
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
