// Issue #16: several devices at once — two arms of one robot driven independently in one
// session, a teaching pointer, device files, and the force cues sent back to the devices.
#include <filesystem>
#include <fstream>
#include <random>

#include <gtest/gtest.h>

#include "common/error.hpp"
#include "control/control_loop.hpp"
#include "control/device_config.hpp"
#include "control/device_input.hpp"
#include "control/force_feedback.hpp"
#include "control/teleop_session.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "kinematics/jacobian.hpp"
#include "kinematics/start_configuration.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

/// The cart with its tool at `frame`.
std::shared_ptr<const robot::RobotModel> CartWithTool(const std::string& frame) {
  const auto builder = robot::LoadRobotDescription(test::SourcePath("robots/davinci-classic/cart.yaml"));
  const robot::RobotModel plain = builder.Build();
  const robot::Frame& f = plain.GetFrame(frame);
  robot::RobotModelBuilder b = builder;
  b.SetTool({frame + "_teleop", plain.link(f.link).name, f.X_LF});
  return std::make_shared<const robot::RobotModel>(b.Build());
}

/// A device that never moves.
class StillInput final : public control::DeviceInput {
 public:
  std::string name() const override { return "still"; }
  control::DeviceSample Sample(double t) override {
    control::DeviceSample s;
    s.t = t;
    return s;
  }
};

struct TwoArmRun {
  std::vector<control::Recorder> records;
  control::SessionSnapshot last;
  Eigen::VectorXd q1, q2;  // each loop's own state at the end
  std::vector<int> positions1, positions2;
};

/// psm1 from a circle, psm2 from `second` (null: a still device), and a pointer from a sinusoid,
/// on the simulated clock.
TwoArmRun RunTwoArms(control::DeviceInput* second) {
  const auto psm1 = CartWithTool("psm1_tool"), psm2 = CartWithTool("psm2_tool");
  // Each arm starts where its own tool moves well (as trocar teleop starts several arms).
  Eigen::VectorXd q0 = kinematics::ChooseStart(*psm1).q;
  const Eigen::VectorXd q2 = kinematics::ChooseStart(*psm2).q;
  for (int k : control::ArmPositions(*psm2, psm2->tool_frame().link)) q0[k] = q2[k];
  const auto gains = control::Vector6d::Constant(20);
  control::ControlLoop loop1(*psm1, control::MakeController("dls", *psm1, gains), q0);
  control::ControlLoop loop2(*psm2, control::MakeController("dls", *psm2, gains), q0);
  control::ScriptedMotion circle;
  circle.kind = control::ScriptedMotion::Kind::kCircle;
  circle.amplitude = 0.02;
  control::ScriptedInput input1(circle);
  StillInput still;
  control::ScriptedMotion wave;
  wave.amplitude = 0.03;
  control::ScriptedInput pointer_input(wave);
  std::vector<control::SessionChannel> channels(3);
  channels[0].name = "psm1";
  channels[0].loop = &loop1;
  channels[0].input = &input1;
  channels[0].positions = control::ArmPositions(*psm1, psm1->tool_frame().link);
  channels[1].name = "psm2";
  channels[1].loop = &loop2;
  channels[1].input = second ? second : &still;
  channels[1].positions = control::ArmPositions(*psm2, psm2->tool_frame().link);
  channels[2].name = "pointer";
  channels[2].input = &pointer_input;
  channels[2].mapping.position_only = true;
  channels[2].mapping.scale = 2.0;
  channels[2].X_WP_start.translation() = Eigen::Vector3d(1.0, 0.0, 1.0);
  control::TripleBuffer<control::SessionSnapshot> snapshots;
  control::TeleopSessionOptions options;
  options.duration = 2.0;
  options.snapshots = &snapshots;
  TwoArmRun run;
  run.records = control::RunTeleopSession(channels, options);
  snapshots.Read(&run.last);
  run.q1 = loop1.state().q;
  run.q2 = loop2.state().q;
  run.positions1 = channels[0].positions;
  run.positions2 = channels[1].positions;
  return run;
}

