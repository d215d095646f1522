// Collision benchmark (a small harness: per-configuration times, so median and p90 are exact):
// the da Vinci cart placed at a patient's ports (the bundled phantom, about 10^5 triangles) and
// two sets of seeded configurations:
//   around the placement  arm joints within a third of their range around the placed ones (the
//                         plain default placement collides, so these all collide: early exits);
//   free near the patient setup and arm joints anywhere in their limits, kept when nothing
//                         collides and the robot is within 10 cm of the patient: every pair must
//                         be screened, the cost a planner pays on a valid configuration.
// Measured per configuration, after the link poses are known:
//   whole-cart check  SetRobotState + InCollision (all pair classes, first hit stops)
//   all pairs         SetRobotState + Check (every colliding pair with a contact point)
//   arm-patient dist  SetRobotState + MinimumDistance(arm-patient, instrument-patient)
// with OBBRSS and OBB trees side by side (distance needs OBBRSS), and the peer: the same world
// answered by FCL alone for every pair (WorldOptions::exact_mesh_queries = false), on the first
// 50 configurations of each set (its mesh distances cost tens of milliseconds).
//
//   build/bench/collision_bench [patients/<case>] [configurations]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <iostream>
#include <random>
#include <string>

#include "collision/collision_world.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "patient/patient_model.hpp"
#include "port_placement/cart_placement.hpp"
#include "robot/load_robot.hpp"

using namespace trocar;
using Clock = std::chrono::steady_clock;

namespace {

struct Stats {
  double median = 0, p90 = 0, mean = 0;
};

Stats Summarise(std::vector<double> us) {
  std::sort(us.begin(), us.end());
  Stats s;
  s.median = us[us.size() / 2];
  s.p90 = us[static_cast<std::size_t>(0.9 * (us.size() - 1))];
  for (double x : us) s.mean += x / us.size();
  return s;
}

template <typename F>
Stats Time(const std::vector<robot::RobotState>& states, collision::CollisionChecker& checker,
           F query) {
  std::vector<double> us;
  for (int rep = 0; rep < 2; ++rep) {  // the first pass warms caches; the second is kept
    us.clear();
    for (const auto& s : states) {
      const auto t0 = Clock::now();
      checker.SetRobotState(s);
      query(checker);
      us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count());
    }
  }
  return Summarise(us);
}

}  // namespace

