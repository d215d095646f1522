#include <functional>
#include <random>

#include <Eigen/QR>
#include <Eigen/SVD>
#include <gtest/gtest.h>

#include "control/control_loop.hpp"
#include "control/controller.hpp"
#include "control/joint_limits.hpp"
#include "control/task_error.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

using control::TaskTarget;
using control::Vector6d;
using robot::RobotModel;
using robot::RobotState;

const RobotModel& Pa10() {
  static const RobotModel model = robot::LoadRobot(test::SourcePath("robots/pa10/pa10.yaml"));
  return model;
}
const RobotModel& Psm() {
  static const RobotModel model =
      robot::LoadRobot(test::SourcePath("robots/davinci-classic/psm.yaml"));
  return model;
}
Eigen::VectorXd Pa10Start() {
  Eigen::VectorXd q(7);
  q << 0.1, 0.5, 0.0, 1.2, 0.0, 0.8, 0.0;
  return q;
}
Eigen::VectorXd PsmStart() {
  Eigen::VectorXd q(7);
  q << 0.1, -0.2, 0.12, 0.3, 0.1, -0.1, 0.2;
  return q;
}

TEST(TaskError, LuhErrorIsTwiceSineTimesAxis) {
  std::mt19937 rng(1);
  std::normal_distribution<double> g;
  std::uniform_real_distribution<double> angle(0.0, M_PI);
  for (int i = 0; i < 1000; ++i) {
    const Eigen::Vector3d axis = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
    const double theta = angle(rng);
    const Eigen::Matrix3d R_c = Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
    const Eigen::Matrix3d R_d = Eigen::AngleAxisd(theta, axis).toRotationMatrix() * R_c;
    EXPECT_TRUE(test::CompareMatrices(control::OrientationError(R_d, R_c),
                                      2.0 * std::sin(theta) * axis, 1e-12));
    EXPECT_NEAR(control::AngleBetween(R_d, R_c), theta, 1e-7);
  }
}

// ---- Conformance suite: every controller passes the same properties. -----------------------

const RobotModel& Pa10Instrument() {
  static const RobotModel model =
      robot::LoadRobot(test::SourcePath("robots/pa10/pa10_instrument.yaml"));
  return model;
}

// A controller for a robot, made for a start configuration q (the software RCM puts its port
// where the shaft is at q, 0.1 m above the wrist).
struct ControllerCase {
  const char* name;
  const RobotModel& (*robot)();
  std::function<std::unique_ptr<control::Controller>(const RobotModel&, const Eigen::VectorXd& q)> make;
};

Vector6d TestGains() { return (Vector6d() << 20, 20, 20, 40, 40, 40).finished(); }

std::unique_ptr<control::Controller> MakeRcm(const RobotModel& model, const Eigen::VectorXd& q) {
  RobotState state(model);
  kinematics::ForwardKinematics(model, q, &state);
  const int rod = model.GetLink("rod");
  const Eigen::Vector3d p_WR = state.X_WL[rod] * Eigen::Vector3d(0, 0, -0.1);
  return std::make_unique<control::SoftwareRcmController>(TestGains(), rod, Eigen::Vector3d(0, 0, -0.35), p_WR);
}

class ControllerConformance : public ::testing::TestWithParam<ControllerCase> {
 protected:
  const RobotModel& model() const { return GetParam().robot(); }
  Eigen::VectorXd Home() const { return model().defaults().home; }
};

TEST_P(ControllerConformance, ZeroErrorLeavesTheToolStill) {
  RobotState state(model());
  std::mt19937 rng(2);
  control::ControllerWorkspace ws;
  Eigen::VectorXd qdot;
  kinematics::Matrix6Xd J;
  for (int trial = 0; trial < 200; ++trial) {
    const Eigen::VectorXd q = 0.8 * test::RandomConfiguration(model(), &rng);
    const auto controller = GetParam().make(model(), q);
    kinematics::ForwardKinematics(model(), q, &state);
    TaskTarget target;
    target.X_WD = kinematics::FramePose(state, model().tool_frame());
    controller->ComputeVelocity(model(), state, target, &ws, &qdot);
    ASSERT_TRUE(qdot.allFinite());
    kinematics::ComputeFrameJacobian(model(), state, model().tool_frame(), &J);
    EXPECT_LT((J * qdot).norm(), 1e-6) << "q = " << q.transpose();
  }
}