TEST(MultiArmSession, TwoArmsOfOneRobotFollowTheirOwnDevicesIndependently) {
  control::ScriptedMotion sinusoid;
  sinusoid.amplitude = 0.01;
  control::ScriptedInput moving(sinusoid);
  const TwoArmRun still = RunTwoArms(nullptr), both = RunTwoArms(&moving);
  // Each arm owns the joints on its tool's path (yaw to wrist yaw; the jaw is beside the tool
  // frame), none shared.
  ASSERT_EQ(still.positions1.size(), 6u);
  ASSERT_EQ(still.positions2.size(), 6u);
  for (int k : still.positions1)
    EXPECT_EQ(std::count(still.positions2.begin(), still.positions2.end(), k), 0);
  // psm1 does exactly the same whether psm2's device moves or not.
  ASSERT_EQ(still.records[0].rows().size(), both.records[0].rows().size());
  for (std::size_t i = 0; i < still.records[0].rows().size(); ++i)
    ASSERT_LT((still.records[0].rows()[i].X_WT.translation() - both.records[0].rows()[i].X_WT.translation()).norm(),
              1e-12)
        << "psm1 moved differently when psm2's device moved, at step " << i;
  // psm2 holds still with a still device, and follows its own when it moves.
  const auto& rows2 = still.records[1].rows();
  for (const auto& row : rows2)
    ASSERT_LT((row.X_WT.translation() - rows2.front().X_WT.translation()).norm(), 1e-9);
  double travel = 0.0;
  for (const auto& row : both.records[1].rows())
    travel = std::max(travel, (row.X_WT.translation() - both.records[1].rows().front().X_WT.translation()).norm());
  EXPECT_GT(travel, 0.008) << "psm2 did not follow its device";
  for (const TwoArmRun* run : {&still, &both}) {
    EXPECT_LT(run->records[0].Summarize().rms_position_error, 1e-3);
    EXPECT_LT(run->records[1].Summarize().rms_position_error, 1e-3);
    // The session's robot takes each arm's joints from that arm's own loop.
    for (int k : run->positions1) EXPECT_EQ(run->last.q[k], run->q1[k]);
    for (int k : run->positions2) EXPECT_EQ(run->last.q[k], run->q2[k]);
  }
  // psm1 follows its circle: it travels the circle's diameter.
  double span = 0.0;
  for (const auto& row : still.records[0].rows())
    span = std::max(span, (row.X_WT.translation() - still.records[0].rows().front().X_WT.translation()).norm());
  EXPECT_GT(span, 0.035);
}

TEST(MultiArmSession, APointerGoesWhereItsDeviceTakesItScaledAndMovesNothing) {
  const TwoArmRun run = RunTwoArms(nullptr);
  control::ScriptedMotion wave;
  wave.amplitude = 0.03;
  control::ScriptedInput reference(wave);
  const auto& rows = run.records[2].rows();
  for (std::size_t i = 0; i < rows.size(); i += 97) {
    const Eigen::Vector3d hand = reference.Sample(rows[i].t).X_DH.translation();
    const Eigen::Vector3d expected = Eigen::Vector3d(1.0, 0.0, 1.0) + hand / 2.0;  // scale 2:1
    EXPECT_LT((rows[i].X_WD.translation() - expected).norm(), 1e-9) << rows[i].t;
    EXPECT_TRUE(rows[i].q.size() == 0);  // a pointer has no joints
  }
  EXPECT_LT((run.last.channels[2].X_WD.translation() - rows.back().X_WD.translation()).norm(), 1e-12);
}

// ---- force cues -------------------------------------------------------------------------------

struct PsmArm {
  robot::RobotModel model = robot::LoadRobot(test::SourcePath("robots/davinci-classic/psm.yaml"));
  robot::RobotState state{model};
  std::vector<int> all() const {
    std::vector<int> p(model.num_positions());
    for (int i = 0; i < model.num_positions(); ++i) p[i] = i;
    return p;
  }
  void At(const Eigen::VectorXd& q) { ASSERT_TRUE(kinematics::ForwardKinematics(model, q, &state).ok()); }
  Eigen::Vector3d ToolVelocityOf(int k) {
    kinematics::Matrix6Xd J;
    kinematics::ComputeFrameJacobian(model, state, model.tool_frame(), &J);
    return J.block<3, 1>(3, k);
  }
};

