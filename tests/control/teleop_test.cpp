#include <filesystem>
#include <fstream>
#include <random>

#include <gtest/gtest.h>

#include "common/error.hpp"
#include "control/control_loop.hpp"
#include "control/device_input.hpp"
#include "control/teleop.hpp"
#include "control/teleop_session.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

using control::DeviceSample;
using control::SampleStatus;
using control::TeleopMapping;
using control::TeleopOptions;

Eigen::Isometry3d Pose(const Eigen::Vector3d& p, double angle = 0.0,
                       const Eigen::Vector3d& axis = Eigen::Vector3d::UnitZ()) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = p;
  X.linear() = Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
  return X;
}

DeviceSample Sample(double t, const Eigen::Isometry3d& X, bool clutch = false, bool present = true) {
  DeviceSample s;
  s.t = t;
  s.X_DH = X;
  s.clutch = clutch;
  s.operator_present = present;
  return s;
}

const Eigen::Isometry3d kTool = Pose({0.4, -0.1, 0.9}, 0.7, {1, 1, 0});

TEST(TeleopMapping, ScalesTranslationByTheRatio) {
  for (double scale : {1.0, 2.0, 3.0, 5.0, 7.5}) {
    TeleopOptions options;
    options.scale = scale;
    options.max_jump = 1.0;
    TeleopMapping mapping(options, kTool);
    mapping.Update(Sample(0.0, Pose({0.1, 0.2, 0.3})));
    mapping.Update(Sample(0.01, Pose({0.13, 0.18, 0.34})));
    EXPECT_TRUE(test::CompareMatrices(mapping.desired().translation() - kTool.translation(),
                                      Eigen::Vector3d(0.03, -0.02, 0.04) / scale, 1e-15));
    EXPECT_TRUE(test::CompareMatrices(mapping.desired().linear(), kTool.linear(), 1e-15));
  }
}

TEST(TeleopMapping, RotatesTheToolByTheHandsRelativeRotation) {
  TeleopMapping mapping(TeleopOptions{}, kTool);
  const Eigen::Isometry3d start = Pose({0, 0, 0}, 0.3, {0, 1, 0});
  mapping.Update(Sample(0.0, start));
  const Eigen::Matrix3d turn = Eigen::AngleAxisd(0.5, Eigen::Vector3d(1, -1, 2).normalized()).toRotationMatrix();
  Eigen::Isometry3d moved = start;
  moved.linear() = turn * start.linear();
  mapping.Update(Sample(0.01, moved));
  EXPECT_TRUE(test::CompareMatrices(mapping.desired().linear(), turn * kTool.linear(), 1e-12));
}

TEST(TeleopMapping, ReadsTheHandInTheCameraFrame) {
  TeleopOptions options;
  options.R_WC = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  TeleopMapping mapping(options, kTool);
  mapping.Update(Sample(0.0, Pose({0, 0, 0})));
  mapping.Update(Sample(0.01, Pose({0.01, 0, 0})));  // hand moves along the camera's x
  EXPECT_TRUE(test::CompareMatrices(mapping.desired().translation() - kTool.translation(),
                                    Eigen::Vector3d(0, 0.01, 0), 1e-15));
}

TEST(TeleopMapping, ClutchInAndOutDoesNotMoveTheTool) {
  std::mt19937 rng(1);
  std::normal_distribution<double> g(0, 0.01);
  for (int trial = 0; trial < 100; ++trial) {
    TeleopOptions options;
    options.scale = 1.0 + trial % 5;
    TeleopMapping mapping(options, kTool);
    Eigen::Vector3d p(0, 0, 0);
    double t = 0;
    for (int k = 0; k < 20; ++k) mapping.Update(Sample(t += 0.001, Pose(p += Eigen::Vector3d(g(rng), g(rng), g(rng)) * 0.1)));
    const Eigen::Isometry3d before = mapping.desired();
    // Clutch in, move the hand a lot (and turn it), clutch out.
    for (int k = 0; k < 20; ++k) {
      EXPECT_EQ(mapping.Update(Sample(t += 0.001, Pose(p += Eigen::Vector3d(g(rng), g(rng), g(rng)), 0.02 * k), true)),
                SampleStatus::kHeldClutch);
    }
    EXPECT_EQ(mapping.Update(Sample(t += 0.001, Pose(p, 0.4))), SampleStatus::kFollowing);
    EXPECT_LT((mapping.desired().translation() - before.translation()).norm(), 1e-9);
    EXPECT_LT(control::AngleBetween(mapping.desired().linear(), before.linear()), 1e-9);
    // And it follows again from there.
    mapping.Update(Sample(t += 0.001, Pose(p + Eigen::Vector3d(0.005, 0, 0), 0.4)));
    EXPECT_NEAR((mapping.desired().translation() - before.translation()).norm(), 0.005 / options.scale, 1e-12);
  }
}