TEST_P(ControllerConformance, MovesTheToolTowardTheTarget) {
  RobotState state(model());
  std::mt19937 rng(3);
  std::normal_distribution<double> g(0.0, 0.01);
  control::ControllerWorkspace ws;
  Eigen::VectorXd qdot;
  kinematics::Matrix6Xd J;
  for (int trial = 0; trial < 200; ++trial) {
    const Eigen::VectorXd q = 0.8 * test::RandomConfiguration(model(), &rng);  // off the limits
    const auto controller = GetParam().make(model(), q);
    kinematics::ForwardKinematics(model(), q, &state);
    TaskTarget target;
    target.X_WD = kinematics::FramePose(state, model().tool_frame());
    target.X_WD.translation() += Eigen::Vector3d(g(rng), g(rng), g(rng));
    target.X_WD.linear() = Eigen::AngleAxisd(0.05, Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized()) *
                           target.X_WD.linear();
    controller->ComputeVelocity(model(), state, target, &ws, &qdot);
    kinematics::ComputeFrameJacobian(model(), state, model().tool_frame(), &J);
    const Vector6d e = control::TaskError(target.X_WD, kinematics::FramePose(state, model().tool_frame()));
    EXPECT_GT(e.dot(J * qdot), 0.0) << "q = " << q.transpose();
  }
}

TEST_P(ControllerConformance, StaysFiniteAtASingularity) {
  RobotState state(model());
  const Eigen::VectorXd q = Eigen::VectorXd::Zero(model().num_positions());  // arm straight up
  const auto controller = GetParam().make(model(), q);
  kinematics::ForwardKinematics(model(), q, &state);
  TaskTarget target;
  target.X_WD = kinematics::FramePose(state, model().tool_frame());
  target.X_WD.translation() += Eigen::Vector3d(0, 0, 0.05);  // further up: unreachable direction
  control::ControllerWorkspace ws;
  Eigen::VectorXd qdot;
  controller->ComputeVelocity(model(), state, target, &ws, &qdot);
  EXPECT_TRUE(qdot.allFinite());
  EXPECT_LT(qdot.norm(), 1e3);
}

TEST_P(ControllerConformance, ConvergesOnAStep) {
  // The robot of the case, and (for controllers that need no port) the PSM too.
  std::vector<const RobotModel*> robots = {&model()};
  if (std::string(GetParam().name) != "rcm") robots.push_back(&Psm());
  for (const RobotModel* robot : robots) {
    SCOPED_TRACE(robot->name());
    const Eigen::VectorXd q0 = robot->defaults().home;
    control::ControlLoop loop(*robot, GetParam().make(*robot, q0), q0);
    TaskTarget target;
    target.X_WD = loop.ToolPose();
    target.X_WD.translation() += Eigen::Vector3d(0.01, -0.008, 0.006);  // a 14 mm step
    target.X_WD.linear() = Eigen::AngleAxisd(0.15, Eigen::Vector3d(1, 2, -1).normalized()) *
                           target.X_WD.linear();  // and 8.6 deg
    control::StepReport report;
    for (int step = 0; step < 20000; ++step) {  // up to 20 s at 1 kHz
      report = loop.Step(target, 1e-3);
      if (report.position_error < 1e-4 && report.orientation_error < 0.1 * M_PI / 180) break;
    }
    EXPECT_LT(report.position_error, 1e-4);
    EXPECT_LT(report.orientation_error, 0.1 * M_PI / 180);
  }
}

