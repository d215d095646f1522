#include "control/teleop_setup.hpp"

#include <iomanip>
#include <sstream>

#include "common/error.hpp"
#include "control/gain_tuning.hpp"
#include "control/joint_limits.hpp"

namespace trocar::control {

std::vector<ChosenArm> ChooseSessionArms(const DeviceConfig* devices,
                                         const std::vector<OfferedArm>* plan_arms,
                                         const std::string& plan_source,
                                         const std::string& requested) {
  std::vector<ChosenArm> chosen;
  TROCAR_THROW_UNLESS(devices == nullptr || requested.empty(),
                      devices->path << " names the arms its devices drive: arm '" << requested
                                    << "' cannot be named beside it");
  if (devices != nullptr) {
    for (const DeviceBinding& b : devices->devices) {
      if (!b.pointer) chosen.push_back({b.arm, b.arm, &b});
    }
    TROCAR_THROW_UNLESS(!chosen.empty(),
                        devices->path << ": no device drives an arm (only pointers)");
  }
  if (plan_arms == nullptr) {
    TROCAR_THROW_UNLESS(requested.empty(), "arm '" << requested
                                                   << "': an arm is named among a plan's arms; "
                                                      "without a plan the robot's tool is driven");
    if (chosen.empty()) chosen.push_back({"tool", "tool", nullptr});
    return chosen;  // a robot's arms are its frames
  }
  std::string names;
  for (const OfferedArm& a : *plan_arms) names += (names.empty() ? "" : ", ") + a.name;
  if (devices == nullptr) {
    const OfferedArm* arm = nullptr;
    for (const OfferedArm& a : *plan_arms) {
      if ((requested.empty() && a.role == "instrument" && arm == nullptr) || a.name == requested)
        arm = &a;
    }
    TROCAR_THROW_UNLESS(arm != nullptr, plan_source
                                            << ": no "
                                            << (requested.empty() ? std::string("instrument arm")
                                                                  : "arm '" + requested + "'")
                                            << " (arms: " << names << ")");
    chosen.push_back({arm->name, arm->tool_frame, nullptr});
    return chosen;
  }
  for (ChosenArm& c : chosen) {
    const OfferedArm* arm = nullptr;
    for (const OfferedArm& a : *plan_arms) {
      if (a.name == c.name) arm = &a;
    }
    TROCAR_THROW_UNLESS(arm != nullptr, devices->path << ": device '" << c.binding->name
                                                      << "': no arm '" << c.name << "' in "
                                                      << plan_source << " (arms: " << names << ")");
    c.tool_frame = arm->tool_frame;
  }
  return chosen;
}

kinematics::StartConfiguration ChooseSessionStart(const std::vector<SessionArm>& arms) {
  TROCAR_THROW_UNLESS(!arms.empty() && arms.front().model,
                      "a session's start needs at least one arm");
  const robot::RobotModel& model = *arms.front().model;
  kinematics::StartConfiguration start = kinematics::ChooseStart(model);
  if (model.defaults().has_home()) return start;
  // Several arms: each starts where its own tool moves well, on its own joints.
  for (std::size_t i = 1; i < arms.size(); ++i) {
    TROCAR_THROW_UNLESS(
        arms[i].model && arms[i].model->num_positions() == model.num_positions(),
        "arm '" << arms[i].name << "' is not an arm of robot '" << model.name() << "'");
    const kinematics::StartConfiguration own = kinematics::ChooseStart(*arms[i].model);
    for (int k : arms[i].positions) start.q[k] = own.q[k];
    for (const std::string& w : own.warnings) start.warnings.push_back(arms[i].name + ": " + w);
  }
  return start;
}

SessionGains GainsForSession(const robot::RobotModel& model, const Eigen::VectorXd& q0,
                             const std::string& controller, const std::string& description) {
  SessionGains out;
  if (controller != "jt" || model.defaults().controller.gains.count("jt") != 0 ||
      model.defaults().controller.task_gains.size() != 0)
    return out;
  GainTuningOptions tuning;
  tuning.controller = "jt";
  out.gains = TuneGains(model, q0, tuning).gains;
  out.tuned = true;
  try {
    out.saved = "saved to " + SaveControllerGains(description, "jt", out.gains);
  } catch (const Error& e) {
    out.saved = std::string("not saved: ") + e.what();
  }
  return out;
}

std::string InputSpeedWarning(const robot::RobotModel& model, const robot::RobotState& state,
                              DeviceInput* input, double duration, const TeleopOptions& mapping) {
  const auto V_W = ToolVelocities(input, duration, 0.01, mapping);
  const VelocityDemand demand = JointVelocityDemand(model, state, V_W, mapping.position_only);
  if (demand.share <= 1.0) return "";
  const robot::Joint& joint = model.joint(model.active_joints()[demand.joint]);
  const bool prismatic = joint.type == robot::JointType::kPrismatic;
  const char* unit = prismatic ? " m/s" : " rad/s";
  std::ostringstream w;
  w << std::setprecision(3) << "the input moves the tool at up to " << demand.peak_tool_speed
    << " m/s; from the start, joint '" << joint.name << "' would need " << demand.rate << unit
    << ", over its velocity limit of " << joint.limits.velocity << unit
    << ": the tool will lag (a smaller amplitude, a larger motion scale, or a start where the "
       "joints need less speed)";
  return w.str();
}

}  // namespace trocar::control
