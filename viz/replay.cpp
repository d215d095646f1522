#include "replay.hpp"

#include <cmath>

#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"

namespace trocar::viz {

std::vector<ReplayFrame> ReplayMotion(const robot::RobotModel& robot, const robot::RobotState& start,
                                      const planners::StoredMotion& motion,
                                      planners::PlanCollisions* collisions, double max_step,
                                      double near_miss) {
  const bool failed = motion.waypoints.empty() && motion.failure_pose.size() > 0;
  TROCAR_THROW_UNLESS(!motion.waypoints.empty() || failed,
                      "motion of " << motion.arm << " to sample " << motion.sample
                                   << " has no waypoints and no failure pose (" << motion.outcome
                                   << ")");
  TROCAR_THROW_UNLESS(max_step > 0, "replay step " << max_step << ": expected > 0");
  std::vector<int> q_index;
  std::vector<double> weight;
  for (const std::string& name : motion.joints) {
    const int j = robot.FindJoint(name);
    TROCAR_THROW_UNLESS(j >= 0 && robot.joint(j).q_index >= 0,
                        "motion of " << motion.arm << ": '" << name << "' is not an active joint of "
                                     << robot.name());
    q_index.push_back(robot.joint(j).q_index);
    weight.push_back(robot.joint(j).type == robot::JointType::kPrismatic ? 10.0 : 1.0);
  }
  std::vector<ReplayFrame> frames;
  auto add = [&](const Eigen::VectorXd& w, std::size_t segment) {
    ReplayFrame frame{start, segment, {}};
    Eigen::VectorXd q = start.q;
    for (std::size_t d = 0; d < q_index.size(); ++d) q[q_index[d]] = w[d];
    const auto fk = kinematics::ForwardKinematics(robot, q, &frame.state);
    TROCAR_THROW_UNLESS(fk.ok(), "motion of " << motion.arm << " to sample " << motion.sample
                                            << ": " << fk.message);
    // On its way to its sample, the instrument's wrist and jaws may touch the organ there.
    if (collisions) frame.collisions = collisions->Check(frame.state, near_miss, motion.sample);
    frames.push_back(std::move(frame));
  };
  // A failed motion: from the nominal pose straight to the pose that fails (issue #43 item 9).
  std::vector<Eigen::VectorXd> to_failure;
  if (failed) {
    TROCAR_THROW_UNLESS(motion.failure_pose.size() == static_cast<Eigen::Index>(q_index.size()),
                        "motion of " << motion.arm << " to sample " << motion.sample << ": "
                                     << motion.failure_pose.size() << " failure-pose values for "
                                     << q_index.size() << " joints");
    Eigen::VectorXd nominal(static_cast<Eigen::Index>(q_index.size()));
    for (std::size_t d = 0; d < q_index.size(); ++d) nominal[d] = start.q[q_index[d]];
    to_failure = {nominal, motion.failure_pose};
  }
  const auto& w = failed ? to_failure : motion.waypoints;
  add(w[0], 0);
  for (std::size_t k = 0; k + 1 < w.size(); ++k) {
    double longest = 0;
    for (std::size_t d = 0; d < q_index.size(); ++d)
      longest = std::max(longest, weight[d] * std::abs(w[k + 1][d] - w[k][d]));
    const int steps = std::max(1, static_cast<int>(std::ceil(longest / max_step)));
    for (int s = 1; s <= steps; ++s) add(w[k] + (w[k + 1] - w[k]) * (double(s) / steps), k);
  }
  return frames;
}

}  // namespace trocar::viz
