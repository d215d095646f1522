#include "port_placement/arms.hpp"

#include <algorithm>
#include <sstream>

#include "common/error.hpp"

namespace trocar::planners {

const char* ToString(ArmRole role) {
  return role == ArmRole::kEndoscope ? "endoscope" : "instrument";
}

namespace {

bool EndsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() &&
         s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

bool Contains(const std::string& s, const std::string& part) {
  return s.find(part) != std::string::npos;
}

// Links on the path from the base to `link`, base first.
std::vector<int> LinkPath(const robot::RobotModel& model, int link) {
  std::vector<int> path;
  for (int l = link; l >= 0;) {
    path.push_back(l);
    const int j = model.link(l).parent_joint;
    l = j >= 0 ? model.joint(j).parent_link : -1;
  }
  std::reverse(path.begin(), path.end());
  return path;
}

std::vector<int> ArmQIndices(const robot::RobotModel& model, int tool_link) {
  std::vector<int> q;
  for (int j : model.movable_path(tool_link)) {
    if (model.joint(j).drive == robot::JointDrive::kActive) q.push_back(model.joint(j).q_index);
  }
  return q;
}

// The slenderest long capsule or cylinder on the links from the base to `tool_link`: the shaft.
bool FindShaft(const robot::RobotModel& model, int tool_link, PlanArm* arm) {
  double best = 0.0;
  for (int l : LinkPath(model, tool_link)) {
    for (const auto& g : model.link(l).collisions) {
      if (g.shape != robot::Geometry::Shape::kCapsule &&
          g.shape != robot::Geometry::Shape::kCylinder)
        continue;
      const double radius = g.size.x(), length = g.size.y();
      if (radius > 0.010 || length < 15 * radius) continue;
      const double slenderness = length / radius;
      if (slenderness <= best) continue;
      best = slenderness;
      arm->shaft_link = l;
      const Eigen::Vector3d axis = g.X_LG.linear().col(2);
      arm->p_L_shaft_a = g.X_LG.translation() - 0.5 * length * axis;
      arm->p_L_shaft_b = g.X_LG.translation() + 0.5 * length * axis;
    }
  }
  return best > 0.0;
}

int InsertionQ(const robot::RobotModel& model, int rcm_link, int tool_link) {
  const std::vector<int>& path = model.movable_path(tool_link);
  for (int j : path) {
    const robot::Joint& joint = model.joint(j);
    // below the RCM: its parent link is the RCM's link or a descendant of it
    const std::vector<int> above = LinkPath(model, joint.parent_link);
    if (std::find(above.begin(), above.end(), rcm_link) == above.end()) continue;
    if (joint.type == robot::JointType::kPrismatic && joint.drive == robot::JointDrive::kActive)
      return joint.q_index;
  }
  return -1;
}

}  // namespace

std::vector<PlanArm> FindArms(const robot::RobotModel& robot,
                              const std::vector<std::string>& roles) {
  std::vector<PlanArm> arms;
  const auto& frames = robot.frames();
  auto find_frame = [&](const std::string& name) -> const robot::Frame* {
    for (const auto& f : frames) {
      if (f.name == name) return &f;
    }
    return nullptr;
  };
  for (const auto& f : frames) {
    if (!EndsWith(f.name, "rcm")) continue;
    PlanArm arm;
    const std::string prefix = f.name.substr(0, f.name.size() - 3);
    arm.name = prefix.empty()
                   ? robot.name()
                   : (EndsWith(prefix, "_") ? prefix.substr(0, prefix.size() - 1) : prefix);
    arm.rcm_frame = f.name;
    const robot::Frame* tool = prefix.empty() ? &robot.tool_frame() : find_frame(prefix + "tool");
    TROCAR_THROW_UNLESS(tool, "robot '" << robot.name() << "': RCM frame '" << f.name
                                        << "' has no tool frame '" << prefix << "tool' beside it");
    arm.tool_frame = tool->name;
    arm.q_indices = ArmQIndices(robot, tool->link);
    TROCAR_THROW_UNLESS(!arm.q_indices.empty(), "robot '" << robot.name() << "': tool frame '"
                                                          << tool->name
                                                          << "' is moved by no active joint");
    arm.insertion_q = InsertionQ(robot, f.link, tool->link);
    bool camera =
        Contains(prefix, "ecm") || Contains(prefix, "endoscope") || Contains(prefix, "camera");
    for (const auto& other : frames) {
      if (other.name.rfind(prefix, 0) == 0 && Contains(other.name.substr(prefix.size()), "camera"))
        camera = true;
    }
    arm.role = camera ? ArmRole::kEndoscope : ArmRole::kInstrument;
    arm.view_frames = {tool->name};
    for (const auto& other : frames) {
      if (other.name != tool->name && other.name.rfind(prefix, 0) == 0 &&
          Contains(other.name.substr(prefix.size()), "camera"))
        arm.view_frames.push_back(other.name);
    }
    FindShaft(robot, tool->link, &arm);
    arms.push_back(std::move(arm));
  }
  if (arms.empty()) {
    PlanArm arm;
    arm.name = robot.name();
    arm.tool_frame = robot.tool_frame().name;
    arm.q_indices = ArmQIndices(robot, robot.tool_frame().link);
    arm.view_frames = {arm.tool_frame};
    TROCAR_THROW_UNLESS(!arm.q_indices.empty(), "robot '" << robot.name() << "': its tool frame '"
                                                          << robot.tool_frame().name
                                                          << "' is moved by no active joint");
    TROCAR_THROW_UNLESS(
        FindShaft(robot, robot.tool_frame().link, &arm),
        "robot '" << robot.name()
                  << "' has no RCM frame and no instrument shaft (a capsule or "
                     "cylinder of radius <= 10 mm, at least 15 radii long, on the tool's links): "
                     "add an `rcm:` frame or a shaft collision shape to its description");
    arms.push_back(std::move(arm));
  }
  // The stand-alone robot's `rcm` and a cart's `tool` frame name the first arm again: keep one
  // arm per tool frame.
  std::vector<PlanArm> unique;
  for (auto& a : arms) {
    const bool dup = std::any_of(unique.begin(), unique.end(),
                                 [&](const PlanArm& u) { return u.tool_frame == a.tool_frame; });
    if (!dup) unique.push_back(std::move(a));
  }
  for (const std::string& spec : roles) {
    const auto eq = spec.find('=');
    TROCAR_THROW_UNLESS(eq != std::string::npos,
                        "arm role '" << spec << "': expected NAME=instrument|endoscope");
    const std::string name = spec.substr(0, eq), role = spec.substr(eq + 1);
    TROCAR_THROW_UNLESS(
        role == "instrument" || role == "endoscope",
        "arm role '" << spec << "': '" << role << "' is not instrument or endoscope");
    bool found = false;
    for (auto& a : unique) {
      if (a.name == name || a.rcm_frame == name) {
        a.role = role == "endoscope" ? ArmRole::kEndoscope : ArmRole::kInstrument;
        found = true;
      }
    }
    if (!found) unique = SelectArms(unique, {name});  // throws, listing the arms
  }
  return unique;
}

std::vector<PlanArm> SelectArms(const std::vector<PlanArm>& arms,
                                const std::vector<std::string>& names) {
  std::vector<PlanArm> selected;
  for (const std::string& name : names) {
    auto it = std::find_if(arms.begin(), arms.end(),
                           [&](const PlanArm& a) { return a.name == name || a.rcm_frame == name; });
    if (it == arms.end()) {
      std::ostringstream known;
      for (const auto& a : arms) known << (known.tellp() > 0 ? ", " : "") << a.name;
      TROCAR_THROW("no arm '" << name << "' (the robot's arms: " << known.str() << ")");
    }
    selected.push_back(*it);
  }
  return selected;
}

}  // namespace trocar::planners
