// What a session settles before it starts (control/teleop_setup.hpp): the arms' start, the
// gains of a controller the robot gives none for, the speed a known input asks of the joints.
#include "control/teleop_setup.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <functional>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "control/control_loop.hpp"
#include "control/controller.hpp"
#include "control/teleop_session.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "kinematics/start_configuration.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

/// The cart with its tool at `frame`, as a session arm moving that tool's joints.
control::SessionArm SetupCartArm(const std::string& frame) {
  const auto builder =
      robot::LoadRobotDescription(test::SourcePath("robots/davinci-classic/cart.yaml"));
  const robot::RobotModel plain = builder.Build();
  const robot::Frame& f = plain.GetFrame(frame);
  robot::RobotModelBuilder b = builder;
  b.SetTool({frame + "_teleop", plain.link(f.link).name, f.X_LF});
  auto model = std::make_shared<const robot::RobotModel>(b.Build());
  return {frame, model, control::ArmPositions(*model, model->tool_frame().link)};
}

std::shared_ptr<const robot::RobotModel> LoadSetupRobot(const std::string& file) {
  return std::make_shared<const robot::RobotModel>(robot::LoadRobot(file));
}

// One arm starts where kinematics::ChooseStart puts its tool; with two arms of the cart (no
// home), each arm's joints are those of the start chosen for its own tool, and the joints neither
// arm moves are the first arm's start's.
TEST(SessionStart, EachArmStartsWhereItsOwnToolMovesWell) {
  const control::SessionArm psm1 = SetupCartArm("psm1_tool"), psm2 = SetupCartArm("psm2_tool");
  ASSERT_FALSE(psm1.model->defaults().has_home());
  const kinematics::StartConfiguration own1 = kinematics::ChooseStart(*psm1.model);
  const kinematics::StartConfiguration own2 = kinematics::ChooseStart(*psm2.model);
  EXPECT_EQ(control::ChooseSessionStart({psm1}).q, own1.q);
  const kinematics::StartConfiguration both = control::ChooseSessionStart({psm1, psm2});
  ASSERT_EQ(both.q.size(), own1.q.size());
  std::vector<bool> second(both.q.size(), false);
  for (int k : psm2.positions) second[k] = true;
  int differ = 0;
  for (int k = 0; k < both.q.size(); ++k) {
    EXPECT_EQ(both.q[k], second[k] ? own2.q[k] : own1.q[k]) << k;
    differ += own1.q[k] != own2.q[k] && second[k];
  }
  EXPECT_GT(differ, 0);  // the second arm's start is its own, not the first's
  EXPECT_TRUE(kinematics::LimitViolations(*psm1.model, both.q).empty());
  // No arm, or an arm of another robot: refused.
  EXPECT_THROW(control::ChooseSessionStart({}), Error);
  control::SessionArm pa10{"pa10", LoadSetupRobot(test::SourcePath("robots/pa10/pa10.yaml")), {}};
  std::string error;
  try {
    control::ChooseSessionStart({psm1, pa10});
  } catch (const Error& e) {
    error = e.what();
  }
  EXPECT_NE(error.find("arm 'pa10' is not an arm of robot"), std::string::npos) << error;
}

// Gains are tuned only for Jacobian transpose on a robot that gives none for it.
TEST(SessionGains, TunedOnlyForJacobianTransposeOnARobotThatGivesNone) {
  const control::Vector6d fallback = (control::Vector6d() << 20, 20, 20, 40, 40, 40).finished();
  const std::string psm_file = test::SourcePath("robots/davinci-classic/psm.yaml");
  const auto psm = LoadSetupRobot(psm_file);
  const Eigen::VectorXd q_psm = kinematics::ChooseStart(*psm).q;
  for (const char* controller : {"jt", "dls", "jla"}) {  // the PSM gives its jt gains
    const control::SessionGains g = control::GainsForSession(*psm, q_psm, controller, psm_file);
    EXPECT_FALSE(g.tuned) << controller;
    EXPECT_EQ(g.gains, fallback) << controller;
    EXPECT_EQ(g.saved, "") << controller;
  }
  const std::string pa10_file = test::SourcePath("robots/pa10/pa10.urdf");
  const auto pa10 = LoadSetupRobot(pa10_file);
  const control::SessionGains dls =
      control::GainsForSession(*pa10, kinematics::ChooseStart(*pa10).q, "dls", pa10_file);
  EXPECT_FALSE(dls.tuned);
}

// A known input asks the ECM's yaw for more than its velocity limit at 1:1 (the thesis' sinusoid,
// 4 cm): the warning names the joint, the rate and the limit; at 3:1 nothing is said.
TEST(SessionSpeed, AnInputFasterThanTheJointsCanFollowIsSaidBeforeTheRun) {
  const auto ecm = LoadSetupRobot(test::SourcePath("robots/davinci-classic/ecm.yaml"));
  const kinematics::StartConfiguration start = kinematics::ChooseStart(*ecm);
  const control::ControlLoop loop(
      *ecm, control::MakeControllerWithGains("dls", control::Vector6d::Constant(20)), start.q);
  control::ScriptedMotion motion;
  motion.amplitude = 0.04;
  control::TeleopOptions mapping;
  mapping.position_only = true;  // the ECM has four joints
  control::ScriptedInput fast(motion);
  const std::string warning = control::InputSpeedWarning(*ecm, loop.state(), &fast, 10.0, mapping);
  EXPECT_NE(warning.find("joint 'outer_yaw' would need"), std::string::npos) << warning;
  EXPECT_NE(warning.find("over its velocity limit of"), std::string::npos) << warning;
  EXPECT_EQ(warning.find("--"), std::string::npos) << warning;  // options, not a command's flags
  mapping.scale = 3.0;
  control::ScriptedInput scaled(motion);
  EXPECT_EQ(control::InputSpeedWarning(*ecm, loop.state(), &scaled, 10.0, mapping), "");
}

