// Forward kinematics plus the full 6×n Jacobian of the 7-DOF PA10-7C: trocar against KDL
// (ChainFkSolverPos_recursive + ChainJntToJacSolver) on the identical chain, in the same run.
// The KDL chain is built from the trocar model's joint origins, and both are checked to give
// the same tool pose and Jacobian before anything is timed.
#include <cstdlib>
#include <iostream>
#include <random>

#include <benchmark/benchmark.h>
#include <kdl/chain.hpp>
#include <kdl/chainfksolverpos_recursive.hpp>
#include <kdl/chainjnttojacsolver.hpp>

#include "kinematics/forward_kinematics.hpp"
#include "kinematics/jacobian.hpp"
#include "kinematics/setup_joints.hpp"
#include "robot/load_robot.hpp"

namespace {

using trocar::robot::RobotModel;

const RobotModel& Pa10() {
  static const RobotModel model =
      trocar::robot::LoadRobot(std::string(TROCAR_SOURCE_DIR) + "/robots/pa10/pa10.yaml");
  return model;
}

KDL::Frame ToKdl(const Eigen::Isometry3d& X) {
  const Eigen::Matrix3d& R = X.linear();
  return KDL::Frame(KDL::Rotation(R(0, 0), R(0, 1), R(0, 2), R(1, 0), R(1, 1), R(1, 2), R(2, 0),
                                  R(2, 1), R(2, 2)),
                    KDL::Vector(X.translation().x(), X.translation().y(), X.translation().z()));
}

// Segment i: joint i about z at its origin, then the constant transform to joint i+1's origin
// (or to the tool for the last one); a fixed first segment carries joint 1's origin.
KDL::Chain ToKdlChain(const RobotModel& model) {
  KDL::Chain chain;
  const auto& active = model.active_joints();
  chain.addSegment(KDL::Segment(KDL::Joint(KDL::Joint::None), ToKdl(model.joint(active[0]).X_PJ)));
  for (std::size_t i = 0; i < active.size(); ++i) {
    const auto& joint = model.joint(active[i]);
    if (joint.axis_J != Eigen::Vector3d::UnitZ()) std::abort();  // DH models turn about z
    const Eigen::Isometry3d tip = i + 1 < active.size() ? model.joint(active[i + 1]).X_PJ
                                                        : model.tool_frame().X_LF;
    chain.addSegment(KDL::Segment(KDL::Joint(KDL::Joint::RotZ), ToKdl(tip)));
  }
  return chain;
}

std::vector<Eigen::VectorXd> Configurations(const RobotModel& model) {
  std::mt19937 rng(42);
  std::vector<Eigen::VectorXd> qs;
  for (int i = 0; i < 1024; ++i) {
    Eigen::VectorXd q(model.num_positions());
    for (int k = 0; k < q.size(); ++k) {
      const auto& l = model.joint(model.active_joints()[k]).limits;
      q[k] = std::uniform_real_distribution<double>(l.lower, l.upper)(rng);
    }
    qs.push_back(q);
  }
  return qs;
}

void CheckSameAnswers() {
  const RobotModel& model = Pa10();
  const KDL::Chain chain = ToKdlChain(model);
  KDL::ChainFkSolverPos_recursive fk(chain);
  KDL::ChainJntToJacSolver jac(chain);
  trocar::robot::RobotState state(model);
  trocar::kinematics::Matrix6Xd J;
  KDL::JntArray q_kdl(model.num_positions());
  KDL::Frame X;
  KDL::Jacobian J_kdl(model.num_positions());
  for (const auto& q : Configurations(model)) {
    trocar::kinematics::ForwardKinematics(model, q, &state);
    trocar::kinematics::ComputeFrameJacobian(model, state, model.tool_frame(), &J);
    q_kdl.data = q;
    fk.JntToCart(q_kdl, X);
    jac.JntToJac(q_kdl, J_kdl);
    const Eigen::Isometry3d X_WT = trocar::kinematics::FramePose(state, model.tool_frame());
    double worst = (X_WT.translation() - Eigen::Vector3d(X.p.x(), X.p.y(), X.p.z())).norm();
    // KDL stacks [v; w], trocar [w; v].
    worst = std::max(worst, (J.topRows<3>() - J_kdl.data.bottomRows<3>()).cwiseAbs().maxCoeff());
    worst = std::max(worst, (J.bottomRows<3>() - J_kdl.data.topRows<3>()).cwiseAbs().maxCoeff());
    if (worst > 1e-12) {
      std::cerr << "trocar and KDL disagree by " << worst << "\n";
      std::exit(1);
    }
  }
}

void BM_Trocar_Pa10_FkJacobian(benchmark::State& bm) {
  const RobotModel& model = Pa10();
  const auto qs = Configurations(model);
  trocar::robot::RobotState state(model);
  trocar::kinematics::Matrix6Xd J(6, model.num_positions());
  std::size_t i = 0;
  for (auto _ : bm) {
    trocar::kinematics::ForwardKinematics(model, qs[i++ & 1023], &state);
    trocar::kinematics::ComputeFrameJacobian(model, state, model.tool_frame(), &J);
    benchmark::DoNotOptimize(J.data());
    benchmark::DoNotOptimize(state.X_WL.back().data());
  }
}
BENCHMARK(BM_Trocar_Pa10_FkJacobian);

void BM_Kdl_Pa10_FkJacobian(benchmark::State& bm) {
  const RobotModel& model = Pa10();
  const auto qs = Configurations(model);
  const KDL::Chain chain = ToKdlChain(model);
  KDL::ChainFkSolverPos_recursive fk(chain);
  KDL::ChainJntToJacSolver jac(chain);
  KDL::JntArray q(model.num_positions());
  KDL::Frame X;
  KDL::Jacobian J(model.num_positions());
  std::size_t i = 0;
  for (auto _ : bm) {
    q.data = qs[i++ & 1023];
    fk.JntToCart(q, X);
    jac.JntToJac(q, J);
    benchmark::DoNotOptimize(J.data.data());
    benchmark::DoNotOptimize(X.p.data);
  }
}
BENCHMARK(BM_Kdl_Pa10_FkJacobian);

void BM_Trocar_Pa10_Fk(benchmark::State& bm) {
  const RobotModel& model = Pa10();
  const auto qs = Configurations(model);
  trocar::robot::RobotState state(model);
  std::size_t i = 0;
  for (auto _ : bm) {
    trocar::kinematics::ForwardKinematics(model, qs[i++ & 1023], &state);
    benchmark::DoNotOptimize(state.X_WL.back().data());
  }
}
BENCHMARK(BM_Trocar_Pa10_Fk);

void BM_Kdl_Pa10_Fk(benchmark::State& bm) {
  const RobotModel& model = Pa10();
  const auto qs = Configurations(model);
  const KDL::Chain chain = ToKdlChain(model);
  KDL::ChainFkSolverPos_recursive fk(chain);
  KDL::JntArray q(model.num_positions());
  KDL::Frame X;
  std::size_t i = 0;
  for (auto _ : bm) {
    q.data = qs[i++ & 1023];
    fk.JntToCart(q, X);
    benchmark::DoNotOptimize(X.p.data);
  }
}
BENCHMARK(BM_Kdl_Pa10_Fk);

// The da Vinci cart (three setup-joint chains, three arms, six closures): posing the whole robot
// against posing one RCM's chain (what the setup-joint solver's inner loop now does), and one
// whole setup-joint solve for PSM1's RCM at a reachable pose (issue #41 item 7).
const RobotModel& Cart() {
  static const RobotModel model = trocar::robot::LoadRobot(
      std::string(TROCAR_SOURCE_DIR) + "/robots/davinci-classic/cart.yaml");
  return model;
}

void BM_Trocar_Cart_FkWholeRobot(benchmark::State& bm) {
  const RobotModel& model = Cart();
  trocar::robot::RobotState state(model);
  (void)trocar::kinematics::SetConfiguration(model, state.q, &state);
  for (auto _ : bm) {
    trocar::kinematics::ForwardKinematics(model, &state);
    benchmark::DoNotOptimize(state.X_WL.back().data());
  }
}
BENCHMARK(BM_Trocar_Cart_FkWholeRobot);

void BM_Trocar_Cart_FkToOneRcm(benchmark::State& bm) {
  const RobotModel& model = Cart();
  trocar::robot::RobotState state(model);
  (void)trocar::kinematics::SetConfiguration(model, state.q, &state);
  const int link = model.GetFrame("psm1_rcm").link;
  for (auto _ : bm) {
    trocar::kinematics::ForwardKinematicsToLink(model, link, &state);
    benchmark::DoNotOptimize(state.X_WL[link].data());
  }
}
BENCHMARK(BM_Trocar_Cart_FkToOneRcm);

void BM_Trocar_Cart_SetupJointSolve(benchmark::State& bm) {
  const RobotModel& model = Cart();
  trocar::robot::RobotState start(model);
  (void)trocar::kinematics::ForwardKinematics(model, start.q, &start);
  trocar::robot::RobotState moved = start;
  for (const char* name : {"psm1_suj_shoulder", "psm1_suj_elbow", "psm1_suj_wrist_2"})
    (void)trocar::kinematics::SetHeldJoint(model, name, 0.4, &moved);
  trocar::kinematics::ForwardKinematics(model, &moved);
  trocar::kinematics::SetupJointRequest request;
  request.frame = "psm1_rcm";
  const Eigen::Isometry3d X_WF = trocar::kinematics::FramePose(moved, model.GetFrame("psm1_rcm"));
  request.p_WF = X_WF.translation();
  request.axis_W = X_WF.linear() * -Eigen::Vector3d::UnitZ();
  trocar::kinematics::SetupJointOptions options;
  options.starts = 8;
  for (auto _ : bm) {
    const auto r = trocar::kinematics::SolveSetupJoints(model, start, request, options);
    benchmark::DoNotOptimize(r.position_error);
  }
}
BENCHMARK(BM_Trocar_Cart_SetupJointSolve)->Unit(benchmark::kMicrosecond);

}  // namespace

int main(int argc, char** argv) {
  CheckSameAnswers();
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
