// The da Vinci Classic models against the public dVRK kinematics (../shared/reference/
// davinci-kinematics.md): tool-tip poses, the fixed remote centre of motion, the cart, and the
// setup-joint solver.
#include <random>

#include <gtest/gtest.h>

#include "common/error.hpp"
#include "common/geometry.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "kinematics/four_bar.hpp"
#include "kinematics/setup_joints.hpp"
#include "robot/dh_table.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

using kinematics::ForwardKinematics;
using robot::DhRow;
using robot::DhTable;
using robot::JointType;
using robot::RobotModel;
using robot::RobotState;
using test::CompareMatrices;

constexpr double kRcmTolerance = 1e-9;  // m
constexpr double kDhTolerance = 1e-9;   // m, and rotation entries

std::string DaVinci(const std::string& file) {
  return test::SourcePath("robots/davinci-classic/" + file);
}

DhRow Row(JointType type, double alpha, double a, double d, double offset) {
  DhRow row;
  row.type = type;
  row.alpha = alpha;
  row.a = a;
  row.d = d;
  row.offset = offset;
  return row;
}

// The dVRK tables as published (modified DH; offset adds to theta, or to d for the prismatic).
DhTable DvrkPsm(double insertion_offset, double roll_d) {
  const auto R = JointType::kRevolute;
  DhTable t;
  t.rows = {Row(R, M_PI / 2, 0, 0, M_PI / 2),
            Row(R, -M_PI / 2, 0, 0, -M_PI / 2),
            Row(JointType::kPrismatic, M_PI / 2, 0, 0, insertion_offset),
            Row(R, 0, 0, roll_d, 0),
            Row(R, -M_PI / 2, 0, 0, -M_PI / 2),
            Row(R, -M_PI / 2, 0.0091, 0, -M_PI / 2)};
  t.X_NT.linear() << 0, -1, 0, 0, 0, 1, -1, 0, 0;  // the dVRK's tool-tip rotation
  return t;
}

DhTable DvrkEcm() {
  DhTable t;
  t.rows = {Row(JointType::kRevolute, M_PI / 2, 0, 0, M_PI / 2),
            Row(JointType::kRevolute, -M_PI / 2, 0, 0, -M_PI / 2),
            Row(JointType::kPrismatic, M_PI / 2, 0, 0, -0.3822),
            Row(JointType::kRevolute, 0, 0, 0.3829, 0)};
  return t;
}

void ExpectToolMatchesDvrk(const std::string& file, const DhTable& table, unsigned seed) {
  SCOPED_TRACE(file);
  const RobotModel model = robot::LoadRobot(file);
  RobotState state(model);
  std::mt19937 rng(seed);
  const int n = static_cast<int>(table.rows.size());
  for (int trial = 0; trial < 1000; ++trial) {
    const Eigen::VectorXd q = test::RandomConfiguration(model, &rng);
    ASSERT_TRUE(ForwardKinematics(model, q, &state).ok()) << q.transpose();
    ASSERT_TRUE(CompareMatrices(kinematics::ToolPoseInBase(model, state).matrix(),
                                robot::DhToolPose(table, q.head(n)).matrix(), kDhTolerance))
        << "q = " << q.transpose();
  }
}

TEST(DaVinci, PsmToolTipMatchesTheDvrkTable) {
  ExpectToolMatchesDvrk(DaVinci("psm.yaml"), DvrkPsm(-0.4318, 0.4162), 1);
}
TEST(DaVinci, SiPsmToolTipMatchesTheDvrkTable) {
  ExpectToolMatchesDvrk(DaVinci("psm_si.yaml"), DvrkPsm(-0.4826, 0.4670), 2);
}
TEST(DaVinci, EcmToolTipMatchesTheDvrkTable) {
  ExpectToolMatchesDvrk(DaVinci("ecm.yaml"), DvrkEcm(), 3);
}
TEST(DaVinci, ThirtyDegreeScopeLooksThirtyDegreesDown) {
  DhTable table = DvrkEcm();
  table.X_NT = RotX(-M_PI / 6);
  ExpectToolMatchesDvrk(DaVinci("ecm_30.yaml"), table, 4);
}

