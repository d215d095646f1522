#pragma once
/// @file
/// Denavit-Hartenberg tables: the standard (distal) and modified (Craig, proximal) conventions.
///
/// Row i gives α, a, d, θ and an offset. For a revolute joint θ_total = θ + q + offset and d is
/// constant; for a prismatic joint d_total = d + q + offset and θ is constant (the dVRK's
/// convention: "the offset adds to θ for a revolute joint and to d for the prismatic joint").
/// - standard:  X_{i-1,i} = Rz(θ_i) Tz(d_i) Tx(a_i) Rx(α_i)
/// - modified:  X_{i-1,i} = Rx(α_i) Tx(a_i) Rz(θ_i) Tz(d_i)   (α, a of the row are α_{i-1}, a_{i-1})
/// The tool pose is X_BT = X_B0 · Π X_{i-1,i} · X_NT.

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "robot/robot_model.hpp"

namespace trocar::robot {

enum class DhConvention { kStandard, kModified };
const char* ToString(DhConvention convention);

struct DhRow {
  std::string joint;  ///< joint name
  std::string link;   ///< name of the link the joint moves
  JointType type = JointType::kRevolute;
  double alpha = 0.0;
  double a = 0.0;
  double d = 0.0;
  double theta = 0.0;
  double offset = 0.0;
  JointLimits limits;
  std::vector<Geometry> visuals;     ///< in the link frame (modified: DH frame i)
  std::vector<Geometry> collisions;
};

struct DhTable {
  DhConvention convention = DhConvention::kModified;
  std::string base_link = "base";
  Eigen::Isometry3d X_B0 = Eigen::Isometry3d::Identity();  ///< DH frame 0 in the base link
  std::vector<DhRow> rows;
  Eigen::Isometry3d X_NT = Eigen::Isometry3d::Identity();  ///< tool in the last DH frame
};

/// X_{i-1,i} of one row at joint value q.
Eigen::Isometry3d DhRowTransform(DhConvention convention, const DhRow& row, double q);

/// Tool pose in the base link, X_BT(q), computed directly from the table (a reference
/// implementation independent of the tree kinematics).
Eigen::Isometry3d DhToolPose(const DhTable& table, const Eigen::VectorXd& q);

/// Adds the table's links and joints to `builder` as a serial chain from `table.base_link` (which
/// is added too) and sets the tool frame. In the modified convention link i's frame is DH frame i;
/// in the standard convention it is frame i−1 turned by joint i, and a fixed "<link>_dh" link
/// carries DH frame n.
void AddDhChain(const DhTable& table, RobotModelBuilder* builder);

}  // namespace trocar::robot
