#pragma once
/// @file
/// Collisions and clearance of the robot of a stored plan (plan_file.hpp), by the plan's rules
/// (docs/plan-format.md, "Ports"): each instrument may touch the skin within its port's
/// allowance around its pivot (the cannula's track through the wall plus the world's port radius,
/// following the instrument as it turns: port_rules.hpp, TrackAllowance);
/// every other contact is a collision. For whatever shows or replays a plan's poses.

#include <memory>
#include <string>
#include <vector>

#include "collision/collision_world.hpp"
#include "patient/patient_model.hpp"
#include "plan/plan_file.hpp"

namespace trocar::collision {
class TriangleBvh;
}

namespace trocar::planners {

struct PoseCollisions {
  bool collision = false;
  std::vector<std::string> pairs;   ///< "psm2_yaw_link - table", per colliding pair
  std::vector<int> colliding_links; ///< robot links in a colliding pair
  /// Smallest distance between the robot and anything else (instruments at their ports
  /// excepted), with the pair: 0 in contact.
  double clearance = 0.0;
  std::string clearance_pair;
  /// Robot links within `near_miss` of something they may not touch (the colliding ones too).
  std::vector<int> near_links;
};

class PlanCollisions {
 public:
  /// @throws trocar::Error when the plan's arms are not the robot's.
  PlanCollisions(const patient::PatientModel& patient, std::shared_ptr<const robot::RobotModel> robot,
                 const PlanFile& file, std::size_t plan_index);
  ~PlanCollisions();

  /// The robot at `state` (forward kinematics done). `near_miss` (m): how close counts as a near
  /// miss. `work_sample` >= 0 (an index into the plan's target samples): the instruments work on
  /// that sample, their wrist and jaws may touch the organ there (port_rules.hpp,
  /// kWorkSiteRadius), as on a motion to it.
  PoseCollisions Check(const robot::RobotState& state, double near_miss = 0.005,
                       int work_sample = -1);

  /// For each link in `arm_links` (a link of an arm, e.g. its tool's), that arm's nearest
  /// approach at `state` to anything it may not touch (its own links aside), with witness points,
  /// the arm's body as `a`; an invalid Clearance for a link on no arm. For force feedback.
  std::vector<collision::Clearance> ArmsNearest(const robot::RobotState& state, const std::vector<int>& arm_links);
  /// "psm1_tool_shaft - heart".
  std::string PairName(const collision::Clearance& c) const;

  const collision::CollisionWorld& world() const { return *world_; }

 private:
  std::shared_ptr<const collision::CollisionWorld> world_;
  std::unique_ptr<collision::CollisionChecker> checker_;
  std::vector<int> port_of_arm_;
  std::vector<double> allowance_;
  std::vector<double> depth_;                 ///< per arm: the pivot's depth under the skin
  std::vector<Eigen::Vector3d> incisions_P_;  ///< per arm
  std::vector<robot::Frame> tool_frame_;      ///< per arm (link -1: none)
  std::unique_ptr<collision::TriangleBvh> skin_;  ///< in P
  Eigen::Isometry3d X_PW_ = Eigen::Isometry3d::Identity();
  std::vector<Eigen::Vector3d> pivots_;
  std::vector<Eigen::Vector3d> samples_W_;
  std::vector<char> instrument_;  ///< per arm
  std::shared_ptr<const robot::RobotModel> robot_;
  void SetState(const robot::RobotState& state, int work_sample = -1);
};

}  // namespace trocar::planners
