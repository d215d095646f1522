// Bring your own robot (issue #18): every link is a frame, the default tool is found on the
// chain's tip, and a robot without a home starts away from limits and singularities.
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include <gtest/gtest.h>

#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "kinematics/start_configuration.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

namespace fs = std::filesystem;

std::string WriteFile(const std::string& name, const std::string& text) {
  const std::string dir = ::testing::TempDir() + "/trocar_any_urdf";
  fs::create_directories(dir);
  const std::string path = dir + "/" + name;
  std::ofstream(path) << text;
  return path;
}

constexpr const char* kJoint =
    R"(<joint name="%s" type="%s"><parent link="%s"/><child link="%s"/><origin xyz="0 0 0.1"/>)"
    R"(<axis xyz="0 0 1"/><limit lower="-1" upper="1" velocity="1" effort="1"/>%s</joint>)";

std::string Joint(const std::string& name, const std::string& type, const std::string& parent,
                  const std::string& child, const std::string& extra = "") {
  char buffer[512];
  std::snprintf(buffer, sizeof buffer, kJoint, name.c_str(), type.c_str(), parent.c_str(),
                child.c_str(), extra.c_str());
  return buffer;
}

TEST(AnyUrdf, EveryLinkIsAFrameByItsName) {
  const robot::RobotModel model = robot::LoadRobot(test::SourcePath("robots/pa10/pa10.urdf"));
  robot::RobotState state(model);
  const Eigen::VectorXd q = (Eigen::VectorXd(7) << 0.1, -0.5, 0.3, 1.2, -0.4, -0.3, 0.1).finished();
  ASSERT_TRUE(kinematics::ForwardKinematics(model, q, &state).ok());
  for (int l = 0; l < model.num_links(); ++l) {
    const robot::Frame& frame = model.GetFrame(model.link(l).name);
    EXPECT_EQ(frame.link, l);
    EXPECT_TRUE(kinematics::FramePose(state, frame).isApprox(state.X_WL[l], 1e-12)) << model.link(l).name;
  }
  try {
    model.GetFrame("no_such_link");
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("has no frame or link 'no_such_link'"), std::string::npos) << e.what();
  }
}

// The default tool is the tip of the chain below the last active joint, followed through fixed
// and mimic joints (a gripper's jaw driven by the wrist), and stops where the chain branches.
TEST(AnyUrdf, TheDefaultToolFollowsFixedAndMimicJointsToTheTip) {
  const std::string through = WriteFile(
      "through.urdf", "<robot name=\"t\"><link name=\"base\"/><link name=\"a\"/><link name=\"jaw\"/>"
                      "<link name=\"tip\"/>" +
                          Joint("j1", "revolute", "base", "a") +
                          Joint("jaw_joint", "revolute", "a", "jaw", "<mimic joint=\"j1\"/>") +
                          Joint("tip_joint", "fixed", "jaw", "tip") + "</robot>");
  const robot::RobotModel model = robot::LoadRobot(through);
  EXPECT_EQ(model.link(model.tool_frame().link).name, "tip");
  EXPECT_NE(model.tool_basis().find("below the last active joint 'j1' through mimic 'jaw_joint', "
                                    "fixed 'tip_joint'"),
            std::string::npos)
      << model.tool_basis();
  const std::string branch = WriteFile(
      "branch.urdf", "<robot name=\"b\"><link name=\"base\"/><link name=\"a\"/><link name=\"l\"/>"
                     "<link name=\"r\"/>" +
                         Joint("j1", "revolute", "base", "a") + Joint("jl", "fixed", "a", "l") +
                         Joint("jr", "fixed", "a", "r") + "</robot>");
  const robot::RobotModel branched = robot::LoadRobot(branch);
  EXPECT_EQ(branched.link(branched.tool_frame().link).name, "a");
  EXPECT_NE(branched.tool_basis().find("the chain branches there"), std::string::npos);
}

// A URDF whose tip link is itself named `tool`, behind a fixed joint: `tool` is that link, not
// the child of the last active joint (which `--frame tool` used to give, silently).
TEST(AnyUrdf, ALinkNamedToolIsTheTool) {
  const std::string path = WriteFile(
      "named.urdf", "<robot name=\"n\"><link name=\"base\"/><link name=\"a\"/><link name=\"tool\"/>"
                    "<link name=\"camera\"/>" +
                        Joint("j1", "revolute", "base", "a") + Joint("f", "fixed", "a", "tool") +
                        Joint("c", "fixed", "a", "camera") + "</robot>");
  const robot::RobotModel model = robot::LoadRobot(path);
  EXPECT_EQ(model.tool_frame().link, model.GetLink("tool"));
  EXPECT_EQ(model.GetFrame("tool").link, model.GetLink("tool"));
  EXPECT_EQ(model.tool_basis(), "the link named 'tool'");
}

// A sidecar frame named like a link but elsewhere is an error naming both.
TEST(AnyUrdf, ASidecarFrameNamedLikeALinkIsAnError) {
  const std::string urdf = WriteFile(
      "clash.urdf", "<robot name=\"c\"><link name=\"base\"/><link name=\"a\"/>" +
                        Joint("j1", "revolute", "base", "a") + "</robot>");
  WriteFile("clash.trocar.yaml", "frames: [{name: a, link: base, xyz: [0, 0, 0.2]}]\n");
  try {
    robot::LoadRobot(urdf);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("frame 'a' (on link 'base') has the name of link 'a'"),
              std::string::npos)
        << e.what();
  }
  fs::remove(::testing::TempDir() + "/trocar_any_urdf/clash.trocar.yaml");
}

// Without a home, the start is chosen inside the limits, away from them and from singularities,
// the same every time; the PA10 as a plain URDF starts stretched straight up at q = 0 otherwise.
TEST(AnyUrdf, ARobotWithoutAHomeStartsAwayFromLimitsAndSingularities) {
  const robot::RobotModel model = robot::LoadRobot(test::SourcePath("robots/pa10/pa10.urdf"));
  ASSERT_FALSE(model.defaults().has_home());
  const kinematics::StartConfiguration a = kinematics::ChooseStart(model);
  const kinematics::StartConfiguration b = kinematics::ChooseStart(model);
  EXPECT_EQ(a.q, b.q);
  EXPECT_TRUE(kinematics::LimitViolations(model, a.q).empty());
  EXPECT_GE(a.quality.limit_margin, 0.1 - 1e-9);
  EXPECT_GT(a.quality.dexterity, 0.1);
  EXPECT_EQ(a.probe, 1.0);
  EXPECT_TRUE(a.warnings.empty());
  EXPECT_NE(a.basis.find("chosen automatically"), std::string::npos);
  // q = 0 is singular, and said so.
  const auto zero = kinematics::StartWarnings(model, Eigen::VectorXd::Zero(7), a.length);
  ASSERT_FALSE(zero.empty());
  EXPECT_NE(zero[0].find("near a singularity"), std::string::npos) << zero[0];
  EXPECT_LT(kinematics::AssessStart(model, Eigen::VectorXd::Zero(7), a.length).dexterity, 0.02);
  // A declared home is kept as it is.
  const robot::RobotModel yaml = robot::LoadRobot(test::SourcePath("robots/pa10/pa10.yaml"));
  EXPECT_EQ(kinematics::ChooseStart(yaml).q, yaml.defaults().home);
}

}  // namespace
}  // namespace trocar