TEST(TeleopMapping, OperatorAwayHoldsTheTool) {
  TeleopMapping mapping(TeleopOptions{}, kTool);
  mapping.Update(Sample(0.0, Pose({0, 0, 0})));
  EXPECT_EQ(mapping.Update(Sample(0.01, Pose({0.03, 0, 0}), false, false)), SampleStatus::kHeldAbsent);
  EXPECT_TRUE(test::CompareMatrices(mapping.desired().matrix(), kTool.matrix(), 0.0));
  EXPECT_EQ(mapping.Update(Sample(0.02, Pose({0.04, 0, 0}))), SampleStatus::kFollowing);
  EXPECT_TRUE(test::CompareMatrices(mapping.desired().matrix(), kTool.matrix(), 1e-15));
}

TEST(TeleopMapping, DropsNonFiniteSamplesAndHolds) {
  TeleopMapping mapping(TeleopOptions{}, kTool);
  mapping.Update(Sample(0.0, Pose({0, 0, 0})));
  mapping.Update(Sample(0.01, Pose({0.01, 0, 0})));
  const Eigen::Isometry3d held = mapping.desired();
  for (double bad : {NAN, INFINITY, -INFINITY}) {
    Eigen::Isometry3d X = Pose({0.02, 0, 0});
    X.translation().y() = bad;
    EXPECT_EQ(mapping.Update(Sample(0.02, X)), SampleStatus::kDroppedNonFinite);
    X = Pose({0.02, 0, 0});
    X.linear()(1, 1) = bad;
    EXPECT_EQ(mapping.Update(Sample(0.02, X)), SampleStatus::kDroppedNonFinite);
    EXPECT_EQ(mapping.Update(Sample(bad, Pose({0.02, 0, 0}))), SampleStatus::kDroppedNonFinite);
    EXPECT_TRUE(test::CompareMatrices(mapping.desired().matrix(), held.matrix(), 0.0));
  }
}

TEST(TeleopMapping, DropsJumpsThenReanchorsIfTheHandReallyMoved) {
  TeleopOptions options;
  options.max_jump = 0.02;
  options.reanchor_after_drops = 10;
  TeleopMapping mapping(options, kTool);
  mapping.Update(Sample(0.0, Pose({0, 0, 0})));
  const Eigen::Isometry3d held = mapping.desired();
  EXPECT_EQ(mapping.Update(Sample(0.001, Pose({0.5, 0, 0}))), SampleStatus::kDroppedJump);
  EXPECT_EQ(mapping.Update(Sample(0.002, Pose({0.001, 0, 0}))), SampleStatus::kFollowing);
  for (int k = 0; k < 9; ++k) {
    EXPECT_EQ(mapping.Update(Sample(0.003 + k * 1e-3, Pose({0.5, 0, 0}))), SampleStatus::kDroppedJump);
  }
  // The tenth in a row: the hand is there now; take it from here without a jump.
  const Eigen::Isometry3d before = mapping.desired();
  EXPECT_EQ(mapping.Update(Sample(0.02, Pose({0.5, 0, 0}))), SampleStatus::kFollowing);
  EXPECT_LT((mapping.desired().translation() - before.translation()).norm(), 1e-12);
  (void)held;
}