INSTANTIATE_TEST_SUITE_P(
    AllControllers, ControllerConformance,
    ::testing::Values(
        ControllerCase{"jt", &Pa10, [](const RobotModel& m, const Eigen::VectorXd&) { return control::MakeController("jt", m, TestGains()); }},
        ControllerCase{"dls", &Pa10, [](const RobotModel& m, const Eigen::VectorXd&) { return control::MakeController("dls", m, TestGains()); }},
        ControllerCase{"jla", &Pa10, [](const RobotModel& m, const Eigen::VectorXd&) { return control::MakeController("jla", m, TestGains()); }},
        ControllerCase{"rcm", &Pa10Instrument, &MakeRcm}),
    [](const ::testing::TestParamInfo<ControllerCase>& info) { return std::string(info.param.name); });

// The damped least-squares step against its definition, computed independently through an SVD:
// q̇ = Jᵀ (J Jᵀ + λ² I)⁻¹ v with λ² = (1 − (σ_min / σ₀)²) λ_max² below σ₀, 0 above. Seeded random
// configurations of the PA10 and the PSM, some moved toward the PA10's stretched singularity so
// that the damping is exercised; all six rows and the position rows alone; each from the last
// one's warm start, as far from it as random configurations are. A wrong inverse, a smallest
// singular value off by more than ~1e-7 (an inverse iteration stopped when two estimates merely
// agree to 1e-4 was off by 1e-3 here) or damping on the wrong side of σ₀ fails it.
TEST(DampedLeastSquares, StepEqualsTheSvdDefinitionOverRandomAndNearSingularConfigurations) {
  constexpr double kMaxDamping = 0.05, kThreshold = 0.05, kTol = 1e-9;
  const control::DampedLeastSquaresController controller(TestGains(), kMaxDamping, kThreshold);
  std::mt19937 rng(18);
  int damped = 0, undamped = 0;
  for (const RobotModel* model : {&Pa10(), &Psm()}) {
    const Eigen::VectorXd lower = model->lower_limits(), upper = model->upper_limits();
    RobotState state(*model);
    control::ControllerWorkspace ws;
    for (int trial = 0; trial < 200; ++trial) {
      Eigen::VectorXd q = model->defaults().home;
      const double shrink = model == &Pa10() && trial % 2 == 0 ? std::pow(0.5, trial % 20) : 1.0;
      for (int i = 0; i < q.size(); ++i) {
        const double lo = std::max(lower[i], -2.0), hi = std::min(upper[i], 2.0);
        const double u = std::uniform_real_distribution<double>(lo, hi)(rng);
        q[i] = model == &Pa10() ? shrink * u : u;  // PA10 toward q = 0, straight up (singular)
      }
      if (!kinematics::ForwardKinematics(*model, q, &state).ok()) continue;
      TaskTarget target;
      target.X_WD = kinematics::FramePose(state, model->tool_frame());
      target.X_WD.translation() += Eigen::Vector3d(0.004, -0.003, 0.002);
      target.X_WD.linear() = Eigen::AngleAxisd(0.05, Eigen::Vector3d(1, -2, 1).normalized()) *
                             target.X_WD.linear();
      target.V_WD << 0.01, -0.02, 0.03, 0.004, 0.002, -0.001;
      target.position_only = trial % 3 == 0;
      Eigen::VectorXd qdot;
      controller.ComputeVelocity(*model, state, target, &ws, &qdot);

      kinematics::Matrix6Xd J;
      kinematics::ComputeFrameJacobian(*model, state, model->tool_frame(), &J);
      const Vector6d v = target.V_WD + TestGains().asDiagonal() *
                                           control::TaskError(target.X_WD, kinematics::FramePose(state, model->tool_frame()));
      const int rows = target.position_only ? 3 : 6;
      const Eigen::MatrixXd Jr = J.bottomRows(rows);
      const Eigen::VectorXd vr = v.tail(rows);
      const Eigen::JacobiSVD<Eigen::MatrixXd> svd(Jr);
      const double sigma_min = svd.singularValues()[rows - 1];
      double lambda2 = 0.0;
      if (sigma_min < kThreshold) {
        const double ratio = sigma_min / kThreshold;
        lambda2 = (1.0 - ratio * ratio) * kMaxDamping * kMaxDamping;
        ++damped;
      } else {
        ++undamped;
      }
      const Eigen::MatrixXd A =
          Jr * Jr.transpose() + (lambda2 + 1e-12) * Eigen::MatrixXd::Identity(rows, rows);
      const Eigen::VectorXd expected = Jr.transpose() * A.ldlt().solve(vr);
      ASSERT_TRUE(qdot.allFinite());
      EXPECT_LE((qdot - expected).norm(), kTol * std::max(1.0, expected.norm()))
          << model->name() << " trial " << trial << ", σ_min " << sigma_min << "\n  got      "
          << qdot.transpose() << "\n  expected " << expected.transpose();
    }
  }
  // Both sides of the threshold were exercised.
  EXPECT_GT(damped, 10);
  EXPECT_GT(undamped, 100);
}