TEST(DaVinci, JointLimitsAreTheDvrkRanges) {
  const RobotModel psm = robot::LoadRobot(DaVinci("psm.yaml"));
  const double lower[7] = {-1.588, -0.925, 0, -4.538, -1.396, -1.396, -0.698};
  const double upper[7] = {1.588, 0.925, 0.240, 4.538, 1.396, 1.396, 1.396};
  for (int i = 0; i < 7; ++i) {
    EXPECT_EQ(psm.lower_limits()[i], lower[i]) << i;
    EXPECT_EQ(psm.upper_limits()[i], upper[i]) << i;
  }
  const RobotModel ecm = robot::LoadRobot(DaVinci("ecm.yaml"));
  EXPECT_EQ(ecm.lower_limits()[1], -0.768);
  EXPECT_EQ(ecm.upper_limits()[1], 1.134);
  EXPECT_EQ(ecm.upper_limits()[2], 0.255);
}

// Where the shaft crosses the RCM: the insertion axis passes within `distance` of the RCM frame.
double ShaftDistanceFromRcm(const RobotModel& model, const RobotState& state,
                            const std::string& insertion_joint, const std::string& rcm_frame) {
  const robot::Joint& joint = model.joint(model.GetJoint(insertion_joint));
  const Eigen::Isometry3d& X_WI = state.X_WL[joint.child_link];
  const Eigen::Vector3d axis = X_WI.linear() * joint.axis_J;
  const Eigen::Vector3d to_rcm =
      kinematics::FramePose(state, model.GetFrame(rcm_frame)).translation() - X_WI.translation();
  return (to_rcm - to_rcm.dot(axis) * axis).norm();
}

void ExpectRcmFixedOverSweeps(const std::string& file, const std::string& insertion_joint) {
  SCOPED_TRACE(file);
  const RobotModel model = robot::LoadRobot(file);
  RobotState state(model);
  std::mt19937 rng(5);
  const Eigen::VectorXd lower = model.lower_limits(), upper = model.upper_limits();
  // Sweep yaw (0), pitch (1) and roll (3) over their full ranges, the other joints random.
  for (int swept : {0, 1, 3}) {
    for (int repeat = 0; repeat < 5; ++repeat) {
      Eigen::VectorXd q = test::RandomConfiguration(model, &rng);
      for (int step = 0; step <= 200; ++step) {
        q[swept] = lower[swept] + (upper[swept] - lower[swept]) * step / 200.0;
        ASSERT_TRUE(ForwardKinematics(model, q, &state).ok()) << q.transpose();
        // The RCM frame itself is the base, fixed; the shaft must pass through it.
        ASSERT_LT(ShaftDistanceFromRcm(model, state, insertion_joint, "rcm"), kRcmTolerance)
            << "joint " << swept << " q = " << q.transpose();
        // And the loops stay closed.
        for (const auto& c : model.closures()) {
          const auto value = [&](int j) { return state.joint_values[model.joint(j).dof_index]; };
          ASSERT_LT(kinematics::FourBarClosureGap(model, c, value(c.driver), value(c.coupler),
                                                  value(c.rocker)),
                    1e-12);
        }
      }
    }
  }
}

TEST(DaVinci, PsmRcmStaysFixedOverFullSweeps) {
  ExpectRcmFixedOverSweeps(DaVinci("psm.yaml"), "outer_insertion");
}
TEST(DaVinci, SiPsmRcmStaysFixedOverFullSweeps) {
  ExpectRcmFixedOverSweeps(DaVinci("psm_si.yaml"), "outer_insertion");
}
TEST(DaVinci, EcmRcmStaysFixedOverFullSweeps) {
  ExpectRcmFixedOverSweeps(DaVinci("ecm.yaml"), "insertion");
}