TEST(TeleopMapping, TremorFiltersAttenuateTremorAndFollowMotion) {
  // A slow 0.2 Hz sweep of 40 mm plus a 10 Hz, 1 mm tremor, sampled at 1 kHz. The tremor left
  // after filtering is the difference from the same filter fed the sweep alone.
  for (auto filter : {control::TremorFilter::kLowPass, control::TremorFilter::kOneEuro}) {
    SCOPED_TRACE(control::ToString(filter));
    TeleopOptions options;
    options.filter = filter;
    TeleopMapping with_tremor(options, Eigen::Isometry3d::Identity());
    TeleopMapping without(options, Eigen::Isometry3d::Identity());
    double tremor_left = 0.0, lag = 0.0;
    for (int k = 0; k <= 10000; ++k) {
      const double t = k * 1e-3;
      const double slow = 0.04 * std::sin(2 * M_PI * 0.2 * t);
      const double tremor = 0.001 * std::sin(2 * M_PI * 10 * t);
      with_tremor.Update(Sample(t, Pose({slow + tremor, 0, 0})));
      without.Update(Sample(t, Pose({slow, 0, 0})));
      if (t > 2.0) {
        const double x = with_tremor.desired().translation().x();
        tremor_left = std::max(tremor_left, std::abs(x - without.desired().translation().x()));
        lag = std::max(lag, std::abs(without.desired().translation().x() - slow));
      }
    }
    EXPECT_LT(tremor_left, 0.0006);  // the 1 mm tremor at least 40% smaller
    EXPECT_LT(lag, 0.0025);          // the slow motion followed within 2.5 mm
  }
}

// A handle moving at a constant velocity and turning at a constant rate about a fixed axis,
// with the clutch pressed between 0.4 and 0.6 s and a 10 cm jump at 0.8 s.
class SteadyInput final : public control::DeviceInput {
 public:
  std::string name() const override { return "steady"; }
  DeviceSample Sample(double t) override {
    // From 0.8 s on, the handle reads 10 cm off (a jump the mapping drops, then a steady motion).
    const Eigen::Vector3d offset = t > 0.8 ? Eigen::Vector3d(0.1, 0, 0) : Eigen::Vector3d::Zero();
    return trocar::Sample(t, Pose(offset + t * Eigen::Vector3d(0.03, -0.02, 0.01), 0.5 * t, {1, 2, 2}),
                          t > 0.4 && t < 0.6);
  }
};

// The tool velocities a device's motion asks for: the handle's, translation divided by the
// scale, both turned into the world by the camera frame; clutched samples and jumps move nothing.
TEST(TeleopMapping, ToolVelocitiesAreTheHandlesScaledAndReadInTheCameraFrame) {
  TeleopOptions options;
  options.scale = 5.0;
  options.R_WC = Eigen::AngleAxisd(0.9, Eigen::Vector3d(0.3, -1, 0.5).normalized()).toRotationMatrix();
  SteadyInput input;
  const auto V = control::ToolVelocities(&input, 1.0, 0.01, options);
  // 100 pairs of samples 0.01 s apart; those at 0.41–0.59 s are clutched: the 20 pairs touching
  // them are left out, and so is the one across the jump.
  EXPECT_EQ(V.size(), 79u);
  const Eigen::Vector3d v = options.R_WC * Eigen::Vector3d(0.03, -0.02, 0.01) / 5.0;
  const Eigen::Vector3d w = options.R_WC * (0.5 * Eigen::Vector3d(1, 2, 2).normalized());
  for (const auto& V_W : V) {
    EXPECT_LT((V_W.tail<3>() - v).norm(), 1e-12);
    EXPECT_LT((V_W.head<3>() - w).norm(), 1e-9);
  }
  options.position_only = true;
  SteadyInput again;
  for (const auto& V_W : control::ToolVelocities(&again, 1.0, 0.01, options)) EXPECT_EQ(V_W.head<3>().norm(), 0.0);
}

TEST(TeleopMapping, RefusesBadOptions) {
  TeleopOptions options;
  options.scale = 0.0;
  EXPECT_THROW(TeleopMapping(options, kTool), Error);
  options.scale = NAN;
  EXPECT_THROW(TeleopMapping(options, kTool), Error);
  // Not a scaling a hand can drive (#44 item 3): 1e-300 ran to infinite errors.
  for (double scale : {1e-300, 0.009, 101.0, 1e300}) {
    options.scale = scale;
    EXPECT_THROW(TeleopMapping(options, kTool), Error) << scale;
  }
  for (double scale : {0.01, 0.2, 100.0}) {
    options.scale = scale;
    EXPECT_NO_THROW(TeleopMapping(options, kTool)) << scale;
  }
  EXPECT_THROW(control::ParseTremorFilter("kalman"), Error);
}

class DeviceCsv : public ::testing::Test {
 protected:
  std::string Write(const std::string& text) {
    const std::string path = ::testing::TempDir() + "/trocar_device_" +
                             ::testing::UnitTest::GetInstance()->current_test_info()->name() + ".csv";
    std::ofstream(path) << text;
    return path;
  }
};