TEST(SoftwareRcm, KeepsTheShaftThroughThePortWhileTheToolMoves) {
  const RobotModel& model = Pa10Instrument();
  const Eigen::VectorXd q0 = model.defaults().home;
  auto rcm = MakeRcm(model, q0);
  const auto* controller = static_cast<const control::SoftwareRcmController*>(rcm.get());
  control::ControlLoop loop(model, std::move(rcm), q0);
  const Eigen::Isometry3d X0 = loop.ToolPose();
  double worst_rcm = 0.0;
  TaskTarget target;
  // A 15 mm circle about the start, 2 s per turn, fading in over the first second (a hand starts
  // at rest), with its velocity fed forward as a teleoperation session does.
  auto circle = [&](double t) {
    const double x = std::min(1.0, t), fade = x * x * x * (x * (6 * x - 15) + 10);
    const double phase = 2 * M_PI * t / 2.0;
    return Eigen::Vector3d(0.015 * fade * (std::cos(phase) - 1.0), 0.015 * fade * std::sin(phase), 0.0);
  };
  for (int step = 0; step < 6000; ++step) {
    const double t = step * 1e-3;
    target.X_WD = X0;
    target.X_WD.translation() += circle(t);
    target.V_WD.tail<3>() = (circle(t + 1e-6) - circle(t - 1e-6)) / 2e-6;
    loop.Step(target, 1e-3);
    worst_rcm = std::max(worst_rcm, controller->RcmError(model, loop.state()));
  }
  EXPECT_LT(worst_rcm, 1e-3);  // the shaft never leaves the port by more than 1 mm
  // And the tool followed.
  const auto final_report = loop.Step(target, 1e-3);
  EXPECT_LT(final_report.position_error, 2e-3);
}

// ---- Limits ---------------------------------------------------------------------------------

TEST(JointLimits, NoJointEverExceedsItsLimitsUnderAggressiveInput) {
  // 10 s at 1 kHz of a target jumping 0.5 m and 90 deg at random every 50 ms, with large gains:
  // position, velocity and acceleration limits must all hold at every step.
  for (const RobotModel* model : {&Pa10(), &Psm()}) {
    SCOPED_TRACE(model->name());
    const Vector6d gains = (Vector6d() << 500, 500, 500, 2000, 2000, 2000).finished();
    for (const char* name : {"jt", "dls", "jla"}) {
      SCOPED_TRACE(name);
      const Eigen::VectorXd q0 = model == &Pa10() ? Pa10Start() : PsmStart();
      control::ControlLoop loop(*model, control::MakeController(name, *model, gains), q0);
      std::mt19937 rng(4);
      std::normal_distribution<double> g;
      const Eigen::Isometry3d X0 = loop.ToolPose();
      TaskTarget target;
      target.X_WD = X0;
      const Eigen::VectorXd lo = model->lower_limits(), hi = model->upper_limits();
      const Eigen::VectorXd vmax = model->velocity_limits(), amax = model->acceleration_limits();
      Eigen::VectorXd qdot_prev = Eigen::VectorXd::Zero(model->num_positions());
      const double dt = 1e-3;
      int limited = 0;
      for (int step = 0; step < 10000; ++step) {
        if (step % 50 == 0) {
          target.X_WD.translation() = X0.translation() + 0.3 * Eigen::Vector3d(g(rng), g(rng), g(rng));
          target.X_WD.linear() = Eigen::AngleAxisd(1.5 * g(rng), Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized()) * X0.linear();
        }
        const auto report = loop.Step(target, dt);
        limited += report.limits.position_limited + report.limits.velocity_limited +
                   report.limits.acceleration_limited;
        const Eigen::VectorXd& q = loop.state().q;
        const Eigen::VectorXd& qdot = loop.qdot();
        for (int i = 0; i < q.size(); ++i) {
          ASSERT_GE(q[i], lo[i]) << "joint " << i << " step " << step;
          ASSERT_LE(q[i], hi[i]) << "joint " << i << " step " << step;
          ASSERT_LE(std::abs(qdot[i]), vmax[i] * (1 + 1e-12)) << "joint " << i << " step " << step;
          ASSERT_LE(std::abs(qdot[i] - qdot_prev[i]), amax[i] * dt * (1 + 1e-9))
              << "joint " << i << " step " << step;
        }
        qdot_prev = qdot;
      }
      EXPECT_GT(limited, 100);  // the input really was aggressive
    }
  }
}

