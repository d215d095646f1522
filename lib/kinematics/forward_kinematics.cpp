#include "kinematics/forward_kinematics.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "common/error.hpp"
#include "kinematics/four_bar.hpp"
#include "kinematics/sin_cos.hpp"

namespace trocar::kinematics {

using robot::Joint;
using robot::JointDrive;
using robot::JointType;
using robot::RobotModel;
using robot::RobotState;

namespace {

// Resolves mimic and closure joints from the active/held values already in `state`.
ConfigurationResult ResolvePassive(const RobotModel& model, RobotState* state) {
  Eigen::VectorXd& values = state->joint_values;
  Eigen::MatrixXd& grad = state->dvalues_dq;
  for (int step : model.resolve_order()) {
    if (step >= 0) {
      const Joint& joint = model.joint(step);
      const Joint& master = model.joint(joint.mimic.master);
      values[joint.dof_index] = joint.mimic.multiplier * values[master.dof_index] +
                                joint.mimic.offset;
      grad.row(joint.dof_index) = joint.mimic.multiplier * grad.row(master.dof_index);
      continue;
    }
    const int ci = -1 - step;
    const robot::FourBarClosure& c = model.closures()[ci];
    const int d = model.joint(c.driver).dof_index;
    const int cp = model.joint(c.coupler).dof_index;
    const int rk = model.joint(c.rocker).dof_index;
    // Continue from where this loop was last closed, so no change point is jumped over.
    const double previous_driver = state->closure_drivers[ci];
    const FourBarSolution s =
        SolveFourBar(model, c, values[d], previous_driver, values[cp], values[rk]);
    if (!s.ok()) return ConfigurationResult{ConfigurationResult::Status::kClosureRefused, s.message, ci};
    values[cp] = s.coupler;
    values[rk] = s.rocker;
    grad.row(cp) = s.dcoupler_ddriver * grad.row(d);
    grad.row(rk) = s.drocker_ddriver * grad.row(d);
    state->closure_drivers[ci] = values[d];
  }
  return {};
}

// Keeps what SetConfiguration and SetHeldJoint change, in the state's own undo buffers (same
// sizes: no allocation).
void KeepForUndo(RobotState* state) {
  state->undo.q = state->q;
  state->undo.joint_values = state->joint_values;
  state->undo.closure_drivers = state->closure_drivers;
  state->undo.dvalues_dq = state->dvalues_dq;
}

// Runs ResolvePassive, restoring the kept values when a closure refuses.
ConfigurationResult ResolveOrRestore(const RobotModel& model, RobotState* state, bool kept) {
  ConfigurationResult result = ResolvePassive(model, state);
  if (!result.ok() && kept) {
    state->q = state->undo.q;
    state->joint_values = state->undo.joint_values;
    state->closure_drivers = state->undo.closure_drivers;
    state->dvalues_dq = state->undo.dvalues_dq;
  }
  return result;
}

}  // namespace

const char* ToString(ConfigurationResult::Status status) {
  switch (status) {
    case ConfigurationResult::Status::kSet: return "set";
    case ConfigurationResult::Status::kClosureRefused: return "a closure refused";
  }
  return "unknown";
}

ConfigurationResult SetConfiguration(const RobotModel& model, const Eigen::VectorXd& q,
                                     RobotState* state) {
  TROCAR_THROW_UNLESS(q.size() == model.num_positions(),
                      "robot '" << model.name() << "': configuration has " << q.size()
                                << " values, expected " << model.num_positions());
  if (!q.allFinite()) {
    for (int i = 0; i < q.size(); ++i) {
      TROCAR_THROW_UNLESS(std::isfinite(q[i]),
                          "robot '" << model.name() << "': configuration value " << i
                                    << " (joint '" << model.joint(model.active_joints()[i]).name
                                    << "') is " << q[i] << ", expected a finite number");
    }
  }
  // Only closures can refuse; keep what changes to undo the step only when there are some.
  const bool keep = !model.closures().empty();
  if (keep) KeepForUndo(state);
  state->q = q;
  for (int i = 0; i < q.size(); ++i) {
    const Joint& joint = model.joint(model.active_joints()[i]);
    state->joint_values[joint.dof_index] = q[i];
  }
  return ResolveOrRestore(model, state, keep);
}

ConfigurationResult SetHeldJoint(const RobotModel& model, const std::string& name, double value,
                                 RobotState* state) {
  const Joint& joint = model.joint(model.GetJoint(name));
  TROCAR_THROW_UNLESS(joint.drive == JointDrive::kHeld,
                      "robot '" << model.name() << "': joint '" << name << "' is "
                                << robot::ToString(joint.drive) << ", not held");
  TROCAR_THROW_UNLESS(std::isfinite(value), "robot '" << model.name() << "': joint '" << name
                                                      << "' value " << value
                                                      << " is not finite");
  TROCAR_THROW_UNLESS(value >= joint.limits.lower && value <= joint.limits.upper,
                      "robot '" << model.name() << "': joint '" << name << "' value " << value
                                << " is outside its limits [" << joint.limits.lower << ", "
                                << joint.limits.upper << "]");
  KeepForUndo(state);
  state->joint_values[joint.dof_index] = value;
  return ResolveOrRestore(model, state, true);
}

namespace {

// X_WC of a joint's child link from its parent's pose X_WP and the joint's value (s, c: the
// value's sine and cosine, for a revolute joint).
inline void ChildPose(const Joint& joint, const Eigen::Isometry3d& X_WP, double value, double s,
                      double c, Eigen::Isometry3d* X_WC_out) {
  Eigen::Isometry3d& X_WC = *X_WC_out;
  switch (joint.type) {
    case JointType::kFixed:
      X_WC.linear().noalias() = X_WP.linear() * joint.X_PJ.linear();
      X_WC.translation().noalias() = X_WP.linear() * joint.X_PJ.translation();
      X_WC.translation() += X_WP.translation();
      break;
    case JointType::kRevolute: {
      const Eigen::Matrix3d& R_PJ = joint.X_PJ.linear();
      Eigen::Matrix3d R_PC;
      if (joint.axis_J.z() == 1.0) {  // the common case (DH, most URDFs): no Rodrigues
        R_PC.col(0) = c * R_PJ.col(0) + s * R_PJ.col(1);
        R_PC.col(1) = c * R_PJ.col(1) - s * R_PJ.col(0);
        R_PC.col(2) = R_PJ.col(2);
      } else {  // Rodrigues, with the joint's constant terms from the model
        R_PC = c * (R_PJ - joint.rodrigues_M) + s * joint.rodrigues_N + joint.rodrigues_M;
      }
      X_WC.linear().noalias() = X_WP.linear() * R_PC;
      X_WC.translation().noalias() = X_WP.linear() * joint.X_PJ.translation();
      X_WC.translation() += X_WP.translation();
      break;
    }
    case JointType::kPrismatic: {
      X_WC.linear().noalias() = X_WP.linear() * joint.X_PJ.linear();
      X_WC.translation().noalias() = X_WC.linear() * (value * joint.axis_J);
      X_WC.translation() += X_WP * joint.X_PJ.translation();
      break;
    }
  }
}

}  // namespace

void ForwardKinematics(const RobotModel& model, RobotState* state) {
  std::vector<Eigen::Isometry3d>& X_WL = state->X_WL;
  X_WL[0] = state->X_WB;
  // The revolute joints' sines and cosines first, a batch at a time: they do not depend on one
  // another, so the CPU runs their polynomials side by side, where along the chain each waited
  // on its own (measured: FK of the PA10 180 -> 120 ns; bench/kinematics_bench).
  constexpr std::size_t kBatch = 32;
  double sines[kBatch] = {}, cosines[kBatch] = {};
  const std::vector<Joint>& joints = model.joints();
  for (std::size_t start = 0; start < joints.size(); start += kBatch) {
    const std::size_t end = std::min(joints.size(), start + kBatch);
    for (std::size_t i = start; i < end; ++i) {
      if (joints[i].type == JointType::kRevolute)
        SinCos(state->joint_values[joints[i].dof_index], &sines[i - start], &cosines[i - start]);
    }
    for (std::size_t i = start; i < end; ++i) {
      const Joint& joint = joints[i];
      const double value =
          joint.type == JointType::kFixed ? 0.0 : state->joint_values[joint.dof_index];
      ChildPose(joint, X_WL[joint.parent_link], value, sines[i - start], cosines[i - start],
                &X_WL[joint.child_link]);
    }
  }
}

void ForwardKinematicsToLink(const RobotModel& model, int link, RobotState* state) {
  TROCAR_THROW_UNLESS(link >= 0 && link < model.num_links(),
                      "robot '" << model.name() << "': no link " << link);
  std::vector<Eigen::Isometry3d>& X_WL = state->X_WL;
  X_WL[0] = state->X_WB;
  // The chain from the link up to the root, then down it (a chain deeper than the buffer, which
  // no robot here comes near, takes the whole robot's forward kinematics: same poses).
  constexpr int kMaxDepth = 128;
  int chain[kMaxDepth];
  int n = 0;
  for (int l = link; model.link(l).parent_joint >= 0; ++n) {
    if (n == kMaxDepth) {
      ForwardKinematics(model, state);
      return;
    }
    chain[n] = model.link(l).parent_joint;
    l = model.joint(chain[n]).parent_link;
  }
  for (int k = n - 1; k >= 0; --k) {
    const Joint& joint = model.joint(chain[k]);
    double value = 0.0, s = 0.0, c = 1.0;
    if (joint.type != JointType::kFixed) value = state->joint_values[joint.dof_index];
    if (joint.type == JointType::kRevolute) SinCos(value, &s, &c);
    ChildPose(joint, X_WL[joint.parent_link], value, s, c, &X_WL[joint.child_link]);
  }
}

ConfigurationResult ForwardKinematics(const RobotModel& model, const Eigen::VectorXd& q,
                                      RobotState* state) {
  ConfigurationResult result = SetConfiguration(model, q, state);
  if (result.ok()) ForwardKinematics(model, state);
  return result;
}

Eigen::Isometry3d FramePose(const RobotState& state, const robot::Frame& frame) {
  return state.X_WL[frame.link] * frame.X_LF;
}

Eigen::Isometry3d KinematicFramePose(const RobotModel& model, const RobotState& state,
                                     int link) {
  return state.X_WL.at(link) * model.link(link).X_LK;
}

Eigen::Isometry3d ToolPoseInBase(const RobotModel& model, const RobotState& state) {
  return state.X_WL[model.base_link()].inverse() * FramePose(state, model.tool_frame());
}

std::vector<std::string> LimitViolations(const RobotModel& model, const Eigen::VectorXd& q) {
  std::vector<std::string> out;
  for (int i = 0; i < model.num_positions() && i < q.size(); ++i) {
    const Joint& joint = model.joint(model.active_joints()[i]);
    if (q[i] < joint.limits.lower || q[i] > joint.limits.upper) {
      std::ostringstream msg;
      msg << "joint '" << joint.name << "' = " << q[i] << " outside [" << joint.limits.lower
          << ", " << joint.limits.upper << "]";
      out.push_back(msg.str());
    }
  }
  return out;
}

}  // namespace trocar::kinematics
