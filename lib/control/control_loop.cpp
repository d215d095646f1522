#include "control/control_loop.hpp"

#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"

namespace trocar::control {

ControlLoop::ControlLoop(const robot::RobotModel& model, std::unique_ptr<Controller> controller,
                         const Eigen::VectorXd& q0, const Eigen::Isometry3d& X_WB,
                         const std::vector<std::pair<std::string, double>>& held)
    : model_(model),
      controller_(std::move(controller)),
      state_(model),
      qdot_(Eigen::VectorXd::Zero(model.num_positions())),
      qdot_command_(Eigen::VectorXd::Zero(model.num_positions())),
      qdot_applied_(Eigen::VectorXd::Zero(model.num_positions())),
      q_next_(Eigen::VectorXd::Zero(model.num_positions())) {
  workspace_.Resize(model.num_positions());
  TROCAR_THROW_UNLESS(controller_ != nullptr, "ControlLoop: no controller");
  state_.X_WB = X_WB;
  for (const auto& [name, value] : held) {
    const auto set = kinematics::SetHeldJoint(model_, name, value, &state_);
    TROCAR_THROW_UNLESS(set.ok(), "robot '" << model_.name() << "': held joint '" << name << "': " << set.message);
  }
  const auto result = kinematics::ForwardKinematics(model_, q0, &state_);
  TROCAR_THROW_UNLESS(result.ok(), "robot '" << model_.name()
                                           << "': start configuration: " << result.message);
}

Eigen::Isometry3d ControlLoop::ToolPose() const {
  return kinematics::FramePose(state_, model_.tool_frame());
}

StepReport ControlLoop::Step(const TaskTarget& target, double dt) {
  StepReport report;
  if (dt > 0.0) {
    controller_->ComputeVelocity(model_, state_, target, &workspace_, &qdot_command_);
    report.limits =
        ApplyJointLimits(model_, state_.q, qdot_, qdot_command_, dt, &qdot_applied_, &q_next_);
    const auto result = kinematics::SetConfiguration(model_, q_next_, &state_);
    if (result.ok()) {
      qdot_ = qdot_applied_;
      kinematics::ForwardKinematics(model_, &state_);
    } else {
      report.closure_refused = true;  // state unchanged: hold
      qdot_.setZero();
    }
  }
  report.X_WT = ToolPose();
  report.position_error = (target.X_WD.translation() - report.X_WT.translation()).norm();
  report.orientation_error = AngleBetween(target.X_WD.linear(), report.X_WT.linear());
  return report;
}

}  // namespace trocar::control