TEST(DaVinci, ParallelogramLinksAreRealBodiesDrivenByTwoClosures) {
  const RobotModel model = robot::LoadRobot(DaVinci("psm.yaml"));
  ASSERT_EQ(model.closures().size(), 2u);
  // The two loops share the back -> bottom joint: loop 1's coupler drives loop 2.
  EXPECT_EQ(model.closures()[0].coupler, model.closures()[1].driver);
  for (const char* link : {"pitch_back_link", "pitch_front_link", "pitch_bottom_link",
                           "pitch_top_link", "pitch_end_link"}) {
    EXPECT_FALSE(model.link(model.GetLink(link)).collisions.empty()) << link;
  }
  for (const char* joint : {"pitch_front", "pitch_bottom", "pitch_top", "pitch_end"}) {
    EXPECT_EQ(model.joint(model.GetJoint(joint)).drive, robot::JointDrive::kClosure) << joint;
  }
  // The bottom link stays parallel to the yaw axis and the end link turns with the pitch.
  RobotState state(model);
  Eigen::VectorXd q = Eigen::VectorXd::Zero(7);
  q[1] = 0.6;
  ASSERT_TRUE(ForwardKinematics(model, q, &state).ok());
  const Eigen::Matrix3d R_yaw = state.X_WL[model.GetLink("yaw_link")].linear();
  EXPECT_TRUE(CompareMatrices(state.X_WL[model.GetLink("pitch_bottom_link")].linear(), R_yaw, 1e-12));
  EXPECT_TRUE(CompareMatrices(
      state.X_WL[model.GetLink("pitch_end_link")].linear(),
      R_yaw * Eigen::AngleAxisd(0.6, Eigen::Vector3d::UnitY()).toRotationMatrix(), 1e-12));
}

// Every held (setup) joint of the cart at a random value within its limits.
void RandomSetupJoints(const RobotModel& cart, std::mt19937* rng, RobotState* state) {
  for (int j : cart.dof_joints()) {
    const robot::Joint& joint = cart.joint(j);
    if (joint.drive != robot::JointDrive::kHeld) continue;
    state->joint_values[joint.dof_index] =
        std::uniform_real_distribution<double>(joint.limits.lower, joint.limits.upper)(*rng);
  }
}

TEST(DaVinciCart, IsOneDescriptionWithHeldSetupJointsAndActiveArms) {
  const RobotModel cart = robot::LoadRobot(DaVinci("cart.yaml"));
  EXPECT_EQ(cart.num_positions(), 18);
  int held = 0;
  for (int j : cart.dof_joints()) held += cart.joint(j).drive == robot::JointDrive::kHeld;
  EXPECT_EQ(held, 16);
  EXPECT_EQ(cart.closures().size(), 6u);
  for (const char* frame : {"psm1_rcm", "psm2_rcm", "ecm_rcm", "psm1_tool", "psm2_tool",
                            "ecm_tool", "ecm_camera_30_down"}) {
    EXPECT_NO_THROW(cart.GetFrame(frame)) << frame;
  }
  // Each arm keeps its RCM when it moves, wherever the setup joints put it.
  RobotState state(cart);
  std::mt19937 rng(6);
  for (int trial = 0; trial < 200; ++trial) {
    RandomSetupJoints(cart, &rng, &state);
    ASSERT_TRUE(ForwardKinematics(cart, test::RandomConfiguration(cart, &rng), &state).ok());
    EXPECT_LT(ShaftDistanceFromRcm(cart, state, "psm1_outer_insertion", "psm1_rcm"), 1e-9);
    EXPECT_LT(ShaftDistanceFromRcm(cart, state, "psm2_outer_insertion", "psm2_rcm"), 1e-9);
    EXPECT_LT(ShaftDistanceFromRcm(cart, state, "ecm_insertion", "ecm_rcm"), 1e-9);
  }
}

