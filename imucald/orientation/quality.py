"""How good the orientation is: inclination and heading standard deviations from the
calibration's uncertainty, the noise figures and the filter's state.  Pure functions.

The filter (VQF, Laidig & Seel 2023) corrects its gyro-integrated attitude towards the
accelerometer's gravity direction with time constant ``tau_acc_s`` (3 s by default) and its
heading towards the magnetometer's horizontal direction with ``tau_mag_s`` (9 s).  A
complementary filter of time constant tau settles, for each error source, at (Laidig & Seel,
section 3; a first-order low-pass of the disturbance):

* a gyro bias b not yet estimated: an angle error b * tau about each axis it acts on;
* a gyro gain error E (sensitivity and cross-axis, reading = (I + E) w): a bias E w that
  follows the rate, so the angle error is E times the rotation of the last few tau,
  forgotten as e^{-age/tau} (a 90-deg flip with a 3 % sensitivity error: 2.7 deg);
* a saturated gyro's unreported rate x: the angle error is x times the time at the rail,
  forgotten likewise (x taken as N(0, (range/2)^2), filter.SATURATED_EXCESS);
* an accelerometer bias (or scale error) of the calibration: its horizontal part divided by
  1 g, in rad (the filter cannot tell it from a tilt);
* a linear (gravity-free) acceleration: its tau-mean horizontal part divided by 1 g, rad;
* white accelerometer noise of sigma_a per sample at fs: sigma_a * sqrt(1 / (2 tau fs)) per axis;
* a relative magnetometer error r (residual hard/soft iron, disturbance): up to r / cos(dip)
  rad of heading, dip being the field's inclination below the horizon;
* while the magnetometer is rejected as disturbed, the heading runs on the gyro alone: its
  bias uncertainty integrates to sigma_b * t over t seconds of rejection;
* a tilt error e about the field's horizontal direction: the field's vertical part leaks into
  the estimated horizontal plane, e tan(dip) rad of heading (the steady state; holds shorter
  than tau_mag reach about half of it);
* a gyro bias taken off when a still interval measured it: the heading it turned, at most
  |b| tau_mag, pulled back as e^{-t/(2 tau_mag)} (VQF slows its heading correction while it
  doubts the field; the filter's _handover_hvar and HEADING_PULL_TAUS);
* a saturated gyro's unreported rate about the vertical: as the tilt's, with the vertical row
  of R, pulled back likewise (the filter's _excess_hvar_rad2).

The sources are independent and add in variance.  Inclination is the total tilt of the vertical
axis (two horizontal components); heading the rotation about the vertical.  These are standard
deviations of the error *model*; bench/orientation.py compares them with the error measured
against BROAD's optical reference.
"""
from __future__ import annotations

import math
from typing import Optional


__all__ = ["tilt_var_rad2", "heading_var_rad2", "ros_covariance", "ARBITRARY_HEADING_VAR_RAD2",
           "ARBITRARY_TILT_VAR_RAD2"]

#: heading variance of a 6D estimate: its heading is an arbitrary angle, uniform on the circle
#: (variance of U(-pi, pi) = pi^2 / 3); ROS readers that fuse yaw get "no information"
ARBITRARY_HEADING_VAR_RAD2 = math.pi ** 2 / 3
#: tilt variance of no information: the vertical axis uniform on the sphere, so the tilt angle
#: has density sin(t)/2 on [0, pi] and E[t^2] = (pi^2 - 4) / 2 (98 deg rms)
ARBITRARY_TILT_VAR_RAD2 = (math.pi ** 2 - 4) / 2


def tilt_var_rad2(acc_bias_var_g2: Optional[float], gyro_bias_sigma_rad_s: float,
                  lin_acc_lp_g: float, acc_noise_g: Optional[float], tau_acc_s: float,
                  rate_hz: float, gain_var_rad2: float = 0.0) -> float:
    """Variance of the total tilt error (both horizontal components), rad^2.

    acc_bias_var_g2: the sum over the axes of the accelerometer calibration's squared bias
    standard errors (g^2), or None when unknown; its horizontal share is 2/3 of the total on
    average over orientations.
    gyro_bias_sigma_rad_s: the filter's own bias uncertainty (worst direction).
    lin_acc_lp_g: magnitude of the tau-low-passed horizontal gravity-free acceleration (g).
    acc_noise_g: one sample's accelerometer noise std (g), or None.
    gain_var_rad2: the tilt variance a gyro gain (sensitivity, cross-axis) error leaves: its
    variance times the rotation of the last few tau_acc, both horizontal components (the
    filter's _track_gain), plus the saturated gyro's unreported rate's (_track_excess)."""
    v = 2.0 * (gyro_bias_sigma_rad_s * tau_acc_s) ** 2 + lin_acc_lp_g ** 2 + gain_var_rad2
    if acc_bias_var_g2 is not None:
        v += 2.0 / 3.0 * acc_bias_var_g2
    if acc_noise_g is not None:
        v += 2.0 * acc_noise_g ** 2 / (2.0 * tau_acc_s * rate_hz)
    return min(v, ARBITRARY_TILT_VAR_RAD2)


def heading_var_rad2(gyro_bias_sigma_rad_s: float, mag_rel_err: float, dip_rad: float,
                     tau_mag_s: float, rejected_s: float, tilt_var: float = 0.0,
                     pullback_var: float = 0.0) -> float:
    """Variance of the heading error of a magnetometer-referenced estimate, rad^2.

    mag_rel_err: relative error of the magnetometer's vector (the calibration's held-out
    relative RMS or the measured spread of |m|, whichever is larger); dip_rad: the field's
    inclination; rejected_s: seconds the magnetometer has been rejected as disturbed;
    tilt_var: the tilt variance (tilt_var_rad2), rad^2.  The heading is the direction of the
    field's horizontal part, found through the estimated vertical: a tilt error e about the
    field's horizontal direction moves it by e tan(dip) (the vertical part, sin(dip), leaks
    into the horizontal plane, cos(dip)), about the perpendicular axis not at all; one of the
    two horizontal components, tilt_var / 2 on average over headings (a tilt error lined up
    with the field's direction moves the heading sqrt(2) times more than this sd says).
    pullback_var: heading errors the magnetometer is pulling back, rad^2: what a gyro bias left
    when a still interval measured it and it was taken off, and a saturated gyro's unreported
    turn about the vertical (the filter's, fading over HEADING_PULL_TAUS tau_mag of rows with
    a magnetometer)."""
    c = max(math.cos(dip_rad), 0.2)          # near the poles heading is undetermined anyway
    v = (mag_rel_err / c) ** 2 + (gyro_bias_sigma_rad_s * tau_mag_s) ** 2
    v += (gyro_bias_sigma_rad_s * rejected_s) ** 2
    v += tilt_var / 2.0 * (1.0 - c * c) / (c * c) + pullback_var
    return min(v, ARBITRARY_HEADING_VAR_RAD2)


def ros_covariance(tilt_var: float, heading_var: float) -> list:
    """sensor_msgs/Imu ``orientation_covariance``: 9 numbers, row-major, rad^2, about the fixed
    x, y, z axes (roll, pitch, yaw): the tilt variance split evenly between roll and pitch."""
    r = tilt_var / 2.0
    return [r, 0.0, 0.0, 0.0, r, 0.0, 0.0, 0.0, heading_var]