// What a tool motion asks of the joints' velocity limits: against the least-squares joint rates
// computed independently (complete orthogonal decomposition) over seeded configurations and
// velocities of the PA10; the share scales with the motion; a still tool asks nothing.
TEST(JointLimits, VelocityDemandIsTheLeastSquaresJointRatesShareOfTheLimits) {
  const RobotModel& model = Pa10();
  std::mt19937 rng(7);
  std::normal_distribution<double> normal;
  const Eigen::VectorXd limits = model.velocity_limits();
  for (int trial = 0; trial < 50; ++trial) {
    RobotState state(model);
    Eigen::VectorXd q = Pa10Start();
    for (int i = 0; i < q.size(); ++i) q[i] += 0.3 * normal(rng);
    q = q.cwiseMax(model.lower_limits()).cwiseMin(model.upper_limits());
    ASSERT_TRUE(kinematics::ForwardKinematics(model, q, &state).ok());
    std::vector<Vector6d> V(3);
    for (auto& v : V) v << 0.2 * normal(rng), 0.2 * normal(rng), 0.2 * normal(rng), 0.1 * normal(rng), 0.1 * normal(rng), 0.1 * normal(rng);
    for (bool position_only : {false, true}) {
      const control::VelocityDemand demand = control::JointVelocityDemand(model, state, V, position_only);
      kinematics::Matrix6Xd J;
      kinematics::ComputeFrameJacobian(model, state, model.tool_frame(), &J);
      const Eigen::MatrixXd Jr = position_only ? Eigen::MatrixXd(J.bottomRows<3>()) : Eigen::MatrixXd(J);
      const Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd> cod(Jr);
      double worst = 0.0, speed = 0.0;
      for (const auto& v : V) {
        speed = std::max(speed, v.tail<3>().norm());
        const Eigen::VectorXd rates = cod.solve(position_only ? Eigen::VectorXd(v.tail<3>()) : Eigen::VectorXd(v));
        worst = std::max(worst, (rates.cwiseAbs().array() / limits.array()).maxCoeff());
      }
      EXPECT_NEAR(demand.share, worst, 1e-9 * worst) << "trial " << trial;
      EXPECT_NEAR(demand.rate, demand.share * limits[demand.joint], 1e-12);
      EXPECT_DOUBLE_EQ(demand.peak_tool_speed, speed);
      std::vector<Vector6d> doubled = V;
      for (auto& v : doubled) v *= 2.0;
      EXPECT_NEAR(control::JointVelocityDemand(model, state, doubled, position_only).share, 2.0 * demand.share,
                  1e-9 * demand.share);
    }
    const std::vector<Vector6d> still(4, Vector6d::Zero());
    EXPECT_EQ(control::JointVelocityDemand(model, state, still, false).share, 0.0);
  }
}

TEST(JointLimits, BrakingSpeedStopsExactlyAtTheLimit) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> dist(0.0, 0.5), acc(0.5, 50.0);
  for (int trial = 0; trial < 1000; ++trial) {
    const double d = dist(rng), a = acc(rng), dt = 1e-3;
    double v = control::BrakingSpeed(d, a, dt), x = 0.0;
    while (v > 0) {
      x += v * dt;
      v -= a * dt;
    }
    EXPECT_LE(x, d * (1 + 1e-12) + 1e-15);
    EXPECT_GT(x, d - a * dt * dt - 1e-12);  // and not needlessly early
  }
}

