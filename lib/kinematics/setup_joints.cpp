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

// The setup-joint solver of one request, as stages: the joints it solves (Joints), the request
// checked (CheckRequest), the joints' ranges and whether they drive passive joints (Prepare),
// the residual and Jacobian of a candidate (Evaluate), then from each start a descent: with an
// axis and `axis_secondary`, lexicographic (DescendLexicographic: the port first, the axis in
// the position's null space), else damped least squares with an active set (DescendLeastSquares).
class SetupJointSolver {
 public:
  SetupJointSolver(const robot::RobotModel& model, const robot::RobotState& state,
                   const SetupJointRequest& request, const SetupJointOptions& options)
      : model(model),
        state(state),
        request(request),
        options(options),
        frame(model.GetFrame(request.frame)),
        joints(Joints()),
        n(static_cast<int>(joints.size())),
        work(state),
        w(1.0 / options.length_scale) {
    CheckRequest();
    Prepare();
  }

  SetupJointResult Solve() {
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
      x = Clamp(x);
      Evaluation current;
      if (!Evaluate(x, &current)) continue;
      if (with_axis && options.axis_secondary) {
        DescendLexicographic(&x, &current);
        current.cost = current.position_error <= options.position_tolerance
                           ? current.angle_error
                           : 10.0 + current.position_error;  // at the port first
        if (current.cost < best.cost) {
          best = current;
          best_values = x;
        }
        if (GoodEnough(best)) break;
        continue;
      }
      DescendLeastSquares(&x, &current);
      if (current.cost < best.cost) {
        best = current;
        best_values = x;
      }
      if (best.position_error <= options.position_tolerance &&
          best.angle_error <= options.angle_tolerance) {
        break;
      }
    }
    return Result(best, best_values);
  }

 private:
  // The held joints on the frame's path, or the request's (each held and moving the frame).
  std::vector<int> Joints() const {
    const std::vector<int>& path = model.movable_path(frame.link);
    std::vector<int> out;
    if (request.joints.empty()) {
      for (int j : path) {
        if (model.joint(j).drive == JointDrive::kHeld) out.push_back(j);
      }
      TROCAR_THROW_UNLESS(!out.empty(), "robot '" << model.name() << "': frame '" << frame.name
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
        out.push_back(j);
      }
    }
    return out;
  }

  void CheckRequest() {
    TROCAR_THROW_UNLESS(request.p_WF.allFinite(),
                        "setup joints for '" << frame.name << "': target position "
                                             << FormatVector(request.p_WF) << " is not finite");
    with_axis = request.axis_W.has_value();
    if (with_axis) {
      TROCAR_THROW_UNLESS(request.axis_W->allFinite() && request.axis_W->norm() > 1e-9,
                          "setup joints for '" << frame.name << "': axis "
                                               << FormatVector(*request.axis_W)
                                               << " must be a finite non-zero vector");
      axis_W = request.axis_W->normalized();
    }
    TROCAR_THROW_UNLESS(request.axis_F.allFinite() && request.axis_F.norm() > 1e-9,
                        "setup joints for '" << frame.name << "': axis_F must be non-zero");
    axis_F = request.axis_F.normalized();
  }

  // The joints' ranges; whether they drive mimic joints or closures. Held joints may drive mimic
  // joints or closures: then every evaluation re-resolves them and poses the whole robot. When
  // none of the solved joints drives one (directly or through another), the frame's pose depends
  // on its own chain alone: only that chain is posed (a da Vinci cart's setup joints move one
  // arm's chain of the whole cart's links).
  void Prepare() {
    lower.resize(n);
    upper.resize(n);
    for (int i = 0; i < n; ++i) {
      const auto& limits = model.joint(joints[i]).limits;
      lower[i] = std::isfinite(limits.lower) ? limits.lower : -M_PI;
      upper[i] = std::isfinite(limits.upper) ? limits.upper : M_PI;
    }
    std::vector<bool> driven(model.joints().size(), false);
    for (int j : joints) driven[j] = true;
    for (int step : model.resolve_order()) {
      if (step >= 0) {
        if (driven[model.joint(step).mimic.master]) driven[step] = drives_passive = true;
      } else {
        const robot::FourBarClosure& c = model.closures()[-1 - step];
        if (driven[c.driver]) driven[c.coupler] = driven[c.rocker] = drives_passive = true;
      }
    }
    // The active joints' and the passive joints' values resolved once from q (the slow path does
    // it at every evaluation).
    if (!drives_passive && !SetConfiguration(model, work.q, &work).ok()) drives_passive = true;
  }

  Eigen::VectorXd Clamp(Eigen::VectorXd v) const {
    return v.cwiseMax(lower).cwiseMin(upper).eval();
  }

  // The frame's pose at `values`: its position residual, its axis residual (scaled by 1/length
  // scale), the Jacobian of both, the errors. False when the robot cannot close at them.
  bool Evaluate(const Eigen::VectorXd& values, Evaluation* e) {
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
  }

  bool GoodEnough(const Evaluation& e) const {
    return e.position_error <= 0.1 * options.position_tolerance &&
           e.angle_error <= 0.1 * options.angle_tolerance;
  }

  // Lexicographic: each step reduces the position error (damped least squares on the position
  // rows) and turns the axis within the null space of the position's Jacobian; a step is kept
  // when it does not lose the port (position within tolerance, or better) and lowers the axis
  // error or the position error.
  bool Better(const Evaluation& t, const Evaluation& c) const {
    const bool t_at = t.position_error <= options.position_tolerance;
    const bool c_at = c.position_error <= options.position_tolerance;
    if (t_at != c_at) return t_at;
    if (!t_at) return t.position_error < c.position_error;
    return t.angle_error < c.angle_error - 1e-12;
  }

  void DescendLexicographic(Eigen::VectorXd* x_out, Evaluation* current_out) {
    Eigen::VectorXd& x = *x_out;
    Evaluation& current = *current_out;
    double lambda = 1e-3;
    int stalled = 0;
    for (int it = 0; it < options.max_iterations && !GoodEnough(current); ++it) {
      const Eigen::MatrixXd Jp = current.jacobian.topRows<3>();
      const Eigen::MatrixXd Ja = current.jacobian.bottomRows<3>();
      const Eigen::Vector3d rp = current.residual.head<3>(), ra = current.residual.tail<3>();
      Eigen::MatrixXd JJt = Jp * Jp.transpose();
      JJt.diagonal().array() += lambda;
      const Eigen::MatrixXd Jp_pinv =
          Jp.transpose() * JJt.ldlt().solve(Eigen::Matrix3d::Identity());
      const Eigen::VectorXd dq_p = -Jp_pinv * rp;
      Eigen::VectorXd dq = dq_p;
      if (current.position_error <= options.position_tolerance) {
        // At the port: turn the axis within the position's null space (exact projector).
        const Eigen::MatrixXd N = Eigen::MatrixXd::Identity(n, n) -
                                  Jp.completeOrthogonalDecomposition().pseudoInverse() * Jp;
        const Eigen::MatrixXd JaN = Ja * N;
        Eigen::MatrixXd KKt = JaN * JaN.transpose();
        KKt.diagonal().array() += lambda;
        dq += N * JaN.transpose() * KKt.ldlt().solve(-ra - Ja * dq_p);
      }
      Eigen::VectorXd candidate = Clamp(x + dq);
      Evaluation trial;
      bool ok = Evaluate(candidate, &trial);
      // Back onto the port after a turn (the null space is the linearised one): a few
      // Gauss-Newton steps on the position alone.
      for (int k = 0; ok && k < 5 && trial.position_error > 0.1 * options.position_tolerance &&
                      current.position_error <= options.position_tolerance;
           ++k) {
        const Eigen::MatrixXd Jt = trial.jacobian.topRows<3>();
        Eigen::MatrixXd M = Jt * Jt.transpose();
        M.diagonal().array() += 1e-9;
        candidate = Clamp(candidate - Jt.transpose() * M.ldlt().solve(trial.residual.head<3>()));
        ok = Evaluate(candidate, &trial);
      }
      if (ok && Better(trial, current)) {
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
  }

  // Damped least squares with an active set, down to a minimum or the iterations' end.
  void DescendLeastSquares(Eigen::VectorXd* x_out, Evaluation* current_out) {
    Eigen::VectorXd& x = *x_out;
    Evaluation& current = *current_out;
    double lambda = 1e-3;
    for (int it = 0; it < options.max_iterations && !GoodEnough(current); ++it) {
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
      const Eigen::VectorXd candidate = Clamp(x + step);
      Evaluation trial;
      if (Evaluate(candidate, &trial) && trial.cost < current.cost) {
        x = candidate;
        current = trial;
        lambda = std::max(lambda / 3.0, 1e-12);
      } else {
        lambda *= 4.0;
        if (lambda > 1e8) break;  // no descent left from here
      }
    }
  }

  SetupJointResult Result(const Evaluation& best, const Eigen::VectorXd& best_values) const {
    SetupJointResult result;
    for (int j : joints) result.joints.push_back(model.joint(j).name);
    result.values = best_values;
    result.position_error = best.position_error;
    result.angle_error = best.angle_error;
    const bool solved = best_values.size() == n &&
                        best.position_error <= options.position_tolerance &&
                        best.angle_error <= options.angle_tolerance;
    result.status =
        solved ? SetupJointResult::Status::kSolved : SetupJointResult::Status::kUnreachable;
    std::ostringstream msg;
    if (solved) {
      msg << "frame '" << frame.name << "' placed (error "
          << FormatError(best.position_error * 1e3, "mm");
      if (with_axis) msg << " and " << FormatError(best.angle_error * 180.0 / M_PI, "deg");
      msg << ")";
    } else {
      msg << "unreachable: frame '" << frame.name << "' stays " << best.position_error * 1e3
          << " mm short of " << FormatVector(request.p_WF);
      if (with_axis) msg << ", axis off by " << best.angle_error * 180.0 / M_PI << " deg";
      msg << " (best of " << options.starts << " starts within the setup-joint limits)";
    }
    result.message = msg.str();
    return result;
  }

  const robot::RobotModel& model;
  const robot::RobotState& state;
  const SetupJointRequest& request;
  const SetupJointOptions& options;
  const robot::Frame& frame;
  const std::vector<int> joints;  // the solved joints
  const int n;
  Eigen::Vector3d axis_W = Eigen::Vector3d::Zero(), axis_F = Eigen::Vector3d::UnitZ();
  bool with_axis = false;
  Eigen::VectorXd lower, upper;  // the joints' ranges (±pi where unbounded)
  bool drives_passive = false;   // they drive mimic joints or closures: pose the whole robot
  robot::RobotState work;        // the robot at the candidate being evaluated
  const double w;                // 1 / length scale: the axis rows' weight
};

}  // namespace

SetupJointResult SolveSetupJoints(const robot::RobotModel& model, const robot::RobotState& state,
                                  const SetupJointRequest& request,
                                  const SetupJointOptions& options) {
  return SetupJointSolver(model, state, request, options).Solve();
}

const char* ToString(SetupJointResult::Status status) {
  switch (status) {
    case SetupJointResult::Status::kSolved: return "solved";
    case SetupJointResult::Status::kUnreachable: return "unreachable";
  }
  return "unknown";
}

}  // namespace trocar::kinematics
