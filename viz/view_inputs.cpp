#include "view_inputs.hpp"

#include <cmath>
#include <sstream>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "robot/load_robot.hpp"

namespace trocar::viz {

SceneStyle StyleOf(const ViewInputs& inputs) {
  SceneStyle style = SceneStyle::Default();
  for (const auto& c : inputs.colours) style.ParseColour(c);
  for (const auto& o : inputs.opacities) style.ParseOpacity(o);
  for (const auto& h : inputs.hidden) style.visible[h] = false;
  style.flat = inputs.flat;
  return style;
}

const planners::StoredMotion& FindMotion(const planners::StoredPlan& plan, const std::string& text,
                                         std::size_t* waypoint) {
  std::vector<std::string> parts;
  std::stringstream in(text);
  std::string part;
  while (std::getline(in, part, ':')) parts.push_back(part);
  auto integer = [&](const std::string& s) {
    std::size_t used = 0;
    long v = -1;
    try {
      v = std::stol(s, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    TROCAR_OPTION_UNLESS(used == s.size() && v >= 0, "motion",
                         "'" << text << "': '" << s << "' is not a whole number");
    return v;
  };
  TROCAR_OPTION_UNLESS(parts.size() == 2 || parts.size() == 3, "motion",
                       "'" << text << "': expected ARM:SAMPLE[:WAYPOINT]");
  const long sample = integer(parts[1]);
  for (const planners::StoredMotion& m : plan.motions) {
    if (m.arm != parts[0] || m.sample != sample) continue;
    if (m.waypoints.empty()) {
      // A failed motion shows the pose where it fails (issue #43 item 9), when the file has it.
      TROCAR_OPTION_UNLESS(m.failure_pose.size() > 0 && parts.size() == 2, "motion",
                           "'" << text << "': that motion was not solved (" << m.outcome << ": "
                               << m.reason << ")"
                               << (m.failure_pose.size() > 0
                                       ? "; it has no waypoints: give ARM:SAMPLE for where it fails"
                                       : " and its plan file keeps no pose where it fails"));
      *waypoint = kFailurePose;
      return m;
    }
    const long k = parts.size() == 3 ? integer(parts[2]) : static_cast<long>(m.waypoints.size()) - 1;
    TROCAR_OPTION_UNLESS(k < static_cast<long>(m.waypoints.size()), "motion",
                         "'" << text << "': the motion has " << m.waypoints.size()
                             << " waypoints (0.." << m.waypoints.size() - 1 << ")");
    *waypoint = static_cast<std::size_t>(k);
    return m;
  }
  TROCAR_OPTION_UNLESS(false, "motion",
                       "'" << text << "': the plan has no verified motion of arm '" << parts[0]
                           << "' to sample " << sample);
}

LoadedView LoadView(const ViewInputs& in) {
  LoadedView out;
  const SceneStyle style = StyleOf(in);
  TROCAR_THROW_UNLESS(!in.case_dir.empty(), "view: no case folder given");
  if (!in.plan.empty()) {
    out.plan = std::make_unique<planners::PlanFile>(planners::ReadPlanFile(in.plan));
    TROCAR_THROW_UNLESS(!out.plan->plans.empty(), in.plan << ": holds no plans");
    TROCAR_OPTION_UNLESS(
        in.plan_index >= 1 && in.plan_index <= static_cast<int>(out.plan->plans.size()),
        "plan_index",
        in.plan_index << ": " << in.plan << " holds " << out.plan->plans.size() << " plans (1.."
                      << out.plan->plans.size() << ")");
    const std::string robot_mismatch = planners::RobotFileMismatch(*out.plan);
    TROCAR_THROW_UNLESS(robot_mismatch.empty(), in.plan << ": " << robot_mismatch << ": plan again");
  }
  out.patient = patient::ImportCase(in.case_dir).model;
  if (out.plan) {
    const std::string patient_mismatch =
        planners::PatientModelMismatch(*out.plan, *out.patient, in.case_dir);
    TROCAR_THROW_UNLESS(patient_mismatch.empty(),
                        in.plan << ": " << patient_mismatch << ": view it with its own case, or plan again");
    out.robot = std::make_shared<const robot::RobotModel>(robot::LoadRobot(out.plan->robot_file));
  } else if (!in.robot.empty()) {
    out.robot = std::make_shared<const robot::RobotModel>(robot::LoadRobot(in.robot));
  }
  TROCAR_OPTION_UNLESS(in.motion.empty() || out.plan, "motion", "needs a plan file");
  TROCAR_OPTION_UNLESS(!in.reach || out.plan, "reach",
                       "needs a plan file (whose arms reach the targets)");
  out.scene = std::make_unique<Scene>(out.patient, out.robot, style);
  if (out.plan) {
    const std::size_t k = static_cast<std::size_t>(in.plan_index - 1);
    out.scene->ShowPlan(*out.plan, k);
    if (in.reach) out.scene->ShowReachability(*out.plan, k);
    int work_sample = -1;  // on a motion, its sample: the wrist may touch the organ there
    if (!in.motion.empty()) {
      std::size_t waypoint = 0;
      const planners::StoredMotion& m = FindMotion(out.plan->plans[k], in.motion, &waypoint);
      robot::RobotState state = *out.scene->robot_state();
      work_sample = m.sample;
      if (waypoint == kFailurePose) {
        planners::SetFailurePose(*out.robot, m, &state);
        out.failure = m.outcome + ": " + m.reason;
      } else {
        planners::SetWaypoint(*out.robot, m, waypoint, &state);
      }
      out.scene->SetRobotState(state);
    }
    out.collisions = std::make_unique<planners::PlanCollisions>(*out.patient, out.robot, *out.plan, k);
    out.pose = out.collisions->Check(*out.scene->robot_state(), 0.005, work_sample);
    out.scene->HighlightLinks(out.pose.colliding_links, out.pose.near_links);
  }
  return out;
}

std::string Describe(const planners::PoseCollisions& pose) {
  std::ostringstream s;
  if (pose.collision) {
    s << "in collision: ";
    for (std::size_t i = 0; i < pose.pairs.size() && i < 4; ++i) s << (i ? ", " : "") << pose.pairs[i];
    if (pose.pairs.size() > 4) s << " and " << pose.pairs.size() - 4 << " more";
  } else if (std::isfinite(pose.clearance)) {
    s.setf(std::ios::fixed);
    s.precision(1);
    s << "collision-free, clearance " << pose.clearance * 1000 << " mm (" << pose.clearance_pair << ")";
  } else {
    s << "collision-free";
  }
  return s.str();
}

}  // namespace trocar::viz
