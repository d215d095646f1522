#pragma once
/// @file
/// One arm's control loop: controller → joint limits (acceleration, velocity, position) →
/// integration with the measured step time → closures solved → forward kinematics. Owns the
/// arm's RobotState; one ControlLoop per thread.

#include <memory>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "control/controller.hpp"
#include "control/joint_limits.hpp"
#include "robot/robot_model.hpp"
#include "robot/robot_state.hpp"

namespace trocar::control {

struct StepReport {
  Eigen::Isometry3d X_WT = Eigen::Isometry3d::Identity();  ///< tool pose after the step
  double position_error = 0.0;     ///< m, |x_d − x| after the step
  double orientation_error = 0.0;  ///< rad, angle between desired and actual
  LimitReport limits;
  bool closure_refused = false;    ///< a closure could not follow: the arm held still
};

class ControlLoop {
 public:
  /// @param model must outlive the loop. @param q0 start configuration (inside the limits).
  /// @throws trocar::Error when q0 is malformed or a closure cannot reach it.
  /// @param held values of held (set-before-use) joints by name, e.g. a plan's setup joints.
  ControlLoop(const robot::RobotModel& model, std::unique_ptr<Controller> controller,
              const Eigen::VectorXd& q0,
              const Eigen::Isometry3d& X_WB = Eigen::Isometry3d::Identity(),
              const std::vector<std::pair<std::string, double>>& held = {});

  /// Advances by `dt` seconds (the measured loop time) toward `target`.
  StepReport Step(const TaskTarget& target, double dt);

  const robot::RobotState& state() const { return state_; }
  const Eigen::VectorXd& qdot() const { return qdot_; }
  const Controller& controller() const { return *controller_; }
  Eigen::Isometry3d ToolPose() const;

 private:
  const robot::RobotModel& model_;
  std::unique_ptr<Controller> controller_;
  robot::RobotState state_;
  ControllerWorkspace workspace_;
  Eigen::VectorXd qdot_;
  Eigen::VectorXd qdot_command_;
  Eigen::VectorXd qdot_applied_;
  Eigen::VectorXd q_next_;
};

}  // namespace trocar::control
