// Port placement: arms found from the robot description, the problem's bad input, determinism
// across thread counts, plans whose claims hold, and a verdict for a patient no plan serves.
#include <gtest/gtest.h>

#include <memory>
#include <nlohmann/json.hpp>
#include <random>

#include "collision/collision_world.hpp"
#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "patient/patient_model.hpp"
#include "port_placement/arms.hpp"
#include "port_placement/optimizer.hpp"
#include "port_placement/plan_io.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar::planners {
namespace {

using test::SourcePath;

std::shared_ptr<const robot::RobotModel> Cart() {
  static auto cart = std::make_shared<const robot::RobotModel>(
      robot::LoadRobot(SourcePath("robots/davinci-classic/cart.yaml")));
  return cart;
}

std::shared_ptr<const patient::PatientModel> Phantom() {
  static auto patient = std::make_shared<const patient::PatientModel>(
      patient::ImportPatient(SourcePath("patients/phantom-default")));
  return patient;
}

PortPlacementOptions Small(int threads) {
  PortPlacementOptions o;
  o.evaluations = 160;
  o.starts = 4;
  o.polish_evaluations = 16;
  o.top_k = 2;
  o.threads = threads;
  o.time_limit = 600;  // the budget, not the clock, ends the run: results must not depend on speed
  return o;
}

TEST(FindArms, ReadsTheCartsArmsAndRolesFromItsFrames) {
  const auto arms = FindArms(*Cart());
  ASSERT_EQ(arms.size(), 3u);
  int scopes = 0;
  for (const auto& a : arms) {
    EXPECT_FALSE(a.rcm_frame.empty());
    EXPECT_EQ(a.tool_frame, a.name + "_tool");
    EXPECT_GE(a.insertion_q, 0) << a.name;
    EXPECT_GE(a.shaft_link, 0) << a.name;
    // The arm's joints move its tool; the other arms' do not.
    for (int i : a.q_indices)
      EXPECT_EQ(Cart()->joint(Cart()->active_joints()[i]).name.rfind(a.name, 0), 0u);
    scopes += a.role == ArmRole::kEndoscope;
  }
  EXPECT_EQ(scopes, 1);
  EXPECT_EQ(FindArms(*Cart(), {"ecm=instrument"})[2].role, ArmRole::kInstrument);
  EXPECT_THROW(FindArms(*Cart(), {"psm3=endoscope"}), Error);
}

TEST(FindArms, AnArmWithoutAnRcmGetsASoftwareRcmOnItsShaft) {
  const auto robot = robot::LoadRobot(SourcePath("robots/pa10/pa10_instrument.yaml"));
  const auto arms = FindArms(robot);
  ASSERT_EQ(arms.size(), 1u);
  EXPECT_FALSE(arms[0].has_rcm());
  EXPECT_EQ(robot.link(arms[0].shaft_link).name, "rod");
  EXPECT_EQ(arms[0].q_indices.size(), 9u);
  // A plain PA10 has neither an RCM nor a shaft: a clear error.
  try {
    FindArms(robot::LoadRobot(SourcePath("robots/pa10/pa10.yaml")));
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("no RCM frame and no instrument shaft"), std::string::npos)
        << e.what();
  }
}

TEST(PortPlacementProblem, BadInputIsRefusedBeforeAnyWork) {
  auto no_targets = std::make_shared<patient::PatientModel>(*Phantom());
  no_targets->targets.clear();
  try {
    PortPlacementProblem(no_targets, Cart(), {});
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("no targets"), std::string::npos) << e.what();
  }
  auto no_candidates = std::make_shared<patient::PatientModel>(*Phantom());
  no_candidates->port_candidates.clear();
  EXPECT_THROW(PortPlacementProblem(no_candidates, Cart(), {}), Error);
  ProblemOptions unknown_arm;
  unknown_arm.arms = {"psm9"};
  EXPECT_THROW(PortPlacementProblem(Phantom(), Cart(), unknown_arm), Error);

  PortPlacementOptions bad;
  bad.algorithm = "simulated-annealing";
  try {
    ValidateOptions(bad);
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("direct-l, crs2-lm, isres, mlsl, exhaustive"),
              std::string::npos);
  }
  bad = {};
  bad.time_limit = 0;
  EXPECT_THROW(ValidateOptions(bad), Error);
  bad = {};
  bad.local = "newton";
  EXPECT_THROW(ValidateOptions(bad), Error);
}

