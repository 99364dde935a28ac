"""Where the lidar-only robot is: odometry prediction corrected by scan matching.

With ``config.localise`` the pose is predicted from the previous estimate and
the measured body velocities (``Observation.velocity``, wheel odometry / gyro: a
unicycle step over the elapsed time at the velocity measured now), and each scan is matched against the
map's returns so far around that prediction (:meth:`~sanav_mj.mapping.sensed_map.SensedMap.match`). A match (trusted,
or ambiguous: then the unconstrained directions stay at the prediction) gives the
estimate; a failed one keeps the prediction (and, with ``skip_unmatched``, the scan is
not added to the map). The episode starts at the pose given to
the pose given at construction (the start pose, as the known-map mode plans from it). The measured pose
(``Observation.pose``, with the ``--mismatch`` noise) enters each match as an absolute
prior (:meth:`~sanav_mj.mapping.sensed_map.SensedMap.match` ``anchor``) whose standard deviation is learnt online
from the measured displacement between steps minus the odometry's (variance
``2 var(noise) + var(odometry error)``; a running mean with ``meas_sigma0`` as two
samples, then an exponential average of weight ``meas_forget``; floored at
``meas_floor``; the controller is not told the noise): an exact measurement pins the
estimate (and so the map) to the world, a noisy one only slowly pulls the map frame
back from drift; without a match the prediction and the
measurement are blended by their variances (``odometry_sigma`` against the learnt one).
When the match is ``ok`` (or ambiguous while the learnt noise is below
``precise_meas``) and the measured pose explains the scan as well (the scan's cost at it
exceeds the match's by at most ``consistent_chi2``), the measured pose is kept as the
estimate (status ``"measured"``): with an exact measurement the map is built as without
localisation.

Used by :class:`sanav_mj.control.sensing.SensingSAMPC` (its ``config`` is a
:class:`~sanav_mj.control.sensing_config.SensingConfig`: ``localise``, ``skip_unmatched``,
``meas_sigma0``, ``meas_floor``, ``meas_forget``, ``consistent_chi2``, ``precise_meas``,
``odometry_sigma``).
"""

from __future__ import annotations

import math

import numpy as np


