// Collision benchmark (a small harness: per-configuration times, so median and p90 are exact):
// the da Vinci cart placed at a patient's ports (the bundled phantom, about 10^5 triangles),
// 2000 seeded configurations around the placement (arm joints anywhere within a third of their
// range around it). Measured per configuration, after the link poses are known:
//   whole-cart check  SetRobotState + InCollision (all pair classes, first hit stops)
//   all pairs         SetRobotState + Check (every colliding pair with a contact point)
//   arm-patient dist  SetRobotState + MinimumDistance(arm-patient, instrument-patient)
// with OBBRSS and OBB trees side by side (distance needs OBBRSS).
//
//   build/bench/collision_bench [patients/<case>] [configurations]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <iostream>
#include <random>

#include "collision/cart_setup.hpp"
#include "collision/collision_world.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "patient/patient_model.hpp"
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
Stats Time(const std::vector<robot::RobotState>& states, collision::CollisionChecker& checker, F query) {
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
  const std::string case_dir = argc > 1 ? argv[1] : std::string(TROCAR_SOURCE_DIR) + "/patients/phantom-default";
  const int n = argc > 2 ? std::atoi(argv[2]) : 2000;
  const patient::PatientModel patient = patient::ImportPatient(case_dir);
  auto cart = std::make_shared<const robot::RobotModel>(
      robot::LoadRobot(std::string(TROCAR_SOURCE_DIR) + "/robots/davinci-classic/cart.yaml"));
  collision::CartSetup setup = collision::DefaultPorts(patient, *cart);
  robot::RobotState placed(*cart);
  const auto placement = collision::PlaceCartAutomatically(*cart, &setup, &placed);
  std::printf("patient %s: %ld triangles; cart placed: %s\n", patient.name.c_str(), patient.triangle_count(),
              placement.ok ? "every port reached" : "nearest placement (not every port reached)");

  std::mt19937 rng(7);
  std::vector<robot::RobotState> states;
  while (static_cast<int>(states.size()) < n) {
    robot::RobotState s = placed;
    Eigen::VectorXd q = placed.q;
    for (int i = 0; i < q.size(); ++i) {
      const auto& lim = cart->joint(cart->active_joints()[i]).limits;
      const double third = (lim.upper - lim.lower) / 6;
      q[i] = std::clamp(q[i] + std::uniform_real_distribution<double>(-third, third)(rng), lim.lower, lim.upper);
    }
    if (kinematics::ForwardKinematics(*cart, q, &s).ok) states.push_back(s);
  }
  std::printf("%d configurations; times per configuration in microseconds\n\n", n);
  std::printf("%-8s %-34s %10s %10s %10s %10s\n", "bvh", "query", "median", "p90", "mean", "hits");
  for (auto kind : {collision::BvhKind::kObbRss, collision::BvhKind::kObb}) {
    collision::WorldOptions options;
    options.bvh = kind;
    const auto t0 = Clock::now();
    const auto world = collision::CollisionWorld::Build(&patient, cart, options);
    const double build_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    collision::CollisionChecker checker(world);
    int hits = 0;
    const Stats cart_check = Time(states, checker, [&](collision::CollisionChecker& c) { hits += c.InCollision(); });
    std::printf("%-8s %-34s %10.1f %10.1f %10.1f %10d\n", collision::ToString(kind), "whole-cart check (InCollision)",
                cart_check.median, cart_check.p90, cart_check.mean, hits / 2);
    hits = 0;
    const Stats all = Time(states, checker, [&](collision::CollisionChecker& c) { hits += c.Check().collision; });
    std::printf("%-8s %-34s %10.1f %10.1f %10.1f %10d\n", collision::ToString(kind), "all pairs (Check)", all.median,
                all.p90, all.mean, hits / 2);
    if (kind == collision::BvhKind::kObbRss) {
      const unsigned mask = collision::Bit(collision::PairClass::kArmPatient) |
                            collision::Bit(collision::PairClass::kInstrumentPatient);
      const Stats dist = Time(states, checker, [&](collision::CollisionChecker& c) { c.MinimumDistance(mask); });
      std::printf("%-8s %-34s %10.1f %10.1f %10.1f %10s\n", collision::ToString(kind), "arm-patient minimum distance",
                  dist.median, dist.p90, dist.mean, "-");
    }
    std::printf("%-8s %-34s %10.1f ms\n", collision::ToString(kind), "world build (BVHs, allowed pairs)", build_ms);
  }
  return 0;
}
