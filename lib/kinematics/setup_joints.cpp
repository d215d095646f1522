#include "kinematics/setup_joints.hpp"

#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>

#include "common/error.hpp"
#include "common/geometry.hpp"
#include "kinematics/forward_kinematics.hpp"

namespace trocar::kinematics {

using robot::Joint;
using robot::JointDrive;
using robot::JointType;

namespace {

struct Evaluation {
  Eigen::Matrix<double, 6, 1> residual;  // [position error; scaled axis error]
  Eigen::Matrix<double, 6, Eigen::Dynamic> jacobian;
  double position_error = 0.0;
  double angle_error = 0.0;
  double cost = 0.0;
};

}  // namespace

SetupJointResult SolveSetupJoints(const robot::RobotModel& model, const robot::RobotState& state,
                                  const SetupJointRequest& request,
                                  const SetupJointOptions& options) {
  const robot::Frame& frame = model.GetFrame(request.frame);
  const std::vector<int>& path = model.movable_path(frame.link);
  std::vector<int> joints;
  if (request.joints.empty()) {
    for (int j : path) {
      if (model.joint(j).drive == JointDrive::kHeld) joints.push_back(j);
    }
    TROCAR_THROW_UNLESS(!joints.empty(), "robot '" << model.name() << "': frame '" << frame.name
                                                   << "' has no held (setup) joints on its path");
  } else {
    for (const std::string& name : request.joints) {
      const int j = model.GetJoint(name);
      TROCAR_THROW_UNLESS(model.joint(j).drive == JointDrive::kHeld,
                          "robot '" << model.name() << "': joint '" << name << "' is "
                                    << robot::ToString(model.joint(j).drive) << ", not held");
      TROCAR_THROW_UNLESS(std::find(path.begin(), path.end(), j) != path.end(),
                          "robot '" << model.name() << "': joint '" << name
                                    << "' does not move frame '" << frame.name << "'");
      joints.push_back(j);
    }
  }
  TROCAR_THROW_UNLESS(request.p_WF.allFinite(), "setup joints for '" << frame.name
                                                    << "': target position "
                                                    << FormatVector(request.p_WF)
                                                    << " is not finite");
  Eigen::Vector3d axis_W = Eigen::Vector3d::Zero();
  const bool with_axis = request.axis_W.has_value();
  if (with_axis) {
    TROCAR_THROW_UNLESS(request.axis_W->allFinite() && request.axis_W->norm() > 1e-9,
                        "setup joints for '" << frame.name << "': axis "
                                             << FormatVector(*request.axis_W)
                                             << " must be a finite non-zero vector");
    axis_W = request.axis_W->normalized();
  }
  TROCAR_THROW_UNLESS(request.axis_F.allFinite() && request.axis_F.norm() > 1e-9,
                      "setup joints for '" << frame.name << "': axis_F must be non-zero");
  const Eigen::Vector3d axis_F = request.axis_F.normalized();
  const int n = static_cast<int>(joints.size());

  Eigen::VectorXd lower(n), upper(n);
  for (int i = 0; i < n; ++i) {
    const auto& limits = model.joint(joints[i]).limits;
    lower[i] = std::isfinite(limits.lower) ? limits.lower : -M_PI;
    upper[i] = std::isfinite(limits.upper) ? limits.upper : M_PI;
  }
  auto clamp = [&](Eigen::VectorXd v) { return v.cwiseMax(lower).cwiseMin(upper).eval(); };

  // Held joints may drive mimic joints or closures: then every evaluation re-resolves them and
  // poses the whole robot. When none of the solved joints drives one (directly or through
  // another), the frame's pose depends on its own chain alone: only that chain is posed (a da
  // Vinci cart's setup joints move one arm's chain of the whole cart's links).
  std::vector<bool> driven(model.joints().size(), false);
  for (int j : joints) driven[j] = true;
  bool drives_passive = false;
  for (int step : model.resolve_order()) {
    if (step >= 0) {
      if (driven[model.joint(step).mimic.master]) driven[step] = drives_passive = true;
    } else {
      const robot::FourBarClosure& c = model.closures()[-1 - step];
      if (driven[c.driver]) driven[c.coupler] = driven[c.rocker] = drives_passive = true;
    }
  }
  robot::RobotState work = state;
  // The active joints' and the passive joints' values resolved once from q (the slow path does it
  // at every evaluation).
  if (!drives_passive && !SetConfiguration(model, work.q, &work).ok()) drives_passive = true;
  const double w = 1.0 / options.length_scale;
  auto evaluate = [&](const Eigen::VectorXd& values, Evaluation* e) {
    for (int i = 0; i < n; ++i) work.joint_values[model.joint(joints[i]).dof_index] = values[i];
    if (drives_passive) {
      if (!SetConfiguration(model, work.q, &work).ok()) return false;
      ForwardKinematics(model, &work);
    } else {
      ForwardKinematicsToLink(model, frame.link, &work);
    }
    const Eigen::Isometry3d X_WF = FramePose(work, frame);
    const Eigen::Vector3d p = X_WF.translation();
    const Eigen::Vector3d a = X_WF.linear() * axis_F;
    e->residual.head<3>() = p - request.p_WF;
    e->residual.tail<3>() = with_axis ? Eigen::Vector3d(w * (a - axis_W)) : Eigen::Vector3d::Zero();
    e->jacobian.setZero(6, n);
    for (int i = 0; i < n; ++i) {
      const Joint& joint = model.joint(joints[i]);
      const Eigen::Isometry3d& X_WC = work.X_WL[joint.child_link];
      const Eigen::Vector3d e_W = X_WC.linear() * joint.axis_J;
      if (joint.type == JointType::kRevolute) {
        e->jacobian.col(i).head<3>() = e_W.cross(p - X_WC.translation());
        if (with_axis) e->jacobian.col(i).tail<3>() = w * e_W.cross(a);
      } else {
        e->jacobian.col(i).head<3>() = e_W;
      }
    }
    e->position_error = e->residual.head<3>().norm();
    e->angle_error = with_axis ? std::acos(std::clamp(a.dot(axis_W), -1.0, 1.0)) : 0.0;
    e->cost = e->residual.squaredNorm();
    return true;
  };
  auto good_enough = [&](const Evaluation& e) {
    return e.position_error <= 0.1 * options.position_tolerance &&
           e.angle_error <= 0.1 * options.angle_tolerance;
  };

  std::mt19937 rng(options.seed);
  Eigen::VectorXd best_values;
  Evaluation best;
  best.cost = HUGE_VAL;
  for (int start = 0; start < std::max(1, options.starts); ++start) {
    Eigen::VectorXd x(n);
    for (int i = 0; i < n; ++i) {
      x[i] = start == 0 ? state.joint_values[model.joint(joints[i]).dof_index]
                        : std::uniform_real_distribution<double>(lower[i], upper[i])(rng);
    }
    x = clamp(x);
    Evaluation current;
    if (!evaluate(x, &current)) continue;
    double lambda = 1e-3;
    if (with_axis && options.axis_secondary) {
      // Lexicographic: each step reduces the position error (damped least squares on the
      // position rows) and turns the axis within the null space of the position's Jacobian; a
      // step is kept when it does not lose the port (position within tolerance, or better) and
      // lowers the axis error or the position error.
      auto better = [&](const Evaluation& t, const Evaluation& c) {
        const bool t_at = t.position_error <= options.position_tolerance;
        const bool c_at = c.position_error <= options.position_tolerance;
        if (t_at != c_at) return t_at;
        if (!t_at) return t.position_error < c.position_error;
        return t.angle_error < c.angle_error - 1e-12;
      };
      int stalled = 0;
      for (int it = 0; it < options.max_iterations && !good_enough(current); ++it) {
        const Eigen::MatrixXd Jp = current.jacobian.topRows<3>();
        const Eigen::MatrixXd Ja = current.jacobian.bottomRows<3>();
        const Eigen::Vector3d rp = current.residual.head<3>(), ra = current.residual.tail<3>();
        Eigen::MatrixXd JJt = Jp * Jp.transpose();
        JJt.diagonal().array() += lambda;
        const Eigen::MatrixXd Jp_pinv = Jp.transpose() * JJt.ldlt().solve(Eigen::Matrix3d::Identity());
        const Eigen::VectorXd dq_p = -Jp_pinv * rp;
        Eigen::VectorXd dq = dq_p;
        if (current.position_error <= options.position_tolerance) {
          // At the port: turn the axis within the position's null space (exact projector).
          const Eigen::MatrixXd N =
              Eigen::MatrixXd::Identity(n, n) -
              Jp.completeOrthogonalDecomposition().pseudoInverse() * Jp;
          const Eigen::MatrixXd JaN = Ja * N;
          Eigen::MatrixXd KKt = JaN * JaN.transpose();
          KKt.diagonal().array() += lambda;
          dq += N * JaN.transpose() * KKt.ldlt().solve(-ra - Ja * dq_p);
        }
        Eigen::VectorXd candidate = clamp(x + dq);
        Evaluation trial;
        bool ok = evaluate(candidate, &trial);
        // Back onto the port after a turn (the null space is the linearised one): a few
        // Gauss-Newton steps on the position alone.
        for (int k = 0; ok && k < 5 && trial.position_error > 0.1 * options.position_tolerance &&
                        current.position_error <= options.position_tolerance;
             ++k) {
          const Eigen::MatrixXd Jt = trial.jacobian.topRows<3>();
          Eigen::MatrixXd M = Jt * Jt.transpose();
          M.diagonal().array() += 1e-9;
          candidate = clamp(candidate - Jt.transpose() * M.ldlt().solve(trial.residual.head<3>()));
          ok = evaluate(candidate, &trial);
        }
        if (ok && better(trial, current)) {
          // At the port and turning less than 0.001 degrees a step five steps running: as near
          // as this start gets (an unreachable axis never meets good_enough).
          const bool at_port = current.position_error <= options.position_tolerance &&
                               trial.position_error <= options.position_tolerance;
          stalled = at_port && current.angle_error - trial.angle_error < 1e-5 ? stalled + 1 : 0;
          x = candidate;
          current = trial;
          lambda = std::max(lambda / 3.0, 1e-12);
          if (stalled >= 5) break;
        } else {
          lambda *= 4.0;
          if (lambda > 1e8) break;
        }
      }
      current.cost = current.position_error <= options.position_tolerance
                         ? current.angle_error
                         : 10.0 + current.position_error;  // at the port first
      if (current.cost < best.cost) {
        best = current;
        best_values = x;
      }
      if (good_enough(best)) break;
      continue;
    }
    for (int it = 0; it < options.max_iterations && !good_enough(current); ++it) {
      const Eigen::MatrixXd JtJ = current.jacobian.transpose() * current.jacobian;
      const Eigen::VectorXd g = current.jacobian.transpose() * current.residual;
      // Active set: a joint at a bound whose descent direction points out of range is frozen,
      // and the damped step is solved for the others (a plain clamp of the full step stalls).
      std::vector<int> free;
      for (int i = 0; i < n; ++i) {
        const bool at_lower = x[i] <= lower[i] + 1e-12 && g[i] > 0;
        const bool at_upper = x[i] >= upper[i] - 1e-12 && g[i] < 0;
        if (!at_lower && !at_upper) free.push_back(i);
      }
      if (free.empty()) break;  // a corner of the box is a local minimum
      const int m = static_cast<int>(free.size());
      Eigen::MatrixXd A(m, m);
      Eigen::VectorXd b(m);
      for (int r = 0; r < m; ++r) {
        b[r] = -g[free[r]];
        for (int c = 0; c < m; ++c) A(r, c) = JtJ(free[r], free[c]);
        A(r, r) += lambda * (JtJ(free[r], free[r]) + 1e-9);
      }
      const Eigen::VectorXd reduced = A.ldlt().solve(b);
      Eigen::VectorXd step = Eigen::VectorXd::Zero(n);
      for (int r = 0; r < m; ++r) step[free[r]] = reduced[r];
      const Eigen::VectorXd candidate = clamp(x + step);
      Evaluation trial;
      if (evaluate(candidate, &trial) && trial.cost < current.cost) {
        x = candidate;
        current = trial;
        lambda = std::max(lambda / 3.0, 1e-12);
      } else {
        lambda *= 4.0;
        if (lambda > 1e8) break;  // no descent left from here
      }
    }
    if (current.cost < best.cost) {
      best = current;
      best_values = x;
    }
    if (best.position_error <= options.position_tolerance &&
        best.angle_error <= options.angle_tolerance) {
      break;
    }
  }

  SetupJointResult result;
  for (int j : joints) result.joints.push_back(model.joint(j).name);
  result.values = best_values;
  result.position_error = best.position_error;
  result.angle_error = best.angle_error;
  const bool solved = best_values.size() == n &&
                      best.position_error <= options.position_tolerance &&
                      best.angle_error <= options.angle_tolerance;
  result.status = solved ? SetupJointResult::Status::kSolved
                         : SetupJointResult::Status::kUnreachable;
  std::ostringstream msg;
  if (solved) {
    msg << "frame '" << frame.name << "' placed within " << best.position_error * 1e3 << " mm";
    if (with_axis) msg << " and " << best.angle_error * 180.0 / M_PI << " deg";
  } else {
    msg << "unreachable: frame '" << frame.name << "' stays " << best.position_error * 1e3
        << " mm short of " << FormatVector(request.p_WF);
    if (with_axis) msg << ", axis off by " << best.angle_error * 180.0 / M_PI << " deg";
    msg << " (best of " << options.starts << " starts within the setup-joint limits)";
  }
  result.message = msg.str();
  return result;
}

const char* ToString(SetupJointResult::Status status) {
  switch (status) {
    case SetupJointResult::Status::kSolved: return "solved";
    case SetupJointResult::Status::kUnreachable: return "unreachable";
  }
  return "unknown";
}

}  // namespace trocar::kinematics