TEST(DaVinciCart, PosingOneLinksChainGivesTheWholeRobotsPosesThereAndTouchesNothingElse) {
  // ForwardKinematicsToLink (the setup-joint solver's inner loop) against the whole robot's
  // forward kinematics, on every link of the cart at random setup joints, arm joints and cart
  // poses: the same poses bit for bit on the link's chain, and every other link left as it was.
  const RobotModel cart = robot::LoadRobot(DaVinci("cart.yaml"));
  std::mt19937 rng(44);
  const Eigen::Isometry3d kUntouched = Eigen::Translation3d(1e3, -1e3, 1e3) *
                                       Eigen::Isometry3d(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitX()));
  int links_checked = 0;
  for (int trial = 0; trial < 20; ++trial) {
    RobotState whole(cart);
    std::uniform_real_distribution<double> metres(-2.0, 2.0);
    whole.X_WB = Eigen::Translation3d(metres(rng), metres(rng), metres(rng)) *
                 Eigen::AngleAxisd(std::uniform_real_distribution<double>(-M_PI, M_PI)(rng),
                                   Eigen::Vector3d::UnitZ());
    RandomSetupJoints(cart, &rng, &whole);
    ASSERT_TRUE(ForwardKinematics(cart, test::RandomConfiguration(cart, &rng), &whole).ok());
    for (int link = 0; link < cart.num_links(); ++link) {
      RobotState part = whole;
      for (auto& X : part.X_WL) X = kUntouched;
      kinematics::ForwardKinematicsToLink(cart, link, &part);
      std::vector<bool> on_chain(cart.num_links(), false);
      for (int l = link;; l = cart.joint(cart.link(l).parent_joint).parent_link) {
        on_chain[l] = true;
        if (cart.link(l).parent_joint < 0) break;
      }
      for (int l = 0; l < cart.num_links(); ++l) {
        const Eigen::Isometry3d& expected = on_chain[l] ? whole.X_WL[l] : kUntouched;
        ASSERT_TRUE(CompareMatrices(part.X_WL[l].matrix(), expected.matrix(), 0.0))
            << "posing '" << cart.link(link).name << "': link '" << cart.link(l).name << "' ("
            << (on_chain[l] ? "on its chain" : "not on its chain") << ")";
      }
      ++links_checked;
    }
  }
  EXPECT_EQ(links_checked, 20 * cart.num_links());
  RobotState state(cart);
  EXPECT_THROW(kinematics::ForwardKinematicsToLink(cart, cart.num_links(), &state), Error);
  EXPECT_THROW(kinematics::ForwardKinematicsToLink(cart, -1, &state), Error);
}

// The pose of an RCM frame at random setup-joint values (a reachable target), and in `start` the
// same random arm joints with the setup joints at their neutral values.
Eigen::Isometry3d RandomRcmPose(const RobotModel& cart, const robot::Frame& rcm, std::mt19937* rng,
                                RobotState* start) {
  RobotState truth(cart);
  for (int j : cart.movable_path(rcm.link)) {
    const robot::Joint& joint = cart.joint(j);
    if (joint.drive != robot::JointDrive::kHeld) continue;
    truth.joint_values[joint.dof_index] =
        std::uniform_real_distribution<double>(joint.limits.lower, joint.limits.upper)(*rng);
  }
  const Eigen::VectorXd q = test::RandomConfiguration(cart, rng);
  const auto fk = ForwardKinematics(cart, q, &truth);
  EXPECT_TRUE(fk.ok()) << fk.message;
  *start = RobotState(cart);
  EXPECT_TRUE(kinematics::SetConfiguration(cart, q, start).ok());
  return kinematics::FramePose(truth, rcm);
}

