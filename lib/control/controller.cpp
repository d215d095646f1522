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
/// Solves L Lᵀ x = b from a Cholesky factor (the lower triangle of `llt`), unrolled for R, with
/// the diagonal's reciprocals: Eigen's general triangular solves divided on the critical path and
/// were a fifth of a PSM control step (bench/control_bench).
template <int R>
struct CholeskySolve {
  explicit CholeskySolve(const Eigen::Matrix<double, R, R>& llt) : L(llt) {
    for (int i = 0; i < R; ++i) inverse_diagonal[i] = 1.0 / L(i, i);
  }
  Eigen::Matrix<double, R, 1> operator()(const Eigen::Matrix<double, R, 1>& b) const {
    Eigen::Matrix<double, R, 1> y;
    for (int i = 0; i < R; ++i) {  // L y = b
      double s = b[i];
      for (int j = 0; j < i; ++j) s -= L(i, j) * y[j];
      y[i] = s * inverse_diagonal[i];
    }
    for (int i = R - 1; i >= 0; --i) {  // Lᵀ x = y, in place
      double s = y[i];
      for (int j = i + 1; j < R; ++j) s -= L(j, i) * y[j];
      y[i] = s * inverse_diagonal[i];
    }
    return y;
  }
  const Eigen::Matrix<double, R, R>& L;
  double inverse_diagonal[R];
};

template <int R>
using ConstRows = Eigen::Block<const kinematics::Matrix6Xd, R, Eigen::Dynamic, false>;

// y = (J Jᵀ + λ² I)⁻¹ v with λ growing smoothly as the smallest singular value of J drops below
// `threshold` (at most `max_damping`); q̇ = Jᵀ y is then the damped least-squares solution.
// σ_min² (the smallest eigenvalue of J Jᵀ) comes from inverse iteration on the factorisation the
// solve needs anyway, started from the last step's direction (`warm`): one or two iterations
// when the arm moves smoothly. Its estimate never falls below the true value; it stops when two
// estimates agree to 1e-4 (relative). A full eigen-decomposition per step cost more than the
// rest of the step.
template <int R, typename JacobianRows>
Eigen::Matrix<double, R, 1> DampedSolve(const JacobianRows& J, const Eigen::Matrix<double, R, 1>& v,
                                        double max_damping, double threshold, Vector6d* warm) {
  using Vector = Eigen::Matrix<double, R, 1>;
  Eigen::Matrix<double, R, R> JJt;
  JJt.noalias() = J * J.transpose();
  JJt.diagonal().array() += 1e-12;
  // Cholesky: J Jᵀ + εI is symmetric positive definite (no pivoting needed; cheaper than LDLT).
  Eigen::LLT<Eigen::Matrix<double, R, R>> chol(JJt);
  Vector x = warm->head<R>();
  if (!(x.squaredNorm() > 0.5)) x = Vector::Constant(1.0 / std::sqrt(static_cast<double>(R)));
  double lambda_min = HUGE_VAL;
  // A factorisation that failed (J J^T singular to rounding) is a singular arm: full damping.
  if (chol.info() != Eigen::Success) lambda_min = 0.0;
  const CholeskySolve<R> solve(chol.matrixLLT());
  for (int iteration = 0; iteration < 100 && lambda_min > 0.0; ++iteration) {
    const Vector y = solve(x);
    const double norm = y.norm();
    if (!(norm > 0.0) || !std::isfinite(norm)) {  // singular to working precision
      lambda_min = 0.0;
      break;
    }
    const double estimate = 1.0 / norm;  // ≥ λ_min for a unit x
    x = y / norm;
    const bool settled = std::abs(lambda_min - estimate) <= 1e-4 * estimate;
    lambda_min = estimate;
    if (settled) break;
  }
  warm->head<R>() = x;
  const double sigma_min = std::sqrt(std::max(0.0, lambda_min - 1e-12));
  if (sigma_min >= threshold) return solve(v);
  const double ratio = sigma_min / threshold;
  const double lambda2 = (1.0 - ratio * ratio) * max_damping * max_damping;
  JJt.diagonal().array() += lambda2;
  return JJt.llt().solve(v);
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
  Rows<R> Jr = ws->J_task.topRows<R>();
  Jr = J.bottomRows<R>();  // R = 6: all rows; R = 3: the linear ones
  if (use_frozen) {
    for (int k = 0; k < n; ++k) {
      if (ws->frozen[static_cast<std::size_t>(k)]) Jr.col(k).setZero();
    }
  }
  const Eigen::Matrix<double, R, 1> task = v.tail<R>();
  const Eigen::Matrix<double, R, 1> y = DampedSolve<R>(Jr, task, max_damping, threshold, &ws->sigma_direction);
  qdot->noalias() = Jr.transpose() * y;
}

}  // namespace

Vector6d TaskGains(const robot::RobotModel& model, const std::string& name,
                   const Vector6d& fallback) {
  const auto& settings = model.controller();
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
