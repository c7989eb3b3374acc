"""The Ackermann vehicle of the Victoria Park run (Guivant and Nebot 2001), with Jacobians.

The pose (x, y, theta) is that of the centre of the rear axle. The log gives the speed
``v_e`` of the encoder on the rear-left wheel, ``H`` metres left of the centre line, and
the steering angle ``phi``; the centre's speed is v_c = v_e / (1 - tan(phi) H / L) and over
``dt`` seconds (Euler, the controls held)::

    x' = x + dt v_c cos(theta)
    y' = y + dt v_c sin(theta)
    theta' = theta + dt v_c tan(phi) / L

The noise is on the controls (speed and steering), mapped into the pose through
W = d(pose')/d(v_e, phi).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ekfviz.core.types import FloatArray
from ekfviz.models.angles import wrap_angle


@dataclass(frozen=True, slots=True)
class Ackermann:
    """The vehicle's geometry and the noise of its controls.

    :param wheelbase: L, rear to front axle (m)
    :param encoder_offset: H, the encoder wheel's distance left of the centre line (m)
    :param sigma_speed: standard deviation of the encoder speed (m/s), per input
    :param sigma_steering: standard deviation of the steering angle (rad), per input
    """

    wheelbase: float = 2.83
    encoder_offset: float = 0.76
    sigma_speed: float = 2.0
    sigma_steering: float = math.radians(6.0)

    @property
    def Q(self) -> FloatArray:
        """Covariance (2x2) of the controls (v_e, phi)."""
        return np.diag(np.square([self.sigma_speed, self.sigma_steering]))

    def centre_speed(self, speed: float, steering: float) -> float:
        """v_c of the rear axle's centre from the encoder's speed."""
        return speed / (1.0 - math.tan(steering) * self.encoder_offset / self.wheelbase)

    def motion(
        self, pose_xytheta: FloatArray, speed: float, steering: float, dt: float
    ) -> FloatArray:
        """Noise-free motion over ``dt`` seconds.

        :return: new pose (3,), theta wrapped to (-pi, pi]
        """
        x, y, theta = np.asarray(pose_xytheta, dtype=np.float64).tolist()
        v_c = self.centre_speed(speed, steering)
        return np.array(
            [
                x + dt * v_c * math.cos(theta),
                y + dt * v_c * math.sin(theta),
                wrap_angle(theta + dt * v_c * math.tan(steering) / self.wheelbase),
            ]
        )

    def jacobians(
        self, pose_xytheta: FloatArray, speed: float, steering: float, dt: float
    ) -> tuple[FloatArray, FloatArray]:
        """Jacobians of :meth:`motion`.

        :return: (G, W): G = d(pose')/d(pose) (3x3), W = d(pose')/d(v_e, phi) (3x2)
        """
        theta = float(pose_xytheta[2])
        c, s = math.cos(theta), math.sin(theta)
        L, H = self.wheelbase, self.encoder_offset
        t = math.tan(steering)
        sec2 = 1.0 + t * t
        k = 1.0 - t * H / L
        v_c = speed / k
        vc_D_speed = 1.0 / k
        vc_D_steering = speed * (H / L) * sec2 / (k * k)
        G = np.array([[1.0, 0.0, -dt * v_c * s], [0.0, 1.0, dt * v_c * c], [0.0, 0.0, 1.0]])
        W = np.array(
            [
                [dt * c * vc_D_speed, dt * c * vc_D_steering],
                [dt * s * vc_D_speed, dt * s * vc_D_steering],
                [dt * t / L * vc_D_speed, dt / L * (vc_D_steering * t + v_c * sec2)],
            ]
        )
        return G, W