TEST(ForceFeedback, NearnessPushesAwayFromTheObstacleGrowingAsTheGapCloses) {
  PsmArm psm;
  psm.At(psm.model.defaults().home);
  control::ForceFeedbackOptions options;
  control::ForceFeedback feedback(psm.model, psm.all(), options);
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int trial = 0; trial < 50; ++trial) {
    control::ArmNearness near;
    near.p_W_other = Eigen::Vector3d(u(rng), u(rng), u(rng));
    const Eigen::Vector3d away = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized();
    near.distance = std::abs(u(rng)) * 2 * options.influence;
    near.p_W_arm = near.p_W_other + near.distance * away;
    const control::ForceCue cue = feedback.Compute(psm.state, psm.model.tool_frame(), near);
    if (near.distance >= options.influence) {
      EXPECT_EQ(cue.f_W.norm(), 0.0) << near.distance;
      EXPECT_EQ(cue.reasons & control::ForceCue::kNear, 0u);
      continue;
    }
    EXPECT_NEAR(cue.f_W.norm(), options.max_force * (1 - near.distance / options.influence), 1e-9);
    EXPECT_GT(cue.f_W.normalized().dot(away), 1 - 1e-9) << "not away from the obstacle";
    EXPECT_TRUE(cue.reasons & control::ForceCue::kNear);
  }
  // In contact the witness points meet: the last direction holds, at full force.
  control::ArmNearness touching;
  touching.distance = 0.0;
  const control::ForceCue contact = feedback.Compute(psm.state, psm.model.tool_frame(), touching);
  EXPECT_NEAR(contact.f_W.norm(), options.max_force, 1e-9);
  // Nothing near: nothing felt.
  EXPECT_EQ(feedback.Compute(psm.state, psm.model.tool_frame(), control::ArmNearness{}).f_W.norm(), 0.0);
}

TEST(ForceFeedback, JointAndInsertionLimitsPushBackAgainstTheMotionTowardThem) {
  PsmArm psm;
  control::ForceFeedback feedback(psm.model, psm.all());
  const int insertion = 2, yaw = 0;
  const Eigen::VectorXd lo = psm.model.lower_limits(), hi = psm.model.upper_limits();
  Eigen::VectorXd q = psm.model.defaults().home;
  psm.At(q);
  EXPECT_EQ(feedback.Compute(psm.state, psm.model.tool_frame(), {}).reasons, 0u) << "home is not near a limit";
  // Insertion nearly at its end.
  q[insertion] = hi[insertion] - 0.01 * (hi[insertion] - lo[insertion]);
  psm.At(q);
  control::ForceCue cue = feedback.Compute(psm.state, psm.model.tool_frame(), {});
  EXPECT_TRUE(cue.reasons & control::ForceCue::kInsertionLimit);
  EXPECT_LT(cue.f_W.dot(psm.ToolVelocityOf(insertion)), 0.0) << "the cue must resist inserting further";
  EXPECT_GT(cue.f_W.norm(), 0.5);
  // Deeper into the margin: a stronger cue.
  const double near_end = cue.f_W.norm();
  q[insertion] = hi[insertion] - 0.03 * (hi[insertion] - lo[insertion]);
  psm.At(q);
  EXPECT_LT(feedback.Compute(psm.state, psm.model.tool_frame(), {}).f_W.norm(), near_end);
  // Yaw near its lower limit: resist yawing further down.
  q = psm.model.defaults().home;
  q[yaw] = lo[yaw] + 0.005 * (hi[yaw] - lo[yaw]);
  psm.At(q);
  cue = feedback.Compute(psm.state, psm.model.tool_frame(), {});
  EXPECT_TRUE(cue.reasons & control::ForceCue::kJointLimit);
  EXPECT_EQ(cue.joint, psm.model.joint(psm.model.active_joints()[yaw]).name);
  EXPECT_GT(cue.f_W.dot(psm.ToolVelocityOf(yaw)), 0.0) << "the cue must resist yawing toward the lower limit";
}

TEST(ForceFeedback, TheForceIsExpressedInTheDevicesFrame) {
  std::mt19937 rng(8);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int i = 0; i < 20; ++i) {
    const Eigen::Matrix3d R_WD = Eigen::Quaterniond(u(rng), u(rng), u(rng), u(rng)).normalized().toRotationMatrix();
    const Eigen::Vector3d f_W(u(rng), u(rng), u(rng));
    EXPECT_LT((R_WD * control::ForceFeedback::InDevice(f_W, R_WD) - f_W).norm(), 1e-12);
  }
}

// ---- device files -----------------------------------------------------------------------------

