#pragma once
/// @file
/// Pose errors for kinematic control (thesis §4.6): position error x_d − x and Luh et al.'s
/// orientation error φ_e = (r32 − r23, r13 − r31, r21 − r12) of R_e = R_d R_cᵀ, which is
/// 2 sin(θ) times the axis of the rotation from the current to the desired orientation.

#include <Eigen/Geometry>

namespace trocar::control {

using Vector6d = Eigen::Matrix<double, 6, 1>;

/// Luh's orientation error of R_e = R_d R_cᵀ, in the world frame.
Eigen::Vector3d OrientationError(const Eigen::Matrix3d& R_WD, const Eigen::Matrix3d& R_WC);

/// Task-space error [φ_e; x_d − x_c], angular over linear like the Jacobians.
Vector6d TaskError(const Eigen::Isometry3d& X_WD, const Eigen::Isometry3d& X_WC);

/// Angle (rad) between two orientations, 0 .. π.
double AngleBetween(const Eigen::Matrix3d& R_a, const Eigen::Matrix3d& R_b);

}  // namespace trocar::control
