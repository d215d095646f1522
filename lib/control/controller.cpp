#include "control/controller.hpp"

#include <cmath>

#include <Eigen/Eigenvalues>
#include <Eigen/QR>

#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"

namespace trocar::control {

namespace {

// Task velocity V_d + K e for the tool, after filling the tool Jacobian into the workspace.
Vector6d ToolTaskVelocity(const robot::RobotModel& model, const robot::RobotState& state,
                          const TaskTarget& target, const Vector6d& gains,
                          ControllerWorkspace* ws) {
  kinematics::ComputeFrameJacobian(model, state, model.tool_frame(), &ws->J);
  return target.V_WD +
         gains.asDiagonal() * TaskError(target.X_WD, kinematics::FramePose(state, model.tool_frame()));
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
  kinematics::ComputeFrameJacobian(model, state, model.tool_frame(), &ws->J);
  Vector6d e = TaskError(target.X_WD, kinematics::FramePose(state, model.tool_frame()));
  if (target.position_only) e.head<3>().setZero();
  qdot->noalias() = ws->J.transpose() * (gains_.asDiagonal() * e);
}

Eigen::VectorXd DampedLeastSquaresController::Solve(const kinematics::Matrix6Xd& J_full,
                                                    const Vector6d& v, bool position_only,
                                                    const std::vector<bool>& frozen) const {
  const int rows = position_only ? 3 : 6;
  Eigen::MatrixXd J = position_only ? Eigen::MatrixXd(J_full.bottomRows<3>())
                                    : Eigen::MatrixXd(J_full);
  for (std::size_t k = 0; k < frozen.size(); ++k) {
    if (frozen[k]) J.col(static_cast<Eigen::Index>(k)).setZero();
  }
  const Eigen::VectorXd task = position_only ? Eigen::VectorXd(v.tail<3>()) : Eigen::VectorXd(v);
  Eigen::MatrixXd JJt = J * J.transpose();
  // Damping grows smoothly as the smallest singular value drops below the threshold.
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(JJt, Eigen::EigenvaluesOnly);
  const double sigma_min = std::sqrt(std::max(0.0, eig.eigenvalues()[0]));
  double lambda2 = 0.0;
  if (sigma_min < singular_threshold_) {
    const double ratio = sigma_min / singular_threshold_;
    lambda2 = (1.0 - ratio * ratio) * max_damping_ * max_damping_;
  }
  JJt.diagonal().array() += lambda2 + 1e-12;
  (void)rows;
  return J.transpose() * JJt.ldlt().solve(task);
}

void DampedLeastSquaresController::ComputeVelocity(const robot::RobotModel& model,
                                                   const robot::RobotState& state,
                                                   const TaskTarget& target,
                                                   ControllerWorkspace* ws,
                                                   Eigen::VectorXd* qdot) const {
  *qdot = Solve(ws->J, ToolTaskVelocity(model, state, target, gains_, ws), target.position_only, {});
}

void JointLimitAvoidanceController::ComputeVelocity(const robot::RobotModel& model,
                                                    const robot::RobotState& state,
                                                    const TaskTarget& target,
                                                    ControllerWorkspace* ws,
                                                    Eigen::VectorXd* qdot) const {
  const Vector6d v = ToolTaskVelocity(model, state, target, gains_, ws);
  const int n = model.num_positions();
  // Secondary motion: the gradient of Σ ((q − mid) / range)², pushing toward mid-range.
  Eigen::VectorXd q0 = Eigen::VectorXd::Zero(n);
  for (int i = 0; i < n; ++i) {
    const auto& l = model.joint(model.active_joints()[i]).limits;
    if (!std::isfinite(l.lower) || !std::isfinite(l.upper) || l.upper <= l.lower) continue;
    const double range = l.upper - l.lower;
    q0[i] = -avoidance_gain_ * (state.q[i] - 0.5 * (l.lower + l.upper)) / (range * range) * 4.0;
  }
  std::vector<bool> frozen(n, false);
  const Eigen::MatrixXd J_task = target.position_only ? Eigen::MatrixXd(ws->J.bottomRows<3>())
                                                      : Eigen::MatrixXd(ws->J);
  for (int pass = 0; pass <= n; ++pass) {
    Eigen::VectorXd primary = Solve(ws->J, v, target.position_only, frozen);
    // Null-space projection of the secondary motion through the same (frozen) Jacobian.
    Eigen::MatrixXd J = J_task;
    for (int k = 0; k < n; ++k) {
      if (frozen[k]) J.col(k).setZero();
    }
    Eigen::VectorXd secondary = q0;
    for (int k = 0; k < n; ++k) {
      if (frozen[k]) secondary[k] = 0.0;
    }
    // Exact projection onto the null space (no damping here: it would leak into the task).
    const Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd> cod(J);
    secondary -= cod.solve(J * secondary);
    *qdot = primary + secondary;
    bool changed = false;
    for (int i = 0; i < n; ++i) {
      if (frozen[i]) continue;
      const auto& l = model.joint(model.active_joints()[i]).limits;
      const bool at_upper = state.q[i] >= l.upper - 1e-6 && (*qdot)[i] > 0;
      const bool at_lower = state.q[i] <= l.lower + 1e-6 && (*qdot)[i] < 0;
      if (at_upper || at_lower) {
        frozen[i] = true;
        changed = true;
      }
    }
    if (!changed) break;
  }
  for (int i = 0; i < n; ++i) {
    if (frozen[i]) (*qdot)[i] = 0.0;
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

void SoftwareRcmController::ComputeVelocity(const robot::RobotModel& model,
                                            const robot::RobotState& state,
                                            const TaskTarget& target, ControllerWorkspace* ws,
                                            Eigen::VectorXd* qdot) const {
  const int n = model.num_positions();
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
  kinematics::Matrix6Xd J_A, J_B;
  kinematics::ComputeJacobian(model, state, shaft_link_, p_LS_, &J_A);
  kinematics::ComputeJacobian(model, state, shaft_link_, Eigen::Vector3d::Zero(), &J_B);
  // Velocity of the shaft point nearest the port, across the shaft.
  const Eigen::MatrixXd J_P = (1.0 - lambda) * J_A.bottomRows<3>() + lambda * J_B.bottomRows<3>();
  Eigen::MatrixXd J_rcm(2, n);
  J_rcm.row(0) = n1.transpose() * J_P;
  J_rcm.row(1) = n2.transpose() * J_P;
  const Eigen::Vector3d P = A + lambda * AB;
  const Eigen::Vector2d e_rcm(n1.dot(p_WR_ - P), n2.dot(p_WR_ - P));
  auto dls_pinv = [](const Eigen::MatrixXd& J, double damping) {
    Eigen::MatrixXd JJt = J * J.transpose();
    JJt.diagonal().array() += damping * damping;
    return Eigen::MatrixXd(J.transpose() * JJt.ldlt().solve(Eigen::MatrixXd::Identity(J.rows(), J.rows())));
  };
  const Eigen::MatrixXd J_rcm_pinv = dls_pinv(J_rcm, 1e-3);
  const Eigen::VectorXd q1 = J_rcm_pinv * (rcm_gain_ * e_rcm);
  const Eigen::MatrixXd N = Eigen::MatrixXd::Identity(n, n) - J_rcm_pinv * J_rcm;
  // Tool task in the constraint's null space.
  const Vector6d v = ToolTaskVelocity(model, state, target, gains_, ws);
  Eigen::MatrixXd J_t = target.position_only ? Eigen::MatrixXd(ws->J.bottomRows<3>())
                                             : Eigen::MatrixXd(ws->J);
  const Eigen::VectorXd v_t = target.position_only ? Eigen::VectorXd(v.tail<3>()) : Eigen::VectorXd(v);
  const Eigen::MatrixXd J_tN = J_t * N;
  *qdot = q1 + N * (dls_pinv(J_tN, max_damping_) * (v_t - J_t * q1));
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