int main(int argc, char** argv) {
  const std::string case_dir =
      argc > 1 ? argv[1] : std::string(TROCAR_SOURCE_DIR) + "/patients/phantom-default";
  const int n = argc > 2 ? std::atoi(argv[2]) : 2000;
  const patient::PatientModel patient = patient::ImportPatient(case_dir);
  auto cart = std::make_shared<const robot::RobotModel>(
      robot::LoadRobot(std::string(TROCAR_SOURCE_DIR) + "/robots/davinci-classic/cart.yaml"));
  planners::CartPlacementRequest setup = planners::DefaultPorts(patient, planners::FindArms(*cart));
  robot::RobotState placed(*cart);
  const auto placement = planners::PlaceCartAutomatically(*cart, &setup, {}, &placed);
  std::printf(
      "patient %s: %ld triangles; cart placed: %s\n", patient.name.c_str(),
      patient.triangle_count(),
      placement.ok() ? "every port reached" : "nearest placement (not every port reached)");

  std::mt19937 rng(7);
  std::vector<robot::RobotState> states;
  while (static_cast<int>(states.size()) < n) {
    robot::RobotState s = placed;
    Eigen::VectorXd q = placed.q;
    for (int i = 0; i < q.size(); ++i) {
      const auto& lim = cart->joint(cart->active_joints()[i]).limits;
      const double third = (lim.upper - lim.lower) / 6;
      q[i] = std::clamp(q[i] + std::uniform_real_distribution<double>(-third, third)(rng),
                        lim.lower, lim.upper);
    }
    if (kinematics::ForwardKinematics(*cart, q, &s).ok()) states.push_back(s);
  }
  const unsigned robot_patient = collision::Bit(collision::PairClass::kArmPatient) |
                                 collision::Bit(collision::PairClass::kInstrumentPatient);
  // Collision-free configurations near the patient.
  std::vector<robot::RobotState> free_states;
  int attempts = 0;
  {
    const auto world = collision::CollisionWorld::Build(&patient, cart);
    collision::CollisionChecker checker(world);
    auto uniform = [&](const robot::JointLimits& lim) {
      const double lo = std::isfinite(lim.lower) ? lim.lower : -M_PI;
      const double hi = std::isfinite(lim.upper) ? lim.upper : M_PI;
      return std::uniform_real_distribution<double>(lo, hi)(rng);
    };
    while (static_cast<int>(free_states.size()) < n && attempts < 400 * n) {
      ++attempts;
      robot::RobotState s = placed;
      for (int j : cart->dof_joints()) {
        if (cart->joint(j).drive == robot::JointDrive::kHeld)
          s.joint_values[cart->joint(j).dof_index] = uniform(cart->joint(j).limits);
      }
      Eigen::VectorXd q(cart->num_positions());
      for (int i = 0; i < q.size(); ++i)
        q[i] = uniform(cart->joint(cart->active_joints()[i]).limits);
      if (!kinematics::ForwardKinematics(*cart, q, &s).ok()) continue;
      checker.SetRobotState(s);
      if (checker.InCollision()) continue;
      if (checker.MinimumDistance(robot_patient).distance > 0.10) continue;
      free_states.push_back(s);
    }
  }
  std::printf(
      "%d configurations around the placement; %zu collision-free near the patient (of %d tried)\n",
      n, free_states.size(), attempts);
  std::printf("times per configuration in microseconds\n\n");
  std::printf("%-11s %-48s %10s %10s %10s %10s\n", "bvh", "query", "median", "p90", "mean", "hits");
  struct Variant {
    collision::BvhKind kind;
    bool exact;
  };
  for (const Variant variant :
       {Variant{collision::BvhKind::kObbRss, true}, Variant{collision::BvhKind::kObb, true},
        Variant{collision::BvhKind::kObbRss, false}}) {
    const auto kind = variant.kind;
    collision::WorldOptions options;
    options.bvh = kind;
    options.exact_mesh_queries = variant.exact;
    const std::string label =
        std::string(collision::ToString(kind)) + (variant.exact ? "" : " FCL");
    const std::size_t count =
        variant.exact ? states.size() : std::min<std::size_t>(50, states.size());
    const std::vector<robot::RobotState> around(states.begin(), states.begin() + count);
    const std::vector<robot::RobotState> free_set(
        free_states.begin(), free_states.begin() + std::min(count, free_states.size()));
    const auto t0 = Clock::now();
    const auto world = collision::CollisionWorld::Build(&patient, cart, options);
    const double build_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    collision::CollisionChecker checker(world);
    auto row = [&](const char* query, const Stats& st, const std::string& hits) {
      std::printf("%-11s %-48s %10.1f %10.1f %10.1f %10s\n", label.c_str(), query, st.median,
                  st.p90, st.mean, hits.c_str());
    };
    if (!free_set.empty()) {
      row("  of which SetRobotState (poses, boxes, tree)",
          Time(free_set, checker, [](collision::CollisionChecker&) {}), "-");
      row("  of which arm-arm and self pairs",
          Time(free_set, checker,
               [&](collision::CollisionChecker& c) {
                 c.InCollision(collision::Bit(collision::PairClass::kArmArm) |
                               collision::Bit(collision::PairClass::kSelf));
               }),
          "-");
      int free_hits = 0;
      row("whole-cart check, collision-free near patient",
          Time(free_set, checker,
               [&](collision::CollisionChecker& c) { free_hits += c.InCollision(); }),
          std::to_string(free_hits / 2));
      if (kind == collision::BvhKind::kObbRss) {
        row("arm-patient distance, collision-free near patient",
            Time(free_set, checker,
                 [&](collision::CollisionChecker& c) { c.MinimumDistance(robot_patient); }),
            "-");
        row("whole-cart distance, collision-free near patient",
            Time(free_set, checker, [&](collision::CollisionChecker& c) { c.MinimumDistance(); }),
            "-");
      }
    }
    int hits = 0;
    const Stats cart_check =
        Time(around, checker, [&](collision::CollisionChecker& c) { hits += c.InCollision(); });
    row("whole-cart check, around the placement", cart_check, std::to_string(hits / 2));
    hits = 0;
    const Stats all =
        Time(around, checker, [&](collision::CollisionChecker& c) { hits += c.Check().collision; });
    row("all pairs (Check), around the placement", all, std::to_string(hits / 2));
    if (kind == collision::BvhKind::kObbRss) {
      int zero = 0;
      const Stats dist = Time(around, checker, [&](collision::CollisionChecker& c) {
        zero += c.MinimumDistance(robot_patient).distance <= 0.0;
      });
      row("arm-patient distance, around the placement", dist, std::to_string(zero / 2) + " at 0");
    }
    std::printf("%-11s %-48s %10.1f ms\n", label.c_str(), "world build (BVHs, allowed pairs)",
                build_ms);
  }
  return 0;
}
