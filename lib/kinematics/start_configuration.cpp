#include "kinematics/start_configuration.hpp"

#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>

#include <Eigen/Geometry>
#include <Eigen/SVD>

#include "common/geometry.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "kinematics/jacobian.hpp"
#include "robot/robot_state.hpp"

namespace trocar::kinematics {
namespace {

constexpr double kLimitMargin = 0.10;     // fraction of a range kept free when sampling
constexpr double kSingularWarning = 0.02;  // dexterity below this: near a singularity
constexpr double kLimitWarning = 0.02;     // fraction of a range: near a limit

bool Bounded(const robot::Joint& j) {
  return std::isfinite(j.limits.lower) && std::isfinite(j.limits.upper);
}

// Sampling range of an active joint: its limits less the margin; unbounded revolute joints
// over a turn, unbounded prismatic ones over ±0.1 m.
std::pair<double, double> SampleRange(const robot::Joint& j) {
  if (Bounded(j)) {
    const double range = j.limits.upper - j.limits.lower;
    return {j.limits.lower + kLimitMargin * range, j.limits.upper - kLimitMargin * range};
  }
  const double half = j.type == robot::JointType::kPrismatic ? 0.1 : M_PI;
  const double lo = std::isfinite(j.limits.lower) ? j.limits.lower : -half;
  const double hi = std::isfinite(j.limits.upper) ? j.limits.upper : half;
  return {std::max(lo, -half), std::min(hi, half)};
}

// How far the tool can actually go from q, holding its orientation while it sweeps a 3-D
// Lissajous curve through a ±kSweep cube (a hand's motion comes in combinations, and joints drift
// along a path: probes from the start alone miss both), then turning ±kProbeTurn about each
// axis. The tool is driven by damped least squares with the joints clamped at their limits; the
// result is the fraction of the sweep followed within a millimetre before it first fails, times
// the fraction of turns reached (1: everything followed). The linear estimate in AssessStart
// ranks many samples; this decides between the best of them.
double ProbeMotion(const robot::RobotModel& model, const Eigen::VectorXd& q0, double length) {
  constexpr double kSweep = 0.055, kProbeTurn = 0.3;
  constexpr int kSweepPoints = 240, kIterations = 4;
  robot::RobotState state(model);
  if (!ForwardKinematics(model, q0, &state).ok()) return 0.0;
  const Eigen::Isometry3d X_W0 = FramePose(state, model.tool_frame());
  const Eigen::VectorXd lower = model.lower_limits(), upper = model.upper_limits();
  Matrix6Xd J;
  const bool position_only = q0.size() < 6;  // as AssessStart: no orientation to hold
  // Drives q toward X_goal; returns the remaining error (m, rotation weighted by `length`).
  auto drive = [&](const Eigen::Isometry3d& X_goal, Eigen::VectorXd* q, int iterations) {
    double error = 1e9;
    for (int it = 0; it <= iterations; ++it) {
      if (!ForwardKinematics(model, *q, &state).ok()) return 1e9;
      const Eigen::Isometry3d X = FramePose(state, model.tool_frame());
      const Eigen::AngleAxisd dR(X_goal.linear() * X.linear().transpose());
      Eigen::VectorXd e(6);
      e << length * dR.angle() * dR.axis(), X_goal.translation() - X.translation();
      if (position_only) e = Eigen::VectorXd(e.tail<3>());
      error = e.norm();
      if (it == iterations) break;
      ComputeFrameJacobian(model, state, model.tool_frame(), &J);
      Eigen::MatrixXd Js = position_only ? Eigen::MatrixXd(J.bottomRows<3>()) : Eigen::MatrixXd(J);
      if (!position_only) Js.topRows<3>() *= length;
      const Eigen::MatrixXd JJt =
          Js * Js.transpose() + 1e-6 * Eigen::MatrixXd::Identity(Js.rows(), Js.rows());
      *q += Js.transpose() * JJt.ldlt().solve(e);
      *q = q->cwiseMax(lower).cwiseMin(upper);
    }
    return error;
  };
  double sweep = 1.0;
  {
    Eigen::VectorXd q = q0;
    for (int k = 1; k <= kSweepPoints; ++k) {
      const double t = 2.0 * M_PI * k / kSweepPoints;
      Eigen::Isometry3d X_goal = X_W0;
      X_goal.translation() +=
          kSweep * Eigen::Vector3d(std::sin(t), std::sin(1.3 * t + 0.5), std::sin(1.7 * t + 1.0));
      if (drive(X_goal, &q, kIterations) > 1e-3) {
        sweep = static_cast<double>(k - 1) / kSweepPoints;
        break;
      }
    }
  }
  if (position_only) return sweep;
  int turns = 0;
  for (int probe = 0; probe < 6; ++probe) {
    Eigen::VectorXd q = q0;
    Eigen::Isometry3d X_goal = X_W0;
    const double sign = probe < 3 ? 1.0 : -1.0;
    bool reached = true;
    for (int k = 1; k <= 4 && reached; ++k) {
      X_goal.linear() = Eigen::AngleAxisd(sign * k * kProbeTurn / 4, Eigen::Vector3d::Unit(probe % 3)) *
                        X_W0.linear();
      reached = drive(X_goal, &q, 10) < 1e-3;
    }
    turns += reached ? 1 : 0;
  }
  return sweep * turns / 6.0;
}

}  // namespace

StartQuality AssessStart(const robot::RobotModel& model, const Eigen::VectorXd& q, double length) {
  StartQuality out;
  robot::RobotState state(model);
  if (const auto set = ForwardKinematics(model, q, &state); !set.ok()) {
    out.status = StartQuality::Status::kConfigurationRefused;
    out.message = set.message;
    return out;
  }
  Matrix6Xd J;
  ComputeFrameJacobian(model, state, model.tool_frame(), &J);
  const int n = static_cast<int>(q.size());
  const int rank = std::min(6, n);
  if (rank == 0) {
    out.status = StartQuality::Status::kNoJoints;
    out.message = "robot '" + model.name() + "' has no active joints";
    return out;
  }
  // Robots with fewer than six joints follow the position only (teleop's default for them).
  const bool position_only = n < 6;
  const int rank_used = position_only ? std::min(3, n) : rank;
  Eigen::MatrixXd scaled = position_only ? Eigen::MatrixXd(J.bottomRows<3>()) : Eigen::MatrixXd(J);
  if (!position_only) scaled.topRows<3>() *= length;
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(scaled, Eigen::ComputeThinU | Eigen::ComputeThinV);
  const Eigen::VectorXd s = svd.singularValues();
  out.dexterity = s[0] > 0.0 ? s[rank_used - 1] / s[0] : 0.0;
  if (!(out.dexterity > 1e-9)) return out;
  // Joint travel a typical hand motion needs from here: the pseudo-inverse's rows, for
  // kHandMotion metres and kHandTurn radians in any direction (scaled rows: v and L·ω).
  constexpr double kHandMotion = 0.08, kHandTurn = 0.25;
  const Eigen::MatrixXd pinv = PseudoInverse(svd, 1e-9);  // of `scaled`: all σ kept (dexterity > 1e-9)
  double worst = 1.0;
  out.limit_margin = 0.5;
  for (int i = 0; i < model.num_positions(); ++i) {
    const robot::Joint& j = model.joint(model.active_joints()[i]);
    if (!Bounded(j) || j.limits.upper <= j.limits.lower) continue;
    const double range = j.limits.upper - j.limits.lower;
    const double margin = std::min(q[i] - j.limits.lower, j.limits.upper - q[i]);
    out.limit_margin = std::min(out.limit_margin, margin / range);
    const double travel = position_only ? kHandMotion * pinv.row(i).norm()
                                        : kHandTurn * length * pinv.row(i).head<3>().norm() +
                                              kHandMotion * pinv.row(i).tail<3>().norm();
    // Full marks with room for twice the travel each way; none at a limit.
    worst = std::min(worst, std::clamp(margin / (2.0 * travel + 1e-12), 0.0, 1.0));
  }
  out.score = out.dexterity * worst;
  return out;
}

const char* ToString(StartQuality::Status status) {
  switch (status) {
    case StartQuality::Status::kAssessed: return "assessed";
    case StartQuality::Status::kConfigurationRefused: return "the configuration is refused";
    case StartQuality::Status::kNoJoints: return "no active joints";
  }
  return "unknown";
}

std::vector<std::string> StartWarnings(const robot::RobotModel& model, const Eigen::VectorXd& q,
                                       double length) {
  std::vector<std::string> warnings;
  const StartQuality quality = AssessStart(model, q, length);
  if (!quality.ok()) {
    warnings.push_back("the start configuration does not assemble (a closure cannot follow)");
    return warnings;
  }
  if (quality.dexterity < kSingularWarning) {
    std::ostringstream w;
    w << "the start configuration is near a singularity (inverse condition number "
      << quality.dexterity << "): the tool cannot move in some directions; give the robot a home configuration or a start "
         "configuration of its own (q0)";
    warnings.push_back(w.str());
  }
  for (int i = 0; i < model.num_positions(); ++i) {
    const robot::Joint& j = model.joint(model.active_joints()[i]);
    if (!Bounded(j) || j.limits.upper <= j.limits.lower) continue;
    const double range = j.limits.upper - j.limits.lower;
    const double margin = std::min(q[i] - j.limits.lower, j.limits.upper - q[i]);
    if (margin < kLimitWarning * range) {
      std::ostringstream w;
      w << "joint '" << j.name << "' starts at " << q[i] << ", within " << margin
        << " of its limits [" << j.limits.lower << ", " << j.limits.upper << "]";
      warnings.push_back(w.str());
    }
  }
  return warnings;
}

StartConfiguration ChooseStart(const robot::RobotModel& model, unsigned seed, int samples) {
  StartConfiguration out;
  const int n = model.num_positions();
  // The characteristic length: half the tool's distance from the base at the neutral pose, so
  // a turn of the wrist and a move of the tool weigh alike whatever the robot's size.
  {
    robot::RobotState state(model);
    if (ForwardKinematics(model, model.neutral_configuration(), &state).ok()) {
      const double reach = ToolPoseInBase(model, state).translation().norm();
      out.length = std::clamp(0.5 * reach, 0.05, 2.0);
    }
  }
  if (model.defaults().has_home()) {
    out.q = model.defaults().home;
    out.basis = "home from " + (model.source().empty() ? model.name() : model.source());
    out.quality = AssessStart(model, out.q, out.length);
    out.warnings = StartWarnings(model, out.q, out.length);
    return out;
  }
  if (n == 0) {  // e.g. a setup-joint arm: every joint held, nothing for a session to drive
    out.q = Eigen::VectorXd(0);
    out.basis = "no active joints (nothing to choose)";
    out.quality.status = StartQuality::Status::kNoJoints;
    out.quality.message = "robot '" + model.name() + "' has no active joints";
    return out;
  }
  std::mt19937 rng(seed);
  // Rank seeded samples by the linear estimate, keep the best few.
  constexpr int kFinalists = 12;
  std::vector<std::pair<double, Eigen::VectorXd>> finalists;
  auto consider = [&](const Eigen::VectorXd& q) {
    const StartQuality quality = AssessStart(model, q, out.length);
    if (!quality.ok()) return;
    finalists.emplace_back(quality.score, q);
    std::stable_sort(finalists.begin(), finalists.end(),
                     [](const auto& a, const auto& b) { return a.first > b.first; });
    if (static_cast<int>(finalists.size()) > kFinalists) finalists.pop_back();
  };
  consider(model.neutral_configuration());
  for (int k = 0; k < samples; ++k) {
    Eigen::VectorXd q(n);
    for (int i = 0; i < n; ++i) {
      const auto [lo, hi] = SampleRange(model.joint(model.active_joints()[i]));
      q[i] = std::uniform_real_distribution<double>(lo, hi)(rng);
    }
    consider(q);
  }
  // Each finalist refined by a coordinate ascent on the estimate, then probed: the one whose
  // tool goes furthest (then the best estimate) wins.
  Eigen::VectorXd best = model.neutral_configuration();
  StartQuality best_quality = AssessStart(model, best, out.length);
  double best_probe = -1.0;
  for (auto& [score, start] : finalists) {
    Eigen::VectorXd q_best = start;
    StartQuality q_quality = AssessStart(model, q_best, out.length);
    Eigen::VectorXd step(n);
    for (int i = 0; i < n; ++i) {
      const auto [lo, hi] = SampleRange(model.joint(model.active_joints()[i]));
      step[i] = 0.1 * (hi - lo);
    }
    for (int round = 0; round < 8 && n > 0 && step.maxCoeff() > 1e-3; ++round) {
      bool improved = false;
      for (int i = 0; i < n; ++i) {
        const auto [lo, hi] = SampleRange(model.joint(model.active_joints()[i]));
        for (const double sign : {1.0, -1.0}) {
          Eigen::VectorXd q = q_best;
          q[i] = std::clamp(q[i] + sign * step[i], lo, hi);
          const StartQuality quality = AssessStart(model, q, out.length);
          if (quality.ok() && quality.score > q_quality.score + 1e-12) {
            q_best = q;
            q_quality = quality;
            improved = true;
            break;
          }
        }
      }
      if (!improved) step *= 0.5;
    }
    const double probe = ProbeMotion(model, q_best, out.length);
    if (probe > best_probe + 1e-9 ||
        (std::abs(probe - best_probe) <= 1e-9 && q_quality.score > best_quality.score)) {
      best = q_best;
      best_quality = q_quality;
      best_probe = probe;
    }
  }
  out.q = best;
  out.quality = best_quality;
  std::ostringstream basis;
  basis << "chosen automatically (no home given): best of " << samples
        << " seeded samples, refined and probed (the tool follows " << 100.0 * best_probe
        << " % of a ±5.5 cm sweep and ±0.3 rad turns); inverse condition number "
        << best_quality.dexterity
        << " at " << out.length << " m, nearest limit " << 100.0 * best_quality.limit_margin
        << " % of its range away";
  out.basis = basis.str();
  out.warnings = StartWarnings(model, out.q, out.length);
  if (best_probe < 1.0) {
    std::ostringstream w;
    w << "from the best start found the tool follows only " << 100.0 * best_probe
      << " % of a ±5.5 cm hand sweep and ±0.3 rad turns: joint limits will stop larger motions "
         "(a tight workspace; give the robot a home configuration, or a start configuration of its own "
         "(q0), if you know a better start)";
    out.warnings.push_back(w.str());
  }
  out.probe = best_probe;
  return out;
}

}  // namespace trocar::kinematics
