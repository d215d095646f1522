#include "control/force_feedback.hpp"

#include <cmath>

#include "common/error.hpp"
#include "kinematics/jacobian.hpp"

namespace trocar::control {

ForceFeedback::ForceFeedback(const robot::RobotModel& model, std::vector<int> positions,
                             const ForceFeedbackOptions& options)
    : model_(model), positions_(std::move(positions)), options_(options) {
  for (double v : {options.influence, options.max_force, options.limit_margin, options.limit_force})
    TROCAR_THROW_UNLESS(std::isfinite(v) && v > 0, "force feedback: option " << v << " must be positive");
  TROCAR_THROW_UNLESS(options.limit_margin < 0.5, "force feedback: limit margin " << options.limit_margin
                                                                                  << " must be under 0.5");
  J_.resize(6, model.num_positions());
}

ForceCue ForceFeedback::Compute(const robot::RobotState& state, const robot::Frame& tool, const ArmNearness& near) {
  ForceCue cue;
  // Nearness: along the witness points, away from the obstacle, linear in the gap.
  if (std::isfinite(near.distance) && near.distance < options_.influence) {
    const Eigen::Vector3d away = near.p_W_arm - near.p_W_other;
    if (away.norm() > 1e-9) last_away_W_ = away.normalized();
    if (last_away_W_.squaredNorm() > 0) {
      const double share = 1.0 - std::max(near.distance, 0.0) / options_.influence;
      cue.f_W += options_.max_force * share * last_away_W_;
      cue.reasons |= ForceCue::kNear;
    }
  }
  // Limits: each arm joint within the margin of a limit pushes the hand against the direction
  // in which that joint moving on would carry the tool.
  kinematics::ComputeFrameJacobian(model_, state, tool, &J_);
  double deepest = 0.0;
  for (int k : positions_) {
    const robot::Joint& joint = model_.joint(model_.active_joints()[k]);
    const double lo = joint.limits.lower, hi = joint.limits.upper;
    if (!std::isfinite(lo) || !std::isfinite(hi) || hi <= lo) continue;
    const double q = state.q[k], band = options_.limit_margin * (hi - lo);
    double depth = 0.0, toward = 0.0;
    if (q > hi - band) {
      depth = (q - (hi - band)) / band;
      toward = 1.0;
    } else if (q < lo + band) {
      depth = ((lo + band) - q) / band;
      toward = -1.0;
    }
    if (depth <= 0.0) continue;
    depth = std::min(depth, 1.0);
    const Eigen::Vector3d v = J_.block<3, 1>(3, k) * toward;  // the tool's motion toward the limit
    if (v.norm() < 1e-9) continue;                              // this joint does not move the tool
    cue.f_W -= options_.limit_force * depth * v.normalized();
    cue.reasons |= joint.type == robot::JointType::kPrismatic ? ForceCue::kInsertionLimit : ForceCue::kJointLimit;
    if (depth > deepest) {
      deepest = depth;
      cue.joint = joint.name;
    }
  }
  return cue;
}

}  // namespace trocar::control
