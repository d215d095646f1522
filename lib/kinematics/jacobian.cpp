#include "kinematics/jacobian.hpp"

namespace trocar::kinematics {

using robot::Joint;
using robot::JointDrive;
using robot::JointType;

namespace {

/// A joint's column for the point p_WF, written into `out` (6 values): [e; e × (p_WF − o)]
/// revolute, [0; e] prismatic. Scalar stores into the destination itself: a column returned by
/// value was stored in halves and loaded whole, a store-forwarding stall per column.
inline void WriteColumn(const Joint& joint, const robot::RobotState& state, const Eigen::Vector3d& p_WF, double* out) {
  const Eigen::Isometry3d& X_WC = state.X_WL[joint.child_link];
  // The joint's axis in the world: the child frame's z column in the common case (DH, most
  // URDFs), else the rotated axis.
  const Eigen::Vector3d e =
      joint.axis_J.z() == 1.0 ? Eigen::Vector3d(X_WC.linear().col(2)) : Eigen::Vector3d(X_WC.linear() * joint.axis_J);
  if (joint.type == JointType::kRevolute) {
    const Eigen::Vector3d d = p_WF - X_WC.translation();
    out[0] = e.x();
    out[1] = e.y();
    out[2] = e.z();
    out[3] = e.y() * d.z() - e.z() * d.y();
    out[4] = e.z() * d.x() - e.x() * d.z();
    out[5] = e.x() * d.y() - e.y() * d.x();
  } else {
    out[0] = out[1] = out[2] = 0.0;
    out[3] = e.x();
    out[4] = e.y();
    out[5] = e.z();
  }
}

}  // namespace

void ComputeJacobian(const robot::RobotModel& model, const robot::RobotState& state, int link,
                     const Eigen::Vector3d& p_LF, Matrix6Xd* J_WF) {
  const int nq = model.num_positions();
  J_WF->resize(6, nq);
  J_WF->setZero();
  const Eigen::Vector3d p_WF = state.X_WL[link] * p_LF;
  const std::vector<int>& path = model.movable_path(link);
  const std::vector<Joint>& joints = model.joints();
  // Active joints' columns written whole (each is on the path once), then mimic and closure
  // joints added through d joint_values / d q: no column is read back right after the zeroing
  // wrote it (a store-forwarding stall that was half the Jacobian's time).
  bool passive = false;
  for (int j : path) {
    const Joint& joint = joints[j];
    if (joint.drive == JointDrive::kActive) {
      WriteColumn(joint, state, p_WF, J_WF->col(joint.q_index).data());
    } else {
      passive = true;
    }
  }
  if (!passive) return;
  for (int j : path) {
    const Joint& joint = joints[j];
    if (joint.drive == JointDrive::kActive) continue;
    Eigen::Matrix<double, 6, 1> column;
    WriteColumn(joint, state, p_WF, column.data());
    const auto gradient = state.dvalues_dq.row(joint.dof_index);
    for (int k = 0; k < nq; ++k) {
      if (gradient[k] != 0.0) J_WF->col(k) += gradient[k] * column;
    }
  }
}

void ComputeFrameJacobian(const robot::RobotModel& model, const robot::RobotState& state,
                          const robot::Frame& frame, Matrix6Xd* J_WF) {
  ComputeJacobian(model, state, frame.link, frame.X_LF.translation(), J_WF);
}

Eigen::MatrixXd PseudoInverse(const Eigen::JacobiSVD<Eigen::MatrixXd>& svd, double relative_cutoff) {
  const Eigen::VectorXd& sigma = svd.singularValues();
  Eigen::VectorXd inverse = Eigen::VectorXd::Zero(sigma.size());
  for (int i = 0; i < sigma.size(); ++i) {
    if (sigma[i] > relative_cutoff * sigma[0]) inverse[i] = 1.0 / sigma[i];
  }
  return svd.matrixV() * inverse.asDiagonal() * svd.matrixU().transpose();
}

}  // namespace trocar::kinematics
