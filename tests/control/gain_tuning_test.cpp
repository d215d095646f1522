#include "control/gain_tuning.hpp"

#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

TEST(GainTuning, FindsGainsThatTrackBetterWithoutOvershoot) {
  const auto model = robot::LoadRobot(test::SourcePath("robots/pa10/pa10.yaml"));
  control::GainTuningOptions options;
  options.duration = 4.0;
  options.max_evaluations = 40;
  const auto first = control::TuneGains(model, model.defaults().home, options);
  EXPECT_LT(first.rms_position_error, 0.5 * first.initial_rms_position_error);
  EXPECT_LE(first.overshoot, options.max_overshoot);
  EXPECT_GT(first.evaluations, 5);
  // Deterministic: the same options give the same gains.
  const auto second = control::TuneGains(model, model.defaults().home, options);
  EXPECT_EQ(first.gains, second.gains);
  options.controller = "pid";
  EXPECT_THROW(control::TuneGains(model, model.defaults().home, options), Error);
}

// Tuned gains go to an overlay beside the robot (issue #18): the user's own files stay byte for
// byte, the values come back at full precision, other controllers' entries are kept.
TEST(GainTuning, SavesIntoAnOverlayNeverTheUsersOwnFile) {
  const std::string dir = ::testing::TempDir() + "/trocar_tune_save";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  const std::string yaml = dir + "/pa10.yaml";
  std::filesystem::copy_file(test::SourcePath("robots/pa10/pa10.yaml"), yaml);
  const std::string original = ReadTextFile(yaml);
  const control::Vector6d gains =
      (control::Vector6d() << 44.123456789012345, 44.2, 44.2, 491.5, 491.5, 1.0 / 3.0).finished();
  EXPECT_EQ(control::SaveControllerGains(yaml, "jt", gains), dir + "/pa10.gains.yaml");
  EXPECT_EQ(control::SaveControllerGains(yaml, "jt", gains), dir + "/pa10.gains.yaml");
  const control::Vector6d other = control::Vector6d::Constant(7.0);
  control::SaveControllerGains(yaml, "dls", other);
  EXPECT_EQ(ReadTextFile(yaml), original);
  const auto model = robot::LoadRobot(yaml);
  ASSERT_EQ(model.defaults().controller.gains.count("jt"), 1u);
  EXPECT_EQ(model.defaults().controller.gains.at("jt"), Eigen::VectorXd(gains));  // exact: 17 digits
  EXPECT_EQ(model.defaults().controller.gains.at("dls"), Eigen::VectorXd(other));
  EXPECT_EQ(model.defaults().controller.task_gains.size(), 6);  // the description's own, untouched
  const std::string text = ReadTextFile(dir + "/pa10.gains.yaml");
  EXPECT_EQ(text.find("jt:"), text.rfind("jt:"));  // one entry, replaced not added

  // Beside a URDF likewise: no sidecar is created.
  const std::string urdf = dir + "/arm.urdf";
  std::filesystem::copy_file(test::SourcePath("robots/pa10/pa10.urdf"), urdf);
  EXPECT_EQ(control::SaveControllerGains(urdf, "dls", gains), dir + "/arm.gains.yaml");
  EXPECT_FALSE(std::filesystem::exists(dir + "/arm.trocar.yaml"));
  EXPECT_EQ(robot::LoadRobot(urdf).defaults().controller.gains.at("dls"), Eigen::VectorXd(gains));
  // A damaged overlay is an error naming it, not ignored.
  std::ofstream(dir + "/arm.gains.yaml") << "gains: {dls: [1, 2]}\n";
  try {
    robot::LoadRobot(urdf);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("arm.gains.yaml"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("expected 6 values"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace trocar
