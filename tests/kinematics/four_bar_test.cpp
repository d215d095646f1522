#include "kinematics/four_bar.hpp"

#include <algorithm>
#include <random>

#include <gtest/gtest.h>

#include "common/geometry.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

using kinematics::ForwardKinematics;
using robot::RobotModel;
using robot::RobotState;
using test::CompareMatrices;

RobotModel Parallelogram() {
  return robot::LoadRobot(test::SourcePath("robots/parallelogram/parallelogram.urdf"));
}

TEST(FourBar, ParallelogramCouplerStaysParallelToTheGroundLink) {
  const RobotModel model = Parallelogram();
  RobotState state(model);
  const int turret = model.GetLink("turret"), coupler = model.GetLink("coupler");
  const int crank = model.GetLink("crank"), rocker = model.GetLink("rocker");
  const auto& closure = model.closures().at(0);
  ASSERT_TRUE(ForwardKinematics(model, Eigen::Vector3d(0.4, 0, 0.05), &state).ok());
  const Eigen::Matrix3d R_TC0 =
      state.X_WL[turret].linear().transpose() * state.X_WL[coupler].linear();
  for (double crank_angle = -1.3; crank_angle <= 1.3; crank_angle += 0.005) {
    ASSERT_TRUE(ForwardKinematics(model, Eigen::Vector3d(0.4, crank_angle, 0.05), &state).ok())
        << crank_angle;
    const Eigen::Matrix3d R_TC =
        state.X_WL[turret].linear().transpose() * state.X_WL[coupler].linear();
    EXPECT_TRUE(CompareMatrices(R_TC, R_TC0, 1e-12)) << "crank " << crank_angle;
    // Link lengths kept: crank and rocker 0.3 m, coupler 0.1 m, loop closed.
    const Eigen::Vector3d p_crank = state.X_WL[crank].translation();
    const Eigen::Vector3d p_coupler = state.X_WL[coupler].translation();
    const Eigen::Vector3d p_rocker = state.X_WL[rocker].translation();
    const Eigen::Vector3d p_cut_on_coupler = state.X_WL[coupler] * closure.p_C3;
    const Eigen::Vector3d p_cut_on_rocker = state.X_WL[rocker] * closure.p_B3;
    EXPECT_NEAR((p_coupler - p_crank).norm(), 0.3, 1e-12);
    EXPECT_NEAR((p_cut_on_coupler - p_coupler).norm(), 0.1, 1e-12);
    EXPECT_NEAR((p_cut_on_rocker - p_rocker).norm(), 0.3, 1e-12);
    EXPECT_LT((p_cut_on_coupler - p_cut_on_rocker).norm(), 1e-12);
    // Parallelogram: the rocker turns exactly with the crank.
    EXPECT_NEAR(state.joint_values[model.joint(closure.rocker).dof_index], crank_angle, 1e-12);
  }
}

void ExpectSameState(const RobotState& a, const RobotState& b) {
  EXPECT_EQ(a.q, b.q);
  EXPECT_EQ(a.joint_values, b.joint_values);
  EXPECT_EQ(a.dvalues_dq, b.dvalues_dq);
  EXPECT_EQ(a.closure_drivers, b.closure_drivers);
}

TEST(FourBar, DrivingBeyondTheRangeIsRefusedAndTheStateIsUnchanged) {
  const RobotModel model = Parallelogram();
  RobotState state(model);
  ASSERT_TRUE(ForwardKinematics(model, Eigen::Vector3d(0.2, 1.0, 0.1), &state).ok());
  const RobotState before = state;
  // The crank meets the ground line at +-pi/2 (change points where the loop could invert).
  for (double bad : {1.5708, 1.6, 2.0, 3.0, -1.5708, -1.6, -2.5}) {
    const auto result = ForwardKinematics(model, Eigen::Vector3d(0.2, bad, 0.1), &state);
    EXPECT_FALSE(result.ok()) << bad;
    EXPECT_EQ(result.status, kinematics::ConfigurationResult::Status::kClosureRefused) << bad;
    EXPECT_EQ(result.failed_closure, 0);
    EXPECT_NE(result.message.find("pitch_parallelogram"), std::string::npos) << result.message;
    ExpectSameState(state, before);
  }
  // And it still moves on from where it was.
  EXPECT_TRUE(ForwardKinematics(model, Eigen::Vector3d(0.2, 1.2, 0.1), &state).ok());
}

