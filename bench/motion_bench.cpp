// Verified motions and batch runs (#14), measured on the bundled phantom:
//  - verifying every target sample of the top plan (one and two instrument arms), 1 and 2
//    threads: the whole verification's wall time, and the RRTConnect median per query;
//  - the validity checker's cost per state (forward kinematics with closures, limits, the
//    collision world with ports), beside the collision check alone;
//  - trocar bench's speed-up from 1 to 2 threads on a spec's motion runs.
// Usage: motion_bench [CASE] [OUT_DIR]
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <random>

#include "bench/runner.hpp"
#include "bench/spec.hpp"
#include "collision/collision_world.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "motion/verify.hpp"
#include "patient/patient_model.hpp"
#include "port_placement/optimizer.hpp"
#include "robot/load_robot.hpp"

using namespace trocar;
using namespace trocar::planners;
using Clock = std::chrono::steady_clock;

namespace {

double Seconds(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  const std::string source = TROCAR_SOURCE_DIR;
  const std::string case_dir = argc > 1 ? argv[1] : source + "/patients/phantom-default";
  const std::string out = argc > 2 ? argv[2] : "out/motion_bench";
  std::filesystem::create_directories(out);
  auto robot = std::make_shared<const robot::RobotModel>(
      robot::LoadRobot(source + "/robots/davinci-classic/cart.yaml"));
  auto patient =
      patient::ImportCase(case_dir).model;
  std::cout << std::fixed;
  for (const std::vector<std::string>& arms :
       {std::vector<std::string>{"psm1"}, std::vector<std::string>{"psm1", "psm2"}}) {
    ProblemOptions po;
    po.arms = arms;
    const PortPlacementProblem problem(patient, robot, po);
    PortPlacementOptions o;
    o.robustness_shift = 0.0;
    o.top_k = 1;
    const PortPlacementResult result = OptimizePorts(problem, o);
    const RankedPlan& plan = result.plans.front();
    std::cout << "\narms " << arms.size() << " (" << problem.samples().size()
              << " target samples): top plan " << ToString(plan.evaluation.status) << ", score "
              << std::setprecision(3) << plan.evaluation.score << "\n";
    if (plan.evaluation.status != PlacementStatus::kPlaced) continue;
    for (int threads : {1, 2}) {
      MotionOptions mo;
      const auto t0 = Clock::now();
      const PlanVerification v = VerifyPlan(problem, plan, mo, 0.8, threads);
      const double wall = Seconds(t0);
      std::vector<double> planning;
      int solved = 0;
      for (const auto& m : v.motions) {
        if (m.status == MotionStatus::kExactSolution || m.status == MotionStatus::kTimeout)
          planning.push_back(m.planning_time);
        solved += m.solved;
      }
      std::cout << "  verify all targets, " << threads << " thread" << (threads > 1 ? "s" : " ")
                << ": " << std::setprecision(2) << wall << " s for " << v.motions.size()
                << " queries (" << solved << " solved); RRTConnect median "
                << std::setprecision(1) << Median(planning) * 1e3 << " ms per planned query; "
                << v.states_checked << " states checked\n";
    }
    // The validity checker per state, against the collision check alone, over random states of
    // the first arm around its start.
    const MotionProblem mp(problem, plan.placement, plan.evaluation);
    MotionContext context(mp);
    const PlanArm& arm = problem.arms()[0];
    std::mt19937 rng(1);
    const int n = 4000;
    std::vector<Eigen::VectorXd> qs;
    for (int i = 0; i < n; ++i) {
      Eigen::VectorXd q = plan.evaluation.q_nominal;
      for (int c : arm.q_indices) {
        const double lo = robot->lower_limits()[c], hi = robot->upper_limits()[c];
        q[c] = std::uniform_real_distribution<double>(lo, hi)(rng);
      }
      qs.push_back(q);
    }
    int valid = 0;
    auto t0 = Clock::now();
    for (const auto& q : qs) valid += context.Valid(q);
    const double per_state = Seconds(t0) / n;
    robot::RobotState state(*robot);
    state.X_WB = plan.placement.X_WB();
    state.joint_values = plan.evaluation.joint_values;
    collision::CollisionChecker checker(problem.world());
    std::vector<robot::RobotState> states;
    for (const auto& q : qs) {
      kinematics::ForwardKinematics(*robot, q, &state);
      states.push_back(state);
    }
    t0 = Clock::now();
    int free = 0;
    for (const auto& s : states) {
      checker.SetRobotState(s);
      problem.SetPorts(plan.placement, s, &checker);
      free += !checker.InCollision();
    }
    const double collision_only = Seconds(t0) / n;
    std::cout << "  validity checker: " << std::setprecision(1) << per_state * 1e6
              << " us per state (" << valid << " of " << n
              << " random states valid); the collision check alone " << collision_only * 1e6
              << " us\n";
  }
  // Batch speed-up: the bundled CI spec's runs at 1 and 2 threads, each into a fresh database.
  BenchSpec spec =
      ReadBenchSpec(source + "/bench/specs/ci.yaml", source + "/robots/davinci-classic/cart.yaml");
  spec.name = "speedup";
  spec.motion_seeds = {1, 2, 3, 4, 5, 6};
  double times[3] = {0, 0, 0};
  for (int threads : {1, 2}) {
    const std::string db = out + "/speedup_" + std::to_string(threads) + ".db";
    std::filesystem::path base(db);
    for (const auto& entry : std::filesystem::directory_iterator(out)) {
      if (entry.path().filename().string().rfind(base.stem().string(), 0) == 0)
        std::filesystem::remove(entry.path());
    }
    BenchOptions bo;
    bo.threads = threads;
    const auto t0 = Clock::now();
    const BenchReport r = RunBench(spec, db, bo);
    times[threads] = Seconds(t0);
    std::cout << "\nbench " << spec.name << ": " << r.added << " runs in " << std::setprecision(2)
              << times[threads] << " s on " << threads << " thread" << (threads > 1 ? "s" : "");
  }
  std::cout << "\nbench speed-up 1 -> 2 threads: " << std::setprecision(2) << times[1] / times[2]
            << "x (" << omp_get_num_procs() << " cores)\n";
  return 0;
}
