#include "kinematics/jacobian.hpp"

namespace trocar::kinematics {

using robot::Joint;
using robot::JointDrive;
using robot::JointType;

void ComputeJacobian(const robot::RobotModel& model, const robot::RobotState& state, int link,
                     const Eigen::Vector3d& p_LF, Matrix6Xd* J_WF) {
  const int nq = model.num_positions();
  J_WF->resize(6, nq);
  J_WF->setZero();
  const Eigen::Vector3d p_WF = state.X_WL[link] * p_LF;
  for (int j : model.movable_path(link)) {
    const Joint& joint = model.joint(j);
    const Eigen::Isometry3d& X_WC = state.X_WL[joint.child_link];
    // The joint's axis in the world: the child frame's z column in the common case (DH, most
    // URDFs), else the rotated axis.
    const Eigen::Vector3d e_W =
        joint.axis_J.z() == 1.0 ? Eigen::Vector3d(X_WC.linear().col(2)) : Eigen::Vector3d(X_WC.linear() * joint.axis_J);
    Eigen::Matrix<double, 6, 1> column;
    if (joint.type == JointType::kRevolute) {
      column.head<3>() = e_W;
      column.tail<3>() = e_W.cross(p_WF - X_WC.translation());
    } else {
      column.head<3>().setZero();
      column.tail<3>() = e_W;
    }
    if (joint.drive == JointDrive::kActive) {
      J_WF->col(joint.q_index) += column;
    } else {
      const auto gradient = state.dvalues_dq.row(joint.dof_index);
      for (int k = 0; k < nq; ++k) {
        if (gradient[k] != 0.0) J_WF->col(k) += gradient[k] * column;
      }
    }
  }
}

void ComputeFrameJacobian(const robot::RobotModel& model, const robot::RobotState& state,
                          const robot::Frame& frame, Matrix6Xd* J_WF) {
  ComputeJacobian(model, state, frame.link, frame.X_LF.translation(), J_WF);
}

}  // namespace trocar::kinematics
