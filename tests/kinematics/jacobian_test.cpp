#include "kinematics/jacobian.hpp"

#include <random>

#include <gtest/gtest.h>

#include "kinematics/forward_kinematics.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

using kinematics::ForwardKinematics;
using robot::RobotModel;
using robot::RobotState;

constexpr double kStep = 1e-6;       // central differences
constexpr double kTolerance = 1e-6;  // tighter than the sqrt(h) = 1e-3 the issue allows

// Spatial velocity [ω; v] of point p_LF on `link` by central differences of forward kinematics.
Eigen::Matrix<double, 6, Eigen::Dynamic> FiniteDifferenceJacobian(const RobotModel& model,
                                                                  const Eigen::VectorXd& q,
                                                                  int link,
                                                                  const Eigen::Vector3d& p_LF) {
  Eigen::Matrix<double, 6, Eigen::Dynamic> J(6, model.num_positions());
  RobotState plus(model), minus(model);
  for (int k = 0; k < model.num_positions(); ++k) {
    Eigen::VectorXd qp = q, qm = q;
    qp[k] += kStep;
    qm[k] -= kStep;
    EXPECT_TRUE(ForwardKinematics(model, q, &plus).ok());  // close loops near q first
    EXPECT_TRUE(ForwardKinematics(model, q, &minus).ok());
    EXPECT_TRUE(ForwardKinematics(model, qp, &plus).ok());
    EXPECT_TRUE(ForwardKinematics(model, qm, &minus).ok());
    const Eigen::Isometry3d& Xp = plus.X_WL[link];
    const Eigen::Isometry3d& Xm = minus.X_WL[link];
    const Eigen::AngleAxisd dR(Xp.linear() * Xm.linear().transpose());
    J.col(k).head<3>() = dR.angle() * dR.axis() / (2 * kStep);
    J.col(k).tail<3>() = (Xp * p_LF - Xm * p_LF) / (2 * kStep);
  }
  return J;
}

void CheckJacobian(const std::string& file, int trials, unsigned seed) {
  SCOPED_TRACE(file);
  const RobotModel model = robot::LoadRobot(file, {false, {}});
  RobotState state(model);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> offset(-0.1, 0.1);
  std::uniform_int_distribution<int> pick_link(0, model.num_links() - 1);
  kinematics::Matrix6Xd J;
  for (int trial = 0; trial < trials; ++trial) {
    const Eigen::VectorXd q = test::RandomConfiguration(model, &rng);
    ASSERT_TRUE(ForwardKinematics(model, q, &state).ok());
    // The tool frame, and a random point on a random link.
    kinematics::ComputeFrameJacobian(model, state, model.tool_frame(), &J);
    ASSERT_TRUE(test::CompareMatrices(
        J, FiniteDifferenceJacobian(model, q, model.tool_frame().link,
                                    model.tool_frame().X_LF.translation()),
        kTolerance))
        << "tool, q = " << q.transpose();
    const int link = pick_link(rng);
    const Eigen::Vector3d p_LF(offset(rng), offset(rng), offset(rng));
    ASSERT_TRUE(ForwardKinematics(model, q, &state).ok());
    kinematics::ComputeJacobian(model, state, link, p_LF, &J);
    ASSERT_TRUE(test::CompareMatrices(J, FiniteDifferenceJacobian(model, q, link, p_LF),
                                      kTolerance))
        << "link " << model.link(link).name << ", q = " << q.transpose();
  }
}

TEST(Jacobian, MatchesFiniteDifferencesPa10) {
  CheckJacobian(test::SourcePath("robots/pa10/pa10.yaml"), 1000, 1);
}
TEST(Jacobian, MatchesFiniteDifferencesPa10Urdf) {
  CheckJacobian(test::SourcePath("robots/pa10/pa10.urdf"), 1000, 2);
}
TEST(Jacobian, MatchesFiniteDifferencesPa10Instrument) {
  CheckJacobian(test::SourcePath("robots/pa10/pa10_instrument.yaml"), 1000, 3);
}
TEST(Jacobian, MatchesFiniteDifferencesPrismaticTestRobot) {
  CheckJacobian(test::SourcePath("robots/prismatic-test/prismatic10.yaml"), 1000, 4);
}
TEST(Jacobian, MatchesFiniteDifferencesThroughFourBarClosure) {
  CheckJacobian(test::SourcePath("robots/parallelogram/parallelogram.urdf"), 1000, 5);
}
TEST(Jacobian, MatchesFiniteDifferencesThroughTheDaVinciDoubleParallelogram) {
  CheckJacobian(test::SourcePath("robots/davinci-classic/psm.yaml"), 1000, 7);
  CheckJacobian(test::SourcePath("robots/davinci-classic/ecm.yaml"), 1000, 8);
}
TEST(Jacobian, MatchesFiniteDifferencesOnTheWholeCart) {
  CheckJacobian(test::SourcePath("robots/davinci-classic/cart.yaml"), 200, 9);
}
TEST(Jacobian, MatchesFiniteDifferencesThroughMimicJoints) {
  const std::string path = test::SharedDataPath("robots/surrol-psm/psm.urdf");
  TROCAR_REQUIRE_SHARED_FILE(path);
  CheckJacobian(path, 1000, 6);
}

TEST(Jacobian, AngularPartIsTheToolAngularVelocityForEveryFrame) {
  // The angular rows are the link's angular velocity in the world (ω with Ṙ = [ω]× R, by
  // differences of the rotation: a sign or frame error fails here), whatever the point.
  const RobotModel model = robot::LoadRobot(test::SourcePath("robots/pa10/pa10.yaml"));
  RobotState state(model);
  std::mt19937 rng(7);
  kinematics::Matrix6Xd J1, J2;
  for (int trial = 0; trial < 100; ++trial) {
    ForwardKinematics(model, test::RandomConfiguration(model, &rng), &state);
    const int link = model.tool_frame().link;
    kinematics::ComputeJacobian(model, state, link, Eigen::Vector3d::Zero(), &J1);
    kinematics::ComputeJacobian(model, state, link, Eigen::Vector3d(0.3, -0.2, 0.1), &J2);
    EXPECT_TRUE(test::CompareMatrices(J1.topRows<3>(), J2.topRows<3>(), 0.0));
    const Eigen::VectorXd q = state.q;
    const auto fd = FiniteDifferenceJacobian(model, q, link, Eigen::Vector3d::Zero());
    EXPECT_TRUE(test::CompareMatrices(J1.topRows<3>(), fd.topRows<3>(), kTolerance));
    // And not merely up to sign: the rows would match their negation only if they were zero.
    EXPECT_GT(J1.topRows<3>().norm(), 0.5);
    ASSERT_TRUE(ForwardKinematics(model, q, &state).ok());
  }
}

}  // namespace
}  // namespace trocar