// The cheap test used before BrakingSpeed is sound: whenever it says a speed can stop within a
// distance, simulating the braking steps stops within it; and it says so for most speeds well
// inside the bound (else it would save nothing).
TEST(JointLimits, CanStopWithinIsASoundShortcut) {
  std::mt19937 rng(8);
  std::uniform_real_distribution<double> dist(0.0, 0.5), acc(0.5, 50.0), speed(0.0, 3.0);
  int accepted = 0;
  for (int trial = 0; trial < 20000; ++trial) {
    const double d = dist(rng), a = acc(rng), dt = 1e-3, v0 = speed(rng);
    if (!control::CanStopWithin(v0, d, a, dt)) continue;
    ++accepted;
    double v = v0, x = 0.0;
    while (v > 0) {
      x += v * dt;
      v -= a * dt;
    }
    ASSERT_LE(x, d) << "v " << v0 << " d " << d << " a " << a;
    ASSERT_LE(v0, control::BrakingSpeed(d, a, dt) * (1 + 1e-12) + 1e-15);
  }
  EXPECT_GT(accepted, 5000);
  EXPECT_FALSE(control::CanStopWithin(1.0, 0.0, 10.0, 1e-3));  // at the limit: never
  EXPECT_TRUE(control::CanStopWithin(0.0, 1e-9, 10.0, 1e-3));
  EXPECT_TRUE(control::CanStopWithin(1.0, 1.0, HUGE_VAL, 1e-3));
  EXPECT_FALSE(control::CanStopWithin(2000.0, 1.0, HUGE_VAL, 1e-3));  // a step beyond it
}

// ---- Orientation beyond 180 degrees ---------------------------------------------------------

TEST(Tracking, ARotationOfMoreThan180DegreesIsFollowed) {
  // The desired orientation turns 200 deg about the roll axis over 6 s; rotation matrices
  // (not Euler angles) let the controller follow it continuously.
  for (const RobotModel* model : {&Pa10(), &Psm()}) {
    SCOPED_TRACE(model->name());
    const Eigen::VectorXd q0 = model == &Pa10() ? Pa10Start() : PsmStart();
    control::ControlLoop loop(*model, control::MakeController("dls", *model, TestGains()), q0);
    const Eigen::Isometry3d X0 = loop.ToolPose();
    // PA10: about the flange axis (W2); PSM: about the instrument shaft (roll).
    const int roll_joint = model == &Pa10() ? 6 : 3;
    const robot::Joint& roll = model->joint(model->active_joints()[roll_joint]);
    const Eigen::Vector3d axis =
        loop.state().X_WL[roll.child_link].linear() * roll.axis_J;
    const double total = 200.0 * M_PI / 180.0, duration = 6.0, dt = 1e-3;
    double worst = 0.0;
    TaskTarget target;
    for (int step = 1; step <= int(duration / dt) + 2000; ++step) {
      const double angle = std::min(1.0, step * dt / duration) * total;
      target.X_WD = X0;
      target.X_WD.linear() = Eigen::AngleAxisd(angle, axis) * X0.linear();
      const auto report = loop.Step(target, dt);
      worst = std::max(worst, report.orientation_error);
    }
    const auto final_report = loop.Step(target, dt);
    EXPECT_LT(final_report.orientation_error, 0.1 * M_PI / 180);
    EXPECT_LT(final_report.position_error, 1e-4);
    EXPECT_LT(worst, 5.0 * M_PI / 180);  // it followed: never more than a few degrees behind
    // The PSM has one way to do it, its roll joint; the redundant PA10 shares it among joints.
    if (model == &Psm()) {
      EXPECT_NEAR(loop.state().q[roll_joint] - q0[roll_joint], total, 0.01);
    }
  }
}

}  // namespace
}  // namespace trocar
