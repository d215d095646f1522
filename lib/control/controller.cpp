#include "control/controller.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/Eigenvalues>

#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"

namespace trocar::control {

void ControllerWorkspace::Resize(int n) {
  if (J.cols() == n && frozen.size() == static_cast<std::size_t>(n)) return;
  J.setZero(6, n);
  J_task.setZero(6, n);
  J_a.setZero(6, n);
  J_b.setZero(6, n);
  pinv2.setZero(n, 2);
  N.setZero(n, n);
  a.setZero(n);
  b.setZero(n);
  c.setZero(n);
  frozen.assign(static_cast<std::size_t>(n), 0);
  sigma_direction.setZero();
}

namespace {

// Task velocity V_d + K e for the tool, after filling the tool Jacobian into the workspace.
Vector6d ToolTaskVelocity(const robot::RobotModel& model, const robot::RobotState& state,
                          const TaskTarget& target, const Vector6d& gains,
                          ControllerWorkspace* ws) {
  kinematics::ComputeFrameJacobian(model, state, model.tool_frame(), &ws->J);
  return target.V_WD +
         gains.asDiagonal() * TaskError(target.X_WD, kinematics::FramePose(state, model.tool_frame()));
}

// The rows of a task: all six, or the three linear ones (position only), as R × n views on the
// top rows of a 6 × n buffer, so that R × R products and solves are fixed-size (on the stack).
template <int R>
using Rows = Eigen::Block<kinematics::Matrix6Xd, R, Eigen::Dynamic, false>;
/// The inverse of a symmetric positive definite R × R matrix, through A = L D Lᵀ (unit lower L,
/// no square roots) unrolled for R, then A⁻¹ = L⁻ᵀ D⁻¹ L⁻¹. A damped least-squares step solves
/// with the same matrix three times (two for the smallest singular value, one for the step):
/// triangular solves are chains of dependent operations, an inverse turns each into a product
/// whose operations run side by side. Eigen's general LLT and triangular solves were a quarter
/// of a PSM control step (bench/control_bench).
template <int R>
struct SpdInverse {
  using Matrix = Eigen::Matrix<double, R, R>;
  /// ok() is false when A is not positive definite to working precision (or not finite).
  explicit SpdInverse(const Matrix& A) {
    Matrix L = Matrix::Identity();
    Eigen::Matrix<double, R, 1> D, inverse_d;
    for (int j = 0; j < R; ++j) {
      double w[R];
      double d = A(j, j);
      for (int k = 0; k < j; ++k) {
        w[k] = L(j, k) * D[k];
        d -= L(j, k) * w[k];
      }
      if (!(d > 0.0) || !std::isfinite(d)) return;
      D[j] = d;
      inverse_d[j] = 1.0 / d;
      for (int i = j + 1; i < R; ++i) {
        double s = A(i, j);
        for (int k = 0; k < j; ++k) s -= L(i, k) * w[k];
        L(i, j) = s * inverse_d[j];
      }
    }
    Matrix M = Matrix::Identity();  // L⁻¹, unit lower; its columns are independent
    for (int j = 0; j < R; ++j) {
      for (int i = j + 1; i < R; ++i) {
        double s = L(i, j);
        for (int k = j + 1; k < i; ++k) s += L(i, k) * M(k, j);
        M(i, j) = -s;
      }
    }
    inverse.noalias() = M.transpose() * inverse_d.asDiagonal() * M;
    positive = true;
  }
  bool ok() const { return positive; }
  Matrix inverse;
  bool positive = false;
};

template <int R>
using ConstRows = Eigen::Block<const kinematics::Matrix6Xd, R, Eigen::Dynamic, false>;

// y = (J Jᵀ + λ² I)⁻¹ v with λ growing smoothly as the smallest singular value of J drops below
// `threshold` (at most `max_damping`); q̇ = Jᵀ y is then the damped least-squares solution.
// Whether to damp needs σ_min² (the smallest eigenvalue λ_min of J Jᵀ) only near the threshold:
// - the inverse B = (J Jᵀ)⁻¹ the solve uses bounds it from below, λ_min ≥ 1 / ‖B‖_F (since
//   ‖B‖_F ≥ λ_max(B)); at or above threshold², no damping, and nothing more to compute (the common
//   case; the bound is at most √R too low);
// - otherwise inverse iteration on B, started from the last step's direction (`warm`), gives the
//   Rayleigh quotient ρ ≥ λ_min; it stops when the residual ‖J Jᵀ x − ρ x‖, within which of ρ an
//   eigenvalue lies, is below 1e-10 of threshold² (or of ρ). Successive estimates that merely
//   agree do not suffice: with two close eigenvalues they agree long before they are right.
// A full eigen-decomposition per step cost more than the rest of the step.
template <int R, typename JacobianRows>
Eigen::Matrix<double, R, 1> DampedSolve(const JacobianRows& J, const Eigen::Matrix<double, R, 1>& v,
                                        double max_damping, double threshold, Vector6d* warm) {
  using Vector = Eigen::Matrix<double, R, 1>;
  Eigen::Matrix<double, R, R> JJt;
  JJt.noalias() = J * J.transpose();
  JJt.diagonal().array() += 1e-12;
  const SpdInverse<R> inverse(JJt);
  const double threshold2 = threshold * threshold;
  // A factorisation that failed (J Jᵀ singular to rounding) is a singular arm: full damping.
  double lambda_min = 0.0;
  if (inverse.ok()) {
    lambda_min = 1.0 / inverse.inverse.norm();  // a lower bound
    if (lambda_min >= threshold2) return inverse.inverse * v;
    Vector x = warm->head<R>();
    if (!(x.squaredNorm() > 0.5)) x = Vector::Constant(1.0 / std::sqrt(static_cast<double>(R)));
    for (int iteration = 0; iteration < 200; ++iteration) {
      const Vector y = inverse.inverse * x;
      const double norm = y.norm();
      if (!(norm > 0.0) || !std::isfinite(norm)) {  // singular to working precision
        lambda_min = 0.0;
        break;
      }
      x = y / norm;
      const Vector Ax = JJt * x;
      lambda_min = x.dot(Ax);  // Rayleigh quotient: ≥ λ_min
      if ((Ax - lambda_min * x).norm() <= 1e-10 * std::max(threshold2, lambda_min)) break;
    }
    warm->head<R>() = x;
  }
  const double sigma_min = std::sqrt(std::max(0.0, lambda_min - 1e-12));
  if (sigma_min >= threshold) return inverse.inverse * v;
  const double ratio = sigma_min / threshold;
  const double lambda2 = (1.0 - ratio * ratio) * max_damping * max_damping;
  JJt.diagonal().array() += lambda2;
  const SpdInverse<R> damped(JJt);
  if (damped.ok()) return damped.inverse * v;
  return JJt.llt().solve(v);  // not finite, or nothing to lift it: as Eigen solves it
}

// x -= J⁺ J x (the projection of x onto the null space of J), with J⁺ = Jᵀ (J Jᵀ)⁺ and the
// pseudo-inverse of the R × R J Jᵀ from its eigen-decomposition: exact, no damping (damping would
// leak into the task), directions with σ below 1e-6 σ_max treated as lost.
template <int R, typename JacobianRows>
void ProjectOntoNullSpace(const JacobianRows& J, Eigen::VectorXd* x) {
  Eigen::Matrix<double, R, R> JJt;
  JJt.noalias() = J * J.transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, R, R>> eig(JJt);
  const double largest = eig.eigenvalues()[R - 1];
  if (!(largest > 0.0)) return;  // J = 0: everything is null space
  Eigen::Matrix<double, R, 1> y = eig.eigenvectors().transpose() * (J * *x);
  for (int i = 0; i < R; ++i) {
    const double l = eig.eigenvalues()[i];
    y[i] = l > 1e-12 * largest ? y[i] / l : 0.0;
  }
  const Eigen::Matrix<double, R, 1> z = eig.eigenvectors() * y;
  x->noalias() -= J.transpose() * z;
}

template <int R>
void SolveRows(const kinematics::Matrix6Xd& J, const Vector6d& v, bool use_frozen, double max_damping,
               double threshold, ControllerWorkspace* ws, Eigen::VectorXd* qdot) {
  const int n = static_cast<int>(J.cols());
  const Eigen::Matrix<double, R, 1> task = v.tail<R>();
  if (!use_frozen) {  // the task's rows of J as they are
    const ConstRows<R> Jr(J, 6 - R, 0, R, n);
    const Eigen::Matrix<double, R, 1> y = DampedSolve<R>(Jr, task, max_damping, threshold, &ws->sigma_direction);
    qdot->noalias() = Jr.transpose() * y;
    return;
  }
  Rows<R> Jr = ws->J_task.topRows<R>();
  Jr = J.bottomRows<R>();  // R = 6: all rows; R = 3: the linear ones
  for (int k = 0; k < n; ++k) {
    if (ws->frozen[static_cast<std::size_t>(k)]) Jr.col(k).setZero();
  }
  const Eigen::Matrix<double, R, 1> y = DampedSolve<R>(Jr, task, max_damping, threshold, &ws->sigma_direction);
  qdot->noalias() = Jr.transpose() * y;
}

}  // namespace

Vector6d TaskGains(const robot::RobotModel& model, const std::string& name,
                   const Vector6d& fallback) {
  const auto& settings = model.defaults().controller;
  const auto found = settings.gains.find(name);
  if (found != settings.gains.end()) return Vector6d(found->second);
  return settings.task_gains.size() == 6 ? Vector6d(settings.task_gains) : fallback;
}

void JacobianTransposeController::ComputeVelocity(const robot::RobotModel& model,
                                                  const robot::RobotState& state,
                                                  const TaskTarget& target,
                                                  ControllerWorkspace* ws,
                                                  Eigen::VectorXd* qdot) const {
  ws->Resize(model.num_positions());
  qdot->resize(model.num_positions());
  kinematics::ComputeFrameJacobian(model, state, model.tool_frame(), &ws->J);
  Vector6d e = TaskError(target.X_WD, kinematics::FramePose(state, model.tool_frame()));
  if (target.position_only) e.head<3>().setZero();
  qdot->noalias() = ws->J.transpose() * (gains_.asDiagonal() * e);
}

void DampedLeastSquaresController::Solve(const kinematics::Matrix6Xd& J, const Vector6d& v,
                                         bool position_only, bool use_frozen,
                                         ControllerWorkspace* ws, Eigen::VectorXd* qdot) const {
  if (position_only) {
    SolveRows<3>(J, v, use_frozen, max_damping_, singular_threshold_, ws, qdot);
  } else {
    SolveRows<6>(J, v, use_frozen, max_damping_, singular_threshold_, ws, qdot);
  }
}

void DampedLeastSquaresController::ComputeVelocity(const robot::RobotModel& model,
                                                   const robot::RobotState& state,
                                                   const TaskTarget& target,
                                                   ControllerWorkspace* ws,
                                                   Eigen::VectorXd* qdot) const {
  ws->Resize(model.num_positions());
  qdot->resize(model.num_positions());
  const Vector6d v = ToolTaskVelocity(model, state, target, gains_, ws);
  Solve(ws->J, v, target.position_only, false, ws, qdot);
}

void JointLimitAvoidanceController::ComputeVelocity(const robot::RobotModel& model,
                                                    const robot::RobotState& state,
                                                    const TaskTarget& target,
                                                    ControllerWorkspace* ws,
                                                    Eigen::VectorXd* qdot) const {
  const int n = model.num_positions();
  ws->Resize(n);
  qdot->resize(n);
  const Vector6d v = ToolTaskVelocity(model, state, target, gains_, ws);
  // Secondary motion: the gradient of Σ ((q − mid) / range)², pushing toward mid-range.
  Eigen::VectorXd& q0 = ws->a;
  q0.setZero();
  for (int i = 0; i < n; ++i) {
    const auto& l = model.joint(model.active_joints()[i]).limits;
    if (!std::isfinite(l.lower) || !std::isfinite(l.upper) || l.upper <= l.lower) continue;
    const double range = l.upper - l.lower;
    q0[i] = -avoidance_gain_ * (state.q[i] - 0.5 * (l.lower + l.upper)) / (range * range) * 4.0;
  }
  std::fill(ws->frozen.begin(), ws->frozen.end(), 0);
  Eigen::VectorXd& primary = ws->b;
  Eigen::VectorXd& secondary = ws->c;
  for (int pass = 0; pass <= n; ++pass) {
    // The primary solve leaves the task's rows, frozen columns zeroed, in ws->J_task.
    Solve(ws->J, v, target.position_only, true, ws, &primary);
    // Null-space projection of the secondary motion through the same (frozen) Jacobian.
    secondary = q0;
    for (int k = 0; k < n; ++k) {
      if (ws->frozen[static_cast<std::size_t>(k)]) secondary[k] = 0.0;
    }
    if (target.position_only) {
      ProjectOntoNullSpace<3>(ConstRows<3>(ws->J_task, 0, 0, 3, n), &secondary);
    } else {
      ProjectOntoNullSpace<6>(ConstRows<6>(ws->J_task, 0, 0, 6, n), &secondary);
    }
    *qdot = primary + secondary;
    bool changed = false;
    for (int i = 0; i < n; ++i) {
      if (ws->frozen[static_cast<std::size_t>(i)]) continue;
      const auto& l = model.joint(model.active_joints()[i]).limits;
      const bool at_upper = state.q[i] >= l.upper - 1e-6 && (*qdot)[i] > 0;
      const bool at_lower = state.q[i] <= l.lower + 1e-6 && (*qdot)[i] < 0;
      if (at_upper || at_lower) {
        ws->frozen[static_cast<std::size_t>(i)] = 1;
        changed = true;
      }
    }
    if (!changed) break;
  }
  for (int i = 0; i < n; ++i) {
    if (ws->frozen[static_cast<std::size_t>(i)]) (*qdot)[i] = 0.0;
  }
}

double SoftwareRcmController::RcmError(const robot::RobotModel& model,
                                       const robot::RobotState& state) const {
  (void)model;
  const Eigen::Vector3d A = state.X_WL[shaft_link_] * p_LS_;
  const Eigen::Vector3d B = state.X_WL[shaft_link_].translation();
  const Eigen::Vector3d u = (B - A).normalized();
  const Eigen::Vector3d d = p_WR_ - A;
  return (d - d.dot(u) * u).norm();
}

namespace {

// The tool task in the RCM constraint's null space: q̇ = q1 + N (J_t N)⁺_damped (v_t − J_t q1).
template <int R>
void RcmTask(const kinematics::Matrix6Xd& J, const Vector6d& v, double max_damping,
             ControllerWorkspace* ws, Eigen::VectorXd* qdot) {
  const int n = static_cast<int>(J.cols());
  const ConstRows<R> J_t(J, 6 - R, 0, R, n);  // all rows, or the linear ones
  Rows<R> J_tN = ws->J_task.topRows<R>();
  J_tN.noalias() = J_t * ws->N;
  const Eigen::Matrix<double, R, 1> residual = v.tail<R>() - J_t * ws->a;
  Eigen::Matrix<double, R, R> JJt;
  JJt.noalias() = J_tN * J_tN.transpose();
  JJt.diagonal().array() += max_damping * max_damping;
  const Eigen::Matrix<double, R, 1> y = JJt.llt().solve(residual);
  ws->b.noalias() = J_tN.transpose() * y;
  *qdot = ws->a;
  qdot->noalias() += ws->N * ws->b;
}

}  // namespace

void SoftwareRcmController::ComputeVelocity(const robot::RobotModel& model,
                                            const robot::RobotState& state,
                                            const TaskTarget& target, ControllerWorkspace* ws,
                                            Eigen::VectorXd* qdot) const {
  const int n = model.num_positions();
  ws->Resize(n);
  qdot->resize(n);
  // The shaft is the line through A (p_LS on the shaft link) and B (the shaft link's origin).
  const Eigen::Vector3d A = state.X_WL[shaft_link_] * p_LS_;
  const Eigen::Vector3d B = state.X_WL[shaft_link_].translation();
  const Eigen::Vector3d AB = B - A;
  const double lambda = (p_WR_ - A).dot(AB) / AB.squaredNorm();
  const Eigen::Vector3d u = AB.normalized();
  Eigen::Vector3d n1 = u.cross(Eigen::Vector3d::UnitX());
  if (n1.norm() < 0.1) n1 = u.cross(Eigen::Vector3d::UnitY());
  n1.normalize();
  const Eigen::Vector3d n2 = u.cross(n1);
  kinematics::ComputeJacobian(model, state, shaft_link_, p_LS_, &ws->J_a);
  kinematics::ComputeJacobian(model, state, shaft_link_, Eigen::Vector3d::Zero(), &ws->J_b);
  // Velocity of the shaft point nearest the port, across the shaft: J_rcm (2 × n), built in the
  // top rows of J_task.
  auto J_rcm = ws->J_task.topRows<2>();
  J_rcm.row(0).noalias() = n1.transpose() * ((1.0 - lambda) * ws->J_a.bottomRows<3>() +
                                             lambda * ws->J_b.bottomRows<3>());
  J_rcm.row(1).noalias() = n2.transpose() * ((1.0 - lambda) * ws->J_a.bottomRows<3>() +
                                             lambda * ws->J_b.bottomRows<3>());
  const Eigen::Vector3d P = A + lambda * AB;
  const Eigen::Vector2d e_rcm(n1.dot(p_WR_ - P), n2.dot(p_WR_ - P));
  // Damped pseudo-inverse of the constraint: J_rcmᵀ (J_rcm J_rcmᵀ + d² I)⁻¹ (n × 2).
  Eigen::Matrix2d JJt;
  JJt.noalias() = J_rcm * J_rcm.transpose();
  JJt.diagonal().array() += 1e-3 * 1e-3;
  const Eigen::Matrix2d JJt_inverse = JJt.llt().solve(Eigen::Matrix2d::Identity());
  ws->pinv2.noalias() = J_rcm.transpose() * JJt_inverse;
  ws->a.noalias() = ws->pinv2 * (rcm_gain_ * e_rcm);  // q1: back onto the port
  ws->N.setIdentity();
  ws->N.noalias() -= ws->pinv2 * J_rcm;
  // Tool task in the constraint's null space.
  const Vector6d v = ToolTaskVelocity(model, state, target, gains_, ws);
  if (target.position_only) {
    RcmTask<3>(ws->J, v, max_damping_, ws, qdot);
  } else {
    RcmTask<6>(ws->J, v, max_damping_, ws, qdot);
  }
}

std::unique_ptr<Controller> MakeController(const std::string& name,
                                           const robot::RobotModel& model,
                                           const Vector6d& fallback_gains) {
  return MakeControllerWithGains(name, TaskGains(model, name, fallback_gains));
}

std::unique_ptr<Controller> MakeControllerWithGains(const std::string& name,
                                                    const Vector6d& gains) {
  if (name == "jt") return std::make_unique<JacobianTransposeController>(gains);
  if (name == "dls") return std::make_unique<DampedLeastSquaresController>(gains);
  if (name == "jla") return std::make_unique<JointLimitAvoidanceController>(gains);
  TROCAR_THROW("unknown controller '" << name << "' (expected jt, dls or jla)");
}

}  // namespace trocar::control