// Which arms a session drives (ChooseSessionArms), for any front end: a device file's arms in its
// order, each at its plan arm's tool frame, its pointer driving nothing; without one, the arm
// asked for or the plan's first instrument, or the robot's tool without a plan; and every wrong
// choice refused, naming the file, the device, the arm asked for and the arms there are.
TEST(SessionArms, AreTheDeviceFilesOrTheOneAskedForOrThePlansFirstInstrument) {
  const std::vector<control::OfferedArm> plan = {{"ecm", "ecm_camera", "endoscope"},
                                                 {"psm1", "psm1_tool", "instrument"},
                                                 {"psm2", "psm2_tool", "instrument"}};
  // Without a device file.
  auto one = control::ChooseSessionArms(nullptr, &plan, "plan.json", "");
  ASSERT_EQ(one.size(), 1u);
  EXPECT_EQ(one[0].name, "psm1");  // the first instrument, not the first arm
  EXPECT_EQ(one[0].tool_frame, "psm1_tool");
  EXPECT_EQ(one[0].binding, nullptr);
  one = control::ChooseSessionArms(nullptr, &plan, "plan.json", "psm2");
  ASSERT_EQ(one.size(), 1u);
  EXPECT_EQ(one[0].tool_frame, "psm2_tool");
  one = control::ChooseSessionArms(nullptr, &plan, "plan.json", "ecm");  // any arm, asked for
  EXPECT_EQ(one.at(0).tool_frame, "ecm_camera");
  const std::string unknown =
      test::ErrorMessage([&] { control::ChooseSessionArms(nullptr, &plan, "plan.json", "psm3"); });
  EXPECT_NE(unknown.find("plan.json: no arm 'psm3' (arms: ecm, psm1, psm2)"), std::string::npos)
      << unknown;
  const std::vector<control::OfferedArm> scope_only = {{"ecm", "ecm_camera", "endoscope"}};
  const std::string no_instrument = test::ErrorMessage(
      [&] { control::ChooseSessionArms(nullptr, &scope_only, "scope.json", ""); });
  EXPECT_NE(no_instrument.find("scope.json: no instrument arm (arms: ecm)"), std::string::npos)
      << no_instrument;
  one = control::ChooseSessionArms(nullptr, nullptr, "", "");
  ASSERT_EQ(one.size(), 1u);
  EXPECT_EQ(one[0].tool_frame, "tool");  // a robot without a plan: its own tool
  EXPECT_FALSE(test::ErrorMessage([&] {
                 control::ChooseSessionArms(nullptr, nullptr, "", "psm1");
               }).empty());

  // With a device file: its arms in its order, the pointer left out, each at its plan arm's tool.
  control::DeviceConfig devices;
  devices.path = "devices.yaml";
  devices.devices = {{"right", "psm2", false}, {"pen", "", true}, {"left", "psm1", false}};
  auto two = control::ChooseSessionArms(&devices, &plan, "plan.json", "");
  ASSERT_EQ(two.size(), 2u);
  EXPECT_EQ(two[0].name, "psm2");
  EXPECT_EQ(two[0].tool_frame, "psm2_tool");
  EXPECT_EQ(two[0].binding, &devices.devices[0]);
  EXPECT_EQ(two[1].name, "psm1");
  EXPECT_EQ(two[1].binding, &devices.devices[2]);
  // Without a plan, a device's arm is a frame of the robot.
  two = control::ChooseSessionArms(&devices, nullptr, "", "");
  ASSERT_EQ(two.size(), 2u);
  EXPECT_EQ(two[1].tool_frame, "psm1");
  // An arm the plan lacks names the device; an arm beside the file, and a file of pointers only,
  // are refused.
  devices.devices[2].arm = "psm9";
  const std::string lacks =
      test::ErrorMessage([&] { control::ChooseSessionArms(&devices, &plan, "plan.json", ""); });
  EXPECT_NE(
      lacks.find("devices.yaml: device 'left': no arm 'psm9' in plan.json (arms: ecm, psm1, psm2)"),
      std::string::npos)
      << lacks;
  devices.devices[2].arm = "psm1";
  EXPECT_NE(test::ErrorMessage([&] {
              control::ChooseSessionArms(&devices, &plan, "plan.json", "psm1");
            }).find("devices.yaml names the arms"),
            std::string::npos);
  control::DeviceConfig pointers;
  pointers.path = "pointers.yaml";
  pointers.devices = {{"pen", "", true}};
  EXPECT_NE(test::ErrorMessage([&] {
              control::ChooseSessionArms(&pointers, &plan, "plan.json", "");
            }).find("pointers.yaml: no device drives an arm (only pointers)"),
            std::string::npos);
}

}  // namespace
}  // namespace trocar