TEST(SetupJointSolver, PlacesEachRcmWhereRandomSetupJointsPutIt) {
  const RobotModel cart = robot::LoadRobot(DaVinci("cart.yaml"), {false, {}});
  std::mt19937 rng(7);
  for (const std::string arm : {"psm1", "psm2", "ecm"}) {
    SCOPED_TRACE(arm);
    const robot::Frame& rcm = cart.GetFrame(arm + "_rcm");
    for (int trial = 0; trial < 40; ++trial) {
      // A reachable target: forward kinematics of random setup-joint values.
      RobotState start(cart);  // setup joints at their neutral values
      const Eigen::Isometry3d X_WR = RandomRcmPose(cart, rcm, &rng, &start);
      kinematics::SetupJointRequest request;
      request.frame = rcm.name;
      request.p_WF = X_WR.translation();
      request.axis_W = X_WR.linear() * -Eigen::Vector3d::UnitZ();
      const auto result = kinematics::SolveSetupJoints(cart, start, request);
      ASSERT_TRUE(result.ok()) << result.message << " trial " << trial;
      // Check independently: put the values in and run forward kinematics.
      RobotState check = start;
      for (std::size_t i = 0; i < result.joints.size(); ++i) {
        ASSERT_TRUE(kinematics::SetHeldJoint(cart, result.joints[i], result.values[i], &check).ok());
      }
      ForwardKinematics(cart, &check);
      const Eigen::Isometry3d X_WR_found = kinematics::FramePose(check, rcm);
      EXPECT_LT((X_WR_found.translation() - request.p_WF).norm(), 1e-4);
      const Eigen::Vector3d axis = X_WR_found.linear() * -Eigen::Vector3d::UnitZ();
      EXPECT_LT(std::acos(std::min(1.0, axis.dot(*request.axis_W))), 0.1 * M_PI / 180);
    }
  }
}

// axis_secondary: the port first, then the axis as near as the position allows. On reachable
// poses (forward kinematics of random setup-joint values) it finds both; asked for any axis at a
// reachable port (upward ones too), PSM1 stays at the port and aims far nearer than the position
// alone leaves the axis (which is what the cart's placement fell back to: an RCM turned anywhere,
// its arm's own joints then at their limits). The ECM's setup joints turn its RCM about the
// vertical only: its axis is what it is, whatever is asked.
TEST(SetupJointSolver, AtThePortFirstItAimsAsNearAsThePositionAllows) {
  const RobotModel cart = robot::LoadRobot(DaVinci("cart.yaml"), {false, {}});
  std::mt19937 rng(11);
  auto random_pose = [&](const robot::Frame& rcm, RobotState* start) {
    return RandomRcmPose(cart, rcm, &rng, start);
  };
  auto angle_of = [&](const kinematics::SetupJointResult& r, const RobotState& start,
                      const robot::Frame& rcm, const Eigen::Vector3d& axis_W, double* position,
                      const Eigen::Vector3d& p_W) {
    RobotState check = start;
    for (std::size_t i = 0; i < r.joints.size(); ++i)
      EXPECT_TRUE(kinematics::SetHeldJoint(cart, r.joints[i], r.values[i], &check).ok());
    ForwardKinematics(cart, &check);
    const Eigen::Isometry3d X = kinematics::FramePose(check, rcm);
    *position = (X.translation() - p_W).norm();
    return std::acos(std::clamp((X.linear() * -Eigen::Vector3d::UnitZ()).dot(axis_W), -1.0, 1.0));
  };
  kinematics::SetupJointOptions secondary;
  secondary.axis_secondary = true;
  for (const std::string arm : {"psm1", "ecm"}) {
    SCOPED_TRACE(arm);
    const robot::Frame& rcm = cart.GetFrame(arm + "_rcm");
    for (int trial = 0; trial < test::Trials(10, 3); ++trial) {
      RobotState start(cart);
      const Eigen::Isometry3d X_WR = random_pose(rcm, &start);
      kinematics::SetupJointRequest request;
      request.frame = rcm.name;
      request.p_WF = X_WR.translation();
      request.axis_W = X_WR.linear() * -Eigen::Vector3d::UnitZ();
      const auto result = kinematics::SolveSetupJoints(cart, start, request, secondary);
      double position = 0.0;
      const double angle = angle_of(result, start, rcm, *request.axis_W, &position, request.p_WF);
      EXPECT_LT(position, 1e-4) << "trial " << trial;
      EXPECT_LT(angle, 0.1 * M_PI / 180) << "trial " << trial << ": " << result.message;
    }
  }
  const robot::Frame& rcm = cart.GetFrame("psm1_rcm");
  double sum_secondary = 0.0, sum_position_only = 0.0;
  const int trials = test::Trials(20, 6);
  for (int trial = 0; trial < trials; ++trial) {
    RobotState start(cart);
    const Eigen::Isometry3d X_WR = random_pose(rcm, &start);
    // Any axis, upward ones too (which the PSM's setup joints cannot give at most ports).
    Eigen::Vector3d axis(std::normal_distribution<double>()(rng),
                         std::normal_distribution<double>()(rng),
                         std::normal_distribution<double>()(rng));
    axis.normalize();
    kinematics::SetupJointRequest request;
    request.frame = rcm.name;
    request.p_WF = X_WR.translation();
    request.axis_W = axis;
    const auto first = kinematics::SolveSetupJoints(cart, start, request, secondary);
    kinematics::SetupJointRequest position_only = request;
    position_only.axis_W.reset();
    const auto only = kinematics::SolveSetupJoints(cart, start, position_only);
    double p1 = 0.0, p2 = 0.0;
    const double a1 = angle_of(first, start, rcm, axis, &p1, request.p_WF);
    const double a2 = angle_of(only, start, rcm, axis, &p2, request.p_WF);
    EXPECT_LE(p1, 1e-4 + 1e-12) << "trial " << trial << ": " << first.message;
    EXPECT_LE(a1, a2 + 1e-6) << "trial " << trial;
    sum_secondary += a1;
    sum_position_only += a2;
  }
  RecordProperty("mean_angle_secondary_deg", std::to_string(sum_secondary / trials * 180 / M_PI));
  RecordProperty("mean_angle_position_only_deg",
                 std::to_string(sum_position_only / trials * 180 / M_PI));
  EXPECT_LT(sum_secondary, 0.5 * sum_position_only);
}

