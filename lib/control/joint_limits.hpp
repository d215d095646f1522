#pragma once
/// @file
/// Joint limits applied to a velocity command, in the thesis' order (§4.5): acceleration, then
/// velocity, then position. Position is guarded with a braking bound: a joint never moves faster
/// than it can still stop, at its acceleration limit, before its position limit, so no limit is
/// ever crossed, even by a step command driving it into a limit.

#include <vector>

#include <Eigen/Core>

#include "robot/robot_model.hpp"
#include "robot/robot_state.hpp"

namespace trocar::control {

struct LimitReport {
  int acceleration_limited = 0;  ///< joints whose command the acceleration limit changed
  int velocity_limited = 0;
  int position_limited = 0;
};

/// @param q current active joint values; @param qdot_previous last applied velocity;
/// @param qdot_command controller output; @param dt step time (s, > 0).
/// @param[out] qdot applied velocity; @param[out] q_next = q + qdot·dt, within the limits.
LimitReport ApplyJointLimits(const robot::RobotModel& model, const Eigen::VectorXd& q,
                             const Eigen::VectorXd& qdot_previous,
                             const Eigen::VectorXd& qdot_command, double dt,
                             Eigen::VectorXd* qdot, Eigen::VectorXd* q_next);

/// Largest speed toward a limit `distance` away from which steps of `dt`, decelerating by at
/// most `acceleration`·dt each, still stop before it (exact for a constant dt).
double BrakingSpeed(double distance, double acceleration, double dt);

/// A cheap sufficient test that `speed` (≥ 0) is at or below BrakingSpeed(distance, ...): true
/// when speed²/acceleration + speed·dt (a bound on the discrete braking distance) and speed·dt
/// fit within `distance`. False says nothing (compute BrakingSpeed).
bool CanStopWithin(double speed, double distance, double acceleration, double dt);

/// What following a tool motion asks of the joints' velocity limits at one configuration.
struct VelocityDemand {
  double share = 0.0;       ///< largest |q̇_i| / velocity limit_i over the samples (≤ 1: within)
  int joint = -1;           ///< q index of that joint (-1 when no sample moves a limited joint)
  double rate = 0.0;        ///< its rate (rad/s or m/s)
  double tool_speed = 0.0;  ///< m/s, the tool's linear speed in that sample
  double peak_tool_speed = 0.0;  ///< m/s, over all samples
};

/// Joint rates the tool velocities `V_W` ([ω; v] in the world frame, one per sample) need at
/// `state` (forward kinematics done: its base pose and held joints count),
/// through the tool Jacobian's pseudo-inverse (rows of the task: all six, or the linear three when
/// `position_only`; directions with σ below 1e-6 σ_max left out): the worst share of a velocity
/// limit. A first-order estimate at the state: along a path the joints move and the demand
/// changes.
VelocityDemand JointVelocityDemand(const robot::RobotModel& model, const robot::RobotState& state,
                                   const std::vector<Eigen::Matrix<double, 6, 1>>& V_W,
                                   bool position_only);

}  // namespace trocar::control
