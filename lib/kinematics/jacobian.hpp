#pragma once
/// @file
/// Geometric Jacobians (thesis eq. 4.23–4.25, after Angeles): for a point F fixed to a link,
/// J_WF maps q̇ to F's spatial velocity [ω_WF; v_WF] expressed in the world frame, angular over
/// linear. Revolute column [e_i; e_i × (p_WF − p_Wi)], prismatic [0; e_i]; mimic and closure
/// joints contribute through d joint_values / d q, so closed chains get the Jacobian of their
/// active joints.

#include <Eigen/Core>
#include <Eigen/SVD>

#include "robot/robot_model.hpp"
#include "robot/robot_state.hpp"

namespace trocar::kinematics {

using Matrix6Xd = Eigen::Matrix<double, 6, Eigen::Dynamic>;

/// Jacobian of the point `p_LF` fixed to `link`, written into `J_WF` (resized to 6 × nq).
/// @pre ForwardKinematics has been run on `state`.
void ComputeJacobian(const robot::RobotModel& model, const robot::RobotState& state, int link,
                     const Eigen::Vector3d& p_LF, Matrix6Xd* J_WF);

/// Jacobian of a named frame's origin (e.g. the tool frame).
void ComputeFrameJacobian(const robot::RobotModel& model, const robot::RobotState& state,
                          const robot::Frame& frame, Matrix6Xd* J_WF);

/// The pseudo-inverse V Σ⁺ Uᵀ from a thin SVD (ComputeThinU | ComputeThinV): singular values
/// at or below `relative_cutoff` × σ_max are taken as lost (0 in Σ⁺).
Eigen::MatrixXd PseudoInverse(const Eigen::JacobiSVD<Eigen::MatrixXd>& svd, double relative_cutoff);

}  // namespace trocar::kinematics