TEST(SetupJointSolver, ATargetOutOfReachIsUnreachableWithTheDistanceShort) {
  const RobotModel cart = robot::LoadRobot(DaVinci("cart.yaml"), {false, {}});
  RobotState state(cart);
  ForwardKinematics(cart, Eigen::VectorXd::Zero(18), &state);
  kinematics::SetupJointRequest request;
  request.frame = "psm1_rcm";
  request.p_WF = Eigen::Vector3d(6.0, 0.0, 1.0);  // far beyond the setup joints' reach
  request.axis_W = -Eigen::Vector3d::UnitZ();
  const auto result = kinematics::SolveSetupJoints(cart, state, request);
  EXPECT_FALSE(result.ok());
  EXPECT_GT(result.position_error, 3.0);
  EXPECT_LT(result.position_error, 6.0);
  EXPECT_NE(result.message.find("unreachable: frame 'psm1_rcm' stays"), std::string::npos)
      << result.message;
  ASSERT_EQ(result.values.size(), 6);
  for (std::size_t i = 0; i < result.joints.size(); ++i) {  // best attempt within the limits
    const auto& limits = cart.joint(cart.GetJoint(result.joints[i])).limits;
    EXPECT_GE(result.values[i], limits.lower);
    EXPECT_LE(result.values[i], limits.upper);
  }
}

TEST(SetupJointSolver, BadRequestsAreErrorsNamingTheProblem) {
  const RobotModel cart = robot::LoadRobot(DaVinci("cart.yaml"), {false, {}});
  RobotState state(cart);
  kinematics::SetupJointRequest request;
  request.frame = "psm3_rcm";
  EXPECT_THROW(kinematics::SolveSetupJoints(cart, state, request), Error);
  request.frame = "psm1_rcm";
  request.p_WF = Eigen::Vector3d(std::nan(""), 0, 1);
  EXPECT_THROW(kinematics::SolveSetupJoints(cart, state, request), Error);
  request.p_WF = Eigen::Vector3d(1, 0, 1);
  request.axis_W = Eigen::Vector3d::Zero();
  EXPECT_THROW(kinematics::SolveSetupJoints(cart, state, request), Error);
  request.axis_W.reset();
  request.joints = {"psm1_outer_yaw"};
  EXPECT_THROW(kinematics::SolveSetupJoints(cart, state, request), Error);
}

}  // namespace
}  // namespace trocar