TEST(PortPlacementProblem, DecodeAndEncodeAgreeAndSitesLieOnTheirCurves) {
  const PortPlacementProblem problem(Phantom(), Cart(), {});
  const auto lb = problem.lower_bounds(), ub = problem.upper_bounds();
  std::mt19937 rng(3);
  for (int trial = 0; trial < 200; ++trial) {
    std::vector<double> x(lb.size());
    for (std::size_t i = 0; i < x.size(); ++i)
      x[i] = std::uniform_real_distribution<double>(lb[i], ub[i])(rng);
    const Placement p = problem.Decode(x);
    const Placement q = problem.Decode(problem.Encode(p));
    ASSERT_EQ(p.sites.size(), 3u);
    for (std::size_t a = 0; a < p.sites.size(); ++a) {
      EXPECT_EQ(p.sites[a].candidate, q.sites[a].candidate);
      EXPECT_LT((p.sites[a].p_W - q.sites[a].p_W).norm(), 1e-9);
      // On the candidate polyline (P frame).
      const auto& curve = Phantom()->port_candidates[p.sites[a].candidate].skin;
      double nearest = 1e9;
      for (std::size_t i = 0; i + 1 < curve.size(); ++i) {
        const Eigen::Vector3d ab = curve[i + 1] - curve[i];
        const double t =
            std::clamp((p.sites[a].p_P - curve[i]).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
        nearest = std::min(nearest, (curve[i] + t * ab - p.sites[a].p_P).norm());
      }
      EXPECT_LT(nearest, 1e-9);
      EXPECT_NEAR((p.sites[a].p_rcm_W - p.sites[a].p_W).norm(), problem.options().rcm_depth, 1e-12);
    }
    EXPECT_NEAR(p.cart_x, q.cart_x, 1e-9);
    EXPECT_NEAR(p.cart_y, q.cart_y, 1e-9);
    EXPECT_NEAR(std::remainder(p.cart_yaw - q.cart_yaw, 2 * M_PI), 0.0, 1e-9);
  }
}

// Each evaluation is a pure function of the placement: the same placement scores the same,
// whatever was evaluated before it in the same workspace.
TEST(PortPlacementProblem, EvaluationIsAPureFunctionOfThePlacement) {
  const PortPlacementProblem problem(Phantom(), Cart(), {});
  Workspace a(problem), b(problem);
  const auto lb = problem.lower_bounds(), ub = problem.upper_bounds();
  std::mt19937 rng(5);
  std::vector<std::vector<double>> xs;
  for (int i = 0; i < 12; ++i) {
    std::vector<double> x(lb.size());
    for (std::size_t k = 0; k < x.size(); ++k)
      x[k] = std::uniform_real_distribution<double>(lb[k], ub[k])(rng);
    xs.push_back(x);
  }
  std::vector<double> forward, backward(xs.size());
  for (const auto& x : xs) forward.push_back(problem.Evaluate(problem.Decode(x), &a).score);
  for (int i = static_cast<int>(xs.size()) - 1; i >= 0; --i)
    backward[i] = problem.Evaluate(problem.Decode(xs[i]), &b).score;
  for (std::size_t i = 0; i < xs.size(); ++i) EXPECT_EQ(forward[i], backward[i]) << i;
}

TEST(OptimizePorts, SameSeedSamePlanWithOneAndTwoThreads) {
  const PortPlacementProblem problem(Phantom(), Cart(), {});
  PlanInputs inputs;
  auto plan_without_run = [&](int threads, unsigned seed) {
    PortPlacementOptions o = Small(threads);
    o.seed = seed;
    nlohmann::json j =
        nlohmann::json::parse(PlanJson(problem, OptimizePorts(problem, o), o, inputs));
    j.erase("run");
    return j.dump();
  };
  const std::string one = plan_without_run(1, 7);
  EXPECT_EQ(one, plan_without_run(2, 7));
  EXPECT_NE(one, plan_without_run(2, 8));  // the seed matters
}

// The unreachable patient: the targets moved 40 cm toward the head, far beyond every candidate
// port and the instruments' insertion. A verdict names why; no crash, no empty plan list.
TEST(OptimizePorts, APatientNoPlanCanServeGetsAVerdictWithTheReason) {
  auto far = std::make_shared<patient::PatientModel>(*Phantom());
  for (auto& t : far->targets) {
    for (auto& p : t.points) p.z() += 0.40;
  }
  const PortPlacementProblem problem(far, Cart(), {});
  const PortPlacementResult result = OptimizePorts(problem, Small(2));
  ASSERT_FALSE(result.plans.empty());
  EXPECT_FALSE(result.verdict.suitable);
  ASSERT_FALSE(result.verdict.reasons.empty());
  EXPECT_NE(result.verdict.summary.find("not suitable"), std::string::npos);
  // Nothing is claimed reached.
  for (const auto& plan : result.plans) {
    for (const auto& r : plan.evaluation.reaches) {
      if (problem.arms()[r.arm].role == ArmRole::kInstrument) EXPECT_FALSE(r.reached);
    }
  }
}

// Every sample a plan calls reached is re-checked here with the robot model and a fresh
// collision checker (not the problem's code): tool tip at the aim, joints in limits, no contact.
TEST(OptimizePorts, ReachedSamplesAreReallyReachedAndCollisionFree) {
  ProblemOptions po;
  po.samples_per_target = 4;
  const PortPlacementProblem problem(Phantom(), Cart(), po);
  PortPlacementOptions o = Small(2);
  o.algorithm = "crs2-lm";
  const PortPlacementResult result = OptimizePorts(problem, o);
  collision::CollisionChecker checker(problem.world());
  int checked = 0;
  for (const auto& plan : result.plans) {
    const Evaluation& ev = plan.evaluation;
    if (ev.status != PlacementStatus::kPlaced) continue;
    for (const auto& r : ev.reaches) {
      const PlanArm& arm = problem.arms()[r.arm];
      if (!r.reached || arm.role != ArmRole::kInstrument) continue;
      robot::RobotState state(problem.robot());
      state.X_WB = plan.placement.X_WB();
      state.joint_values = ev.joint_values;
      Eigen::VectorXd q = ev.q_nominal;
      for (std::size_t c = 0; c < arm.q_indices.size(); ++c) q[arm.q_indices[c]] = r.q_arm[c];
      EXPECT_TRUE(kinematics::LimitViolations(problem.robot(), q).empty());
      ASSERT_TRUE(kinematics::ForwardKinematics(problem.robot(), q, &state).ok);
      const auto& s = problem.samples()[r.sample];
      const Eigen::Vector3d tip =
          kinematics::FramePose(state, problem.robot().GetFrame(arm.tool_frame)).translation();
      EXPECT_LT((tip - (s.p_W + po.standoff * s.n_W)).norm(), po.ik_tolerance + 1e-6);
      checker.SetRobotState(state);
      problem.SetPorts(plan.placement, &checker);
      EXPECT_FALSE(checker.InCollision());
      ++checked;
    }
  }
  RecordProperty("reached_samples_checked", checked);
}

}  // namespace
}  // namespace trocar::planners