TEST_F(DeviceCsv, RoundTripsAndHoldsBetweenRows) {
  std::vector<DeviceSample> samples;
  for (int k = 0; k < 5; ++k) {
    samples.push_back(Sample(0.1 * k, Pose({0.01 * k, -0.02 * k, 0.3}, 0.1 * k, {0, 1, 0}), k == 2, k != 3));
  }
  const std::string path = ::testing::TempDir() + "/trocar_device_roundtrip.csv";
  control::WriteDeviceCsv(path, samples);
  control::CsvReplayInput input(path);
  ASSERT_EQ(input.samples().size(), samples.size());
  for (std::size_t k = 0; k < samples.size(); ++k) {
    EXPECT_TRUE(test::CompareMatrices(input.samples()[k].X_DH.matrix(), samples[k].X_DH.matrix(), 1e-10));
    EXPECT_EQ(input.samples()[k].clutch, samples[k].clutch);
    EXPECT_EQ(input.samples()[k].operator_present, samples[k].operator_present);
  }
  EXPECT_TRUE(test::CompareMatrices(input.Sample(0.25).X_DH.matrix(), samples[2].X_DH.matrix(), 1e-10));
}

TEST_F(DeviceCsv, MalformedLineNamesLineAndColumn) {
  const std::string path = Write("t,x,y,z,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n0.001,abc,0,0,1,0,0,0\n");
  try {
    control::CsvReplayInput input(path);
    FAIL() << "accepted";
  } catch (const Error& e) {
    EXPECT_EQ(std::string(e.what()), path + ":3: column 2 ('x'): 'abc' is not a number");
  }
  const std::string short_row = Write("t,x,y,z,qw,qx,qy,qz\n0,0,0,0,1,0,0\n");
  EXPECT_THROW(control::CsvReplayInput{short_row}, Error);
  const std::string header = Write("time,x,y,z,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n");
  EXPECT_THROW(control::CsvReplayInput{header}, Error);
  const std::string backwards = Write("t,x,y,z,qw,qx,qy,qz\n1,0,0,0,1,0,0,0\n0.5,0,0,0,1,0,0,0\n");
  EXPECT_THROW(control::CsvReplayInput{backwards}, Error);
}

TEST_F(DeviceCsv, NanInTheStreamIsDroppedAndMarkedNotAnError) {
  const std::string path = Write("t,x,y,z,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n0.001,nan,0,0,1,0,0,0\n0.002,0.001,0,0,1,0,0,0\n");
  control::CsvReplayInput input(path);
  const auto model = robot::LoadRobot(test::SourcePath("robots/pa10/pa10.yaml"));
  control::ControlLoop loop(model, control::MakeController("dls", model, control::Vector6d::Constant(20)),
                            model.defaults().home);
  control::TeleopSessionOptions options;
  options.duration = 0.003;
  const auto recorder = control::RunTeleopSession(&loop, &input, options);
  ASSERT_EQ(recorder.rows().size(), 4u);
  EXPECT_EQ(recorder.rows()[1].status, SampleStatus::kDroppedNonFinite);
  EXPECT_EQ(recorder.Summarize().dropped, 1);
  EXPECT_EQ(recorder.rows()[2].status, SampleStatus::kFollowing);
}

TEST(TeleopSession, StepSettlesAndRunsAreDeterministic) {
  const auto model = robot::LoadRobot(test::SourcePath("robots/davinci-classic/psm.yaml"));
  control::ScriptedMotion motion;
  motion.kind = control::ScriptedMotion::Kind::kStep;
  control::TeleopSessionOptions options;
  options.duration = 2.0;
  options.mapping.scale = 5.0;
  std::vector<control::Recorder> runs;
  for (int run = 0; run < 2; ++run) {
    control::ControlLoop loop(model, control::MakeController("dls", model, control::Vector6d::Constant(20)),
                              model.defaults().home);
    control::ScriptedInput input(motion);
    runs.push_back(control::RunTeleopSession(&loop, &input, options));
  }
  const auto summary = runs[0].Summarize(motion.step_time);
  ASSERT_TRUE(summary.settling_time.has_value());
  EXPECT_LT(*summary.settling_time, 1.0);
  EXPECT_LT(runs[0].rows().back().position_error, 1e-4);
  ASSERT_EQ(runs[0].rows().size(), runs[1].rows().size());
  for (std::size_t k = 0; k < runs[0].rows().size(); ++k) {
    ASSERT_EQ(runs[0].rows()[k].q, runs[1].rows()[k].q) << k;
  }
}

}  // namespace
}  // namespace trocar