// A random four-bar in 3-D: random axis direction, random joint frame orientations and axis
// signs, random axial offsets; assembled at zero by construction. Returns the model and whether
// its crank can turn all the way round (Grashof with the crank shortest).
struct RandomFourBar {
  RobotModel model;
  bool crank_rotates_fully;
  double crank, coupler, rocker, ground;
};

Eigen::Matrix3d RandomRotation(std::mt19937* rng) {
  std::normal_distribution<double> g;
  return Eigen::Quaterniond(g(*rng), g(*rng), g(*rng), g(*rng)).normalized().toRotationMatrix();
}

RandomFourBar MakeRandomFourBar(std::mt19937* rng) {
  std::uniform_real_distribution<double> u(-1, 1), length(0.05, 0.5), sign(0, 1);
  const Eigen::Matrix3d R_plane = RandomRotation(rng);  // columns: in-plane u, v and normal n
  const Eigen::Vector3d n = R_plane.col(2);
  auto in_plane = [&](double x, double y, double axial) {
    return Eigen::Vector3d(R_plane * Eigen::Vector3d(x, y, axial));
  };
  const double crank = length(*rng), ground = length(*rng);
  const double crank_angle = u(*rng) * M_PI;
  const Eigen::Vector3d P1 = in_plane(0, 0, 0.1 * u(*rng));
  const Eigen::Vector3d P4 = in_plane(ground, 0, 0.1 * u(*rng));
  const Eigen::Vector3d P2 =
      in_plane(crank * std::cos(crank_angle), crank * std::sin(crank_angle), 0.1 * u(*rng));
  const Eigen::Vector3d P3 = in_plane(u(*rng) * 0.4, 0.05 + 0.4 * sign(*rng), 0.1 * u(*rng));
  auto planar = [&](const Eigen::Vector3d& v) { return (v - v.dot(n) * n).norm(); };
  const double coupler = planar(P3 - P2), rocker = planar(P3 - P4);

  robot::RobotModelBuilder b("random_four_bar", "test");
  for (const char* name : {"ground", "crank", "coupler", "rocker"}) b.AddLink(name);
  auto axis_sign = [&]() { return sign(*rng) < 0.5 ? -1.0 : 1.0; };
  auto add_joint = [&](const char* name, const char* parent, const char* child,
                       const Eigen::Isometry3d& X_GP, const Eigen::Vector3d& origin_G) {
    auto& j = b.AddJoint(name);
    j.type = robot::JointType::kRevolute;
    j.parent = parent;
    j.child = child;
    Eigen::Isometry3d X_GJ = Eigen::Isometry3d::Identity();
    X_GJ.linear() = RandomRotation(rng);
    X_GJ.translation() = origin_G;
    j.X_PJ = X_GP.inverse() * X_GJ;
    j.axis = X_GJ.linear().transpose() * (axis_sign() * n);
    return X_GJ;
  };
  const Eigen::Isometry3d I = Eigen::Isometry3d::Identity();
  const Eigen::Isometry3d X_GA = add_joint("driver", "ground", "crank", I, P1);
  const Eigen::Isometry3d X_GC = add_joint("coupler_joint", "crank", "coupler", X_GA, P2);
  add_joint("rocker_joint", "ground", "rocker", I, P4);
  b.AddFourBar({"loop", "driver", "coupler_joint", "rocker_joint", X_GC.inverse() * P3, {}});

  const double lengths[4] = {crank, coupler, rocker, ground};
  const double s = *std::min_element(lengths, lengths + 4);
  const double l = *std::max_element(lengths, lengths + 4);
  const double sum = crank + coupler + rocker + ground;
  const bool grashof = s + l < sum - s - l - 1e-3;
  return {b.Build(), grashof && s == crank, crank, coupler, rocker, ground};
}

