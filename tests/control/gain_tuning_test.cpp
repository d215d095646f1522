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
  const auto first = control::TuneGains(model, model.home_configuration(), options);
  EXPECT_LT(first.rms_position_error, 0.5 * first.initial_rms_position_error);
  EXPECT_LE(first.overshoot, options.max_overshoot);
  EXPECT_GT(first.evaluations, 5);
  // Deterministic: the same options give the same gains.
  const auto second = control::TuneGains(model, model.home_configuration(), options);
  EXPECT_EQ(first.gains, second.gains);
  options.controller = "pid";
  EXPECT_THROW(control::TuneGains(model, model.home_configuration(), options), Error);
}

TEST(GainTuning, SavesIntoTheSidecarKeepingTheRestOfTheFile) {
  const std::string dir = ::testing::TempDir() + "/trocar_tune_save";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  const std::string yaml = dir + "/pa10.yaml";
  std::filesystem::copy_file(test::SourcePath("robots/pa10/pa10.yaml"), yaml);
  const control::Vector6d gains = (control::Vector6d() << 44.2, 44.2, 44.2, 491.5, 491.5, 491.5).finished();
  EXPECT_EQ(control::SaveControllerGains(yaml, "jt", gains), yaml);
  EXPECT_EQ(control::SaveControllerGains(yaml, "jt", gains), yaml);  // again: replaced, not added
  const auto model = robot::LoadRobot(yaml);
  ASSERT_EQ(model.controller().gains.count("jt"), 1u);
  EXPECT_TRUE(test::CompareMatrices(model.controller().gains.at("jt"), gains, 1e-9));
  EXPECT_EQ(model.controller().task_gains.size(), 6);  // untouched
  const std::string text = ReadTextFile(yaml);
  EXPECT_NE(text.find("# Mitsubishi PA10-7C"), std::string::npos);  // comments kept
  EXPECT_EQ(text.find("jt: ["), text.rfind("jt: ["));               // one line only

  // Beside a URDF the sidecar is created.
  const std::string urdf = dir + "/arm.urdf";
  std::filesystem::copy_file(test::SourcePath("robots/pa10/pa10.urdf"), urdf);
  EXPECT_EQ(control::SaveControllerGains(urdf, "dls", gains), dir + "/arm.trocar.yaml");
  EXPECT_TRUE(test::CompareMatrices(robot::LoadRobot(urdf).controller().gains.at("dls"), gains, 1e-9));
}

}  // namespace
}  // namespace trocar