class ScanLocaliser:
    """The pose estimate of one episode (see the module docstring).

    Args:
        config: the sensing loop's settings (a ``SensingConfig``).
        pose: (3,) [m, m, rad] the start pose of the episode.

    Attributes:
        estimate: (3,) [m, m, rad] the current pose estimate.
        match_log: per step, the scan match status (``"ok"``, ``"ambiguous"``, ``"poor"``,
            ``"few_points"``, ``"empty"``, ``"measured"`` (the measured pose was consistent
            with the scan and kept); ``"none"`` without a scan or without localising)
            and the estimate (3,) after it.
    """

    def __init__(self, config, pose) -> None:
        self.config = config
        self.estimate = np.asarray(pose, dtype=float).reshape(3).copy()
        self._odo: tuple[float, np.ndarray] | None = None  # (t, velocity) of the last step
        self._add_scan = True
        self._meas_var = np.square(np.asarray(config.meas_sigma0, dtype=float))  # [m^2, rad^2]
        self._last_meas: np.ndarray | None = None  # the measured pose of the last step
        self._meas_n = 0  # samples of the measurement noise so far
        self.match_log: list[tuple[str, np.ndarray]] = []

    def localise(self, obs, smap) -> tuple[np.ndarray, bool]:
        """The pose of this step and whether its scan is to be added to the map.

        Args:
            obs: the step's :class:`~sanav_mj.control.base.Observation` (``pose`` (3,)
                [m, m, rad] measured, ``velocity`` (2,) [m/s, rad/s], ``t`` [s], ``scan``).
            smap: the :class:`~sanav_mj.mapping.sensed_map.SensedMap` the scan is matched
                against (read only).

        Returns:
            (3,) [m, m, rad] the measured pose (without ``localise``) or the estimate; and
            False when the scan's match failed and ``skip_unmatched`` holds (else True).
        """
        self._add_scan = True
        if not self.config.localise:
            self.match_log.append(("none", np.asarray(obs.pose, dtype=float).reshape(3).copy()))
            return np.asarray(obs.pose, dtype=float).reshape(3), True
        est = self.estimate.copy()
        odo = None  # odometry displacement since the last step (3,) [m, m, rad]
        vel = np.asarray(obs.velocity, dtype=float).reshape(-1) if obs.velocity is not None else None
        if vel is not None and vel.shape == (2,) and np.all(np.isfinite(vel)):
            if self._odo is not None:
                # the wheel servos reach a new set-point within a few ms: the velocity measured
                # at the end of the interval is its average far better than the trapezoid
                # (complex, seed 0: 0.007 vs 0.011 rad rms yaw error per 0.1 s step)
                dt = float(obs.t) - self._odo[0]
                v, w = vel
                th_mid = est[2] + 0.5 * w * dt
                odo = np.array([v * dt * math.cos(th_mid), v * dt * math.sin(th_mid), w * dt])
                est = est + odo
            self._odo = (float(obs.t), vel)
        meas = np.asarray(obs.pose, dtype=float).reshape(3)
        have_meas = bool(np.all(np.isfinite(meas)))
        sig = np.sqrt(self._meas_var)
        status = "none"
        matched = False
        if obs.scan is not None:
            res = smap.match(est, obs.scan.ranges, obs.scan.hit, obs.scan.angles,
                                 meas if have_meas else None, (float(sig[0]), float(sig[1])),
                                 check=meas if have_meas else None)
            status = res.status
            if res.ok or status == "ambiguous":
                # ambiguous: the directions the scan constrains are matched, the others stay
                # at the prediction (the prior's regularisation); that is the best estimate
                est, matched = res.pose, True
                precise = bool(np.all(sig <= np.asarray(self.config.precise_meas)))
                if (res.ok or precise) and res.check_delta <= self.config.consistent_chi2:
                    # the measured pose explains the scan as well as the match: keep it
                    est, status = meas.copy(), "measured"
            elif status != "empty":
                self._add_scan = not self.config.skip_unmatched
        if have_meas:
            d = meas - est
            d[2] = (d[2] + math.pi) % (2.0 * math.pi) - math.pi
            if not matched:
                # no match: blend prediction and measurement by their variances
                so = self.config.odometry_sigma
                k = np.array([so[0] ** 2, so[0] ** 2, so[1] ** 2])
                k = k / (k + self._meas_var[[0, 0, 1]])
                est = est + k * d
            if odo is not None and self._last_meas is not None:
                # the measurement noise, learnt online (the controller is not told it): the
                # measured displacement minus the odometry's is n_k - n_(k-1) - e_k (n: white
                # measurement noise, e: odometry error), of variance 2 var(n) + var(e);
                # exponential average, floored. Independent of the estimate and the map.
                c = meas - self._last_meas - odo
                c[2] = (c[2] + math.pi) % (2.0 * math.pi) - math.pi
                so = self.config.odometry_sigma
                new_var = np.array([0.25 * (c[0] ** 2 + c[1] ** 2) - 0.5 * so[0] ** 2,
                                    0.5 * c[2] ** 2 - 0.5 * so[1] ** 2])
                # running mean (meas_sigma0 counting as 2 samples) until it weighs less than
                # meas_forget, exponential average after that
                self._meas_n += 1
                a = max(self.config.meas_forget, 1.0 / (self._meas_n + 2))
                self._meas_var = np.maximum((1 - a) * self._meas_var + a * new_var,
                                            np.square(self.config.meas_floor))
            self._last_meas = meas.copy()
        est[2] = (est[2] + math.pi) % (2.0 * math.pi) - math.pi
        self.estimate = est
        self.match_log.append((status, est.copy()))
        return est.copy(), self._add_scan