class DeviceFile : public ::testing::Test {
 protected:
  std::string Write(const std::string& text) {
    const auto dir = std::filesystem::temp_directory_path() / ("trocar_devices_" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir);
    const std::string path = (dir / ("d" + std::to_string(n_++) + ".yaml")).string();
    std::ofstream(path) << text;
    return path;
  }
  /// The error's message, or "" when it did not throw.
  std::string ErrorOf(const std::string& text) {
    try {
      control::ReadDeviceConfig(Write(text));
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  }
  int n_ = 0;
};

TEST_F(DeviceFile, MapsDevicesToArmsWithUnitsScaleAndRotation) {
  const auto c = control::ReadDeviceConfig(Write(R"(devices:
  - {name: left, arm: psm1, units: mm, scale: 3, device_to_camera_rpy: [0, 0, 90 deg]}
  - {name: right, arm: psm2, units: m}
  - {name: bridge, arm: ecm, units: 0.01}
  - {name: senior, pointer: true}
)"));
  ASSERT_EQ(c.devices.size(), 4u);
  EXPECT_EQ(c.ForArm("psm1")->name, "left");
  EXPECT_DOUBLE_EQ(c.devices[0].units, 0.001);
  EXPECT_DOUBLE_EQ(*c.devices[0].scale, 3.0);
  EXPECT_LT((c.devices[0].R_CD * Eigen::Vector3d::UnitX() - Eigen::Vector3d::UnitY()).norm(), 1e-12);
  EXPECT_DOUBLE_EQ(c.devices[1].units, 1.0);
  EXPECT_FALSE(c.devices[1].scale.has_value());
  EXPECT_DOUBLE_EQ(c.devices[2].units, 0.01);
  EXPECT_TRUE(c.devices[3].pointer);
  EXPECT_EQ(c.ForArm("senior"), nullptr);
}

TEST_F(DeviceFile, EveryMistakeIsNamedByItsField) {
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"devices:\n  - {name: a, arm: psm1, colour: red}\n", "colour"},
      {"devices:\n  - {name: a, arm: psm1}\n  - {name: a, arm: psm2}\n", "listed twice"},
      {"devices:\n  - {name: abcdefghijklmnopqrstuvwxyz, arm: psm1}\n", "devices[0].name"},
      {"devices:\n  - {name: a}\n", "either arm"},
      {"devices:\n  - {name: a, arm: psm1, pointer: true}\n", "either arm"},
      {"devices:\n  - {name: a, arm: psm1}\n  - {name: b, arm: psm1}\n", "already has a device"},
      {"devices:\n  - {name: a, arm: psm1, units: -1}\n", "devices[0].units"},
      {"devices:\n  - {name: a, arm: psm1, units: inches}\n", "devices[0].units"},
      {"devices:\n  - {name: a, arm: psm1, scale: 0}\n", "devices[0].scale"},
      // #44 item 3: physical ranges, and names a device can send.
      {"devices:\n  - {name: a, arm: psm1, scale: 1e-300}\n", "devices[0].scale"},
      {"devices:\n  - {name: a, arm: psm1, scale: 1e300}\n", "devices[0].scale"},
      {"devices:\n  - {name: a, arm: psm1, units: 1e-300}\n", "devices[0].units"},
      {"devices:\n  - {name: a, arm: psm1, units: 1000}\n", "devices[0].units"},
      {"devices:\n  - {name: a, arm: psm1, device_to_camera_rpy: [1e308, 0, 0]}\n", "device_to_camera_rpy"},
      {"devices:\n  - {name: \"a\\0b\", arm: psm1}\n", "control or non-ASCII byte"},
      {"devices:\n  - {name: \"a\\tb\", arm: psm1}\n", "control or non-ASCII byte"},
      {"devices:\n  - {name: a, arm: psm1, device_to_camera_rpy: [0, 0]}\n", "device_to_camera_rpy"},
      {"devices: []\n", "no devices"},
      {"devices:\n  - {name: a, pointer: true}\n  - {name: b, pointer: true}\n", "one pointer at most"},
      {"arms: {}\n", "arms"},
  };
  for (const auto& [text, expected] : bad) {
    const std::string message = ErrorOf(text);
    EXPECT_NE(message.find(expected), std::string::npos) << text << " -> " << message;
    EXPECT_NE(message.find(".yaml"), std::string::npos) << "the file is not named: " << message;
  }
}

}  // namespace
}  // namespace trocar
