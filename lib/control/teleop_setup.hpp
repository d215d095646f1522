#pragma once
/// @file
/// What a teleoperation session settles before it starts, for any front end (the command, the
/// workstation, a test): where the arms start, the gains of a controller the robot gives none
/// for, and whether a known input asks the joints for more speed than their limits give. The
/// session itself is teleop_session.hpp; the front end parses, calls these and prints.

#include <Eigen/Core>
#include <memory>
#include <string>
#include <vector>

#include "control/device_config.hpp"
#include "control/device_input.hpp"
#include "control/task_error.hpp"
#include "control/teleop.hpp"
#include "kinematics/start_configuration.hpp"
#include "robot/robot_model.hpp"
#include "robot/robot_state.hpp"

namespace trocar::control {

/// One arm a session drives: the robot with its tool at the arm's tool frame, and the joints the
/// arm moves (indices into q; empty: the whole robot, as when one arm is driven).
struct SessionArm {
  std::string name;
  std::shared_ptr<const robot::RobotModel> model;
  std::vector<int> positions;
};

/// An arm a front end offers to drive: an arm of a plan (its name, its tool frame, its role:
/// "instrument", "endoscope").
struct OfferedArm {
  std::string name;
  std::string tool_frame;
  std::string role;
};

/// An arm a session drives: its name, the robot frame its tool is at, and the device of a
/// device file that drives it (nullptr: the session's one input).
struct ChosenArm {
  std::string name;
  std::string tool_frame;
  const DeviceBinding* binding = nullptr;
};

/// Which arms a session drives, for any front end:
/// - with a device file (`devices`), the arm of each device that is not a pointer, in the file's
///   order;
/// - without one, the arm named `requested`, or, when none is named, the plan's first instrument
///   (or, without a plan, the robot's own tool, named "tool").
/// `plan_arms` are the arms of the plan the session drives (nullptr: a robot without a plan,
/// whose arms are frames of the robot: a device's arm names the frame, and its tool is there);
/// `plan_source` names the plan in messages. @throws trocar::Error naming the device file and
/// device, or the plan, the arm asked for and the arms there are: a file whose devices are all
/// pointers, an arm the plan does not have, an arm named without a plan.
std::vector<ChosenArm> ChooseSessionArms(const DeviceConfig* devices,
                                         const std::vector<OfferedArm>* plan_arms,
                                         const std::string& plan_source,
                                         const std::string& requested);

/// Where a session starts when nothing else sets it: the robot's declared home, or a pose chosen
/// away from limits and singularities for the first arm's tool (kinematics::ChooseStart); with
/// several arms and no home, each further arm's own joints from a start chosen for its own tool,
/// its warnings named by the arm. Every arm's model is one robot (the same joints in the same
/// order). @throws trocar::Error when `arms` is empty.
kinematics::StartConfiguration ChooseSessionStart(const std::vector<SessionArm>& arms);

/// The fallback gains of a session's controller ([ωx ωy ωz vx vy vz], 1/s) and how they came.
struct SessionGains {
  Vector6d gains = (Vector6d() << 20, 20, 20, 40, 40, 40).finished();
  bool tuned = false;  ///< tuned now (below)
  /// When tuned: "saved to FILE" (the overlay beside the robot's description), or "not saved:
  /// WHY" (the session goes on with them).
  std::string saved;
};

/// Jacobian transpose needs gains fitted to the robot (thesis §6.3.2): for `controller` "jt" on
/// a robot that gives none (neither `controller.gains.jt` nor task gains), the gains are tuned
/// from `q0` (TuneGains) and saved beside `description` for the next sessions; any other case
/// keeps the default fallback. @throws trocar::Error from the tuning (bad model or start).
SessionGains GainsForSession(const robot::RobotModel& model, const Eigen::VectorXd& q0,
                             const std::string& controller, const std::string& description);

/// A known input (scripted or recorded, `input` fresh: it is read from its start) driven
/// through `mapping` for `duration` s: does it ask the joints of `model`, at `state` (forward
/// kinematics done), for more speed than their limits give? Sampled every 10 ms; a first-order
/// estimate at the start (JointVelocityDemand). @returns "" when within the limits, else a
/// warning naming the joint, the rate it needs and its limit, and what lowers the demand.
std::string InputSpeedWarning(const robot::RobotModel& model, const robot::RobotState& state,
                              DeviceInput* input, double duration, const TeleopOptions& mapping);

}  // namespace trocar::control
