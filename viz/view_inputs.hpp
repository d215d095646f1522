#pragma once
/// @file
/// What a view is opened on — a case, optionally a plan file and one of its plans, or a robot
/// alone — loaded and checked against each other: the plan must have been made for this patient
/// model and this robot file (their hashes), and its nominal pose must fit the robot. Shared by
/// `trocar view` (window and screenshots) and the report.

#include <memory>
#include <string>
#include <vector>

#include "motion/plan_collisions.hpp"
#include "plan/plan_file.hpp"
#include "scene.hpp"

namespace trocar::viz {

struct ViewInputs {
  std::string case_dir;
  std::string plan;        ///< a plan.json; empty: the case alone
  int plan_index = 1;      ///< 1-based, best first
  std::string robot;       ///< without a plan: a robot to show at its neutral pose
  std::string motion;      ///< "ARM:SAMPLE[:WAYPOINT]": the robot on a verified motion
  std::vector<std::string> colours, opacities, hidden;
  bool flat = false;
  /// Each target coloured along its length by which arms reach it (Scene::ShowReachability).
  bool reach = false;
};

struct LoadedView {
  std::shared_ptr<const patient::PatientModel> patient;
  std::shared_ptr<const robot::RobotModel> robot;
  std::unique_ptr<planners::PlanFile> plan;  ///< null without a plan file
  std::unique_ptr<Scene> scene;
  /// With a plan: its collision rules, and the shown pose's collisions (highlighted in the scene).
  std::unique_ptr<planners::PlanCollisions> collisions;
  planners::PoseCollisions pose;
  /// With a failed motion (`ViewInputs::motion`): why it fails ("unreachable: ..."); the robot is
  /// shown at the pose that fails.
  std::string failure;
};

/// The pose's collisions in words: "in collision: a - b, ..." or "clearance 12.3 mm (a - b)".
std::string Describe(const planners::PoseCollisions& pose);

/// @throws trocar::Error naming the file and what does not match: a missing or malformed case,
/// plan or robot; a plan made for another patient model or robot file; a plan index out of
/// range; a motion the plan has not.
LoadedView LoadView(const ViewInputs& inputs);

/// The style of `inputs` (colours, opacities, hidden groups, flat) over the default.
/// @throws trocar::Error naming a malformed colour or opacity.
SceneStyle StyleOf(const ViewInputs& inputs);

/// FindMotion's waypoint for a failed motion: the pose where it fails.
constexpr std::size_t kFailurePose = static_cast<std::size_t>(-1);

/// Finds a motion by "ARM:SAMPLE[:WAYPOINT]" in a plan, and the waypoint (default: the last); a
/// motion not solved by "ARM:SAMPLE" gives kFailurePose when the file keeps its failure pose.
/// @throws trocar::Error naming the text when the plan has no such motion, or a failed one
/// without a failure pose (or with a waypoint asked).
const planners::StoredMotion& FindMotion(const planners::StoredPlan& plan, const std::string& text,
                                         std::size_t* waypoint);

}  // namespace trocar::viz