TEST(FourBar, RandomLoopsStayClosedWithTheirLinkLengths) {
  std::mt19937 rng(1234);
  int full_rotations = 0, refusals = 0;
  for (int trial = 0; trial < 300; ++trial) {
    const RandomFourBar bar = MakeRandomFourBar(&rng);
    const RobotModel& model = bar.model;
    const auto& c = model.closures().at(0);
    EXPECT_NEAR(c.c0.norm(), bar.crank, 1e-12);
    EXPECT_NEAR(c.L23, bar.coupler, 1e-12);
    EXPECT_NEAR(c.L34, bar.rocker, 1e-12);
    RobotState state(model);
    // Drive in small steps one way round; a full-rotation crank must never be refused.
    const double direction = trial % 2 == 0 ? 1.0 : -1.0;
    bool refused = false;
    for (int step = 1; step <= 400 && !refused; ++step) {
      const double driver = direction * step * (2 * M_PI / 400);
      const RobotState before = state;
      const auto result = kinematics::SetConfiguration(model, Eigen::VectorXd::Constant(1, driver), &state);
      if (!result.ok()) {
        refused = true;
        ++refusals;
        ExpectSameState(state, before);
        EXPECT_FALSE(bar.crank_rotates_fully) << "trial " << trial << ": " << result.message;
        break;
      }
      const double coupler = state.joint_values[model.joint(c.coupler).dof_index];
      const double rocker = state.joint_values[model.joint(c.rocker).dof_index];
      ASSERT_LT(kinematics::FourBarClosureGap(model, c, driver, coupler, rocker), 1e-9)
          << "trial " << trial << " driver " << driver;
      // Derivatives of the closure against finite differences of the solver.
      const double h = 1e-7;
      const auto plus = kinematics::SolveFourBar(model, c, driver + h, driver, coupler, rocker);
      const auto minus = kinematics::SolveFourBar(model, c, driver - h, driver, coupler, rocker);
      if (plus.ok() && minus.ok()) {
        const double scale = 1.0 + std::abs(state.dvalues_dq(model.joint(c.coupler).dof_index, 0));
        EXPECT_NEAR(state.dvalues_dq(model.joint(c.coupler).dof_index, 0),
                    (plus.coupler - minus.coupler) / (2 * h), 1e-5 * scale);
        EXPECT_NEAR(state.dvalues_dq(model.joint(c.rocker).dof_index, 0),
                    (plus.rocker - minus.rocker) / (2 * h), 1e-5 * scale);
      }
    }
    if (!refused) {
      ++full_rotations;
      // After a whole turn the loop is back where it started.
      EXPECT_NEAR(WrapAngle(state.joint_values[model.joint(c.coupler).dof_index]), 0.0, 1e-9);
    }
  }
  // The random population holds both kinds of mechanism.
  EXPECT_GT(full_rotations, 10);
  EXPECT_GT(refusals, 10);
}

TEST(FourBar, AJumpOverAChangePointIsRefusedEvenWhenTheTargetCouldClose) {
  const RobotModel model = Parallelogram();
  const auto& c = model.closures().at(0);
  // At 2.0 rad the coupler and rocker circles do meet (the crossed, anti-parallelogram branch),
  // but the crank would have to pass the change point at pi/2 to get there.
  const auto jump = kinematics::SolveFourBar(model, c, 2.0, 0.0, 0.0, 0.0);
  EXPECT_FALSE(jump.ok());
  EXPECT_EQ(jump.status, kinematics::FourBarSolution::Status::kChangePoint) << jump.message;
  EXPECT_NE(jump.message.find("change point"), std::string::npos) << jump.message;
  EXPECT_TRUE(kinematics::SolveFourBar(model, c, 1.45, 0.0, 0.0, 0.0).ok());
  // Exactly at the change point the circles only touch: outside the range, said as such.
  const auto at = kinematics::SolveFourBar(model, c, M_PI / 2, M_PI / 2, 0.0, 0.0);
  EXPECT_EQ(at.status, kinematics::FourBarSolution::Status::kOutsideRange) << at.message;
  EXPECT_STREQ(kinematics::ToString(at.status), "outside the mechanism's range");
}

}  // namespace
}  // namespace trocar
