#include "robot/dh_table.hpp"

#include "common/error.hpp"
#include "common/geometry.hpp"

namespace trocar::robot {

const char* ToString(DhConvention convention) {
  return convention == DhConvention::kStandard ? "standard" : "modified";
}

Eigen::Isometry3d DhRowTransform(DhConvention convention, const DhRow& row, double q) {
  const bool revolute = row.type == JointType::kRevolute;
  const double theta = row.theta + (revolute ? q + row.offset : 0.0);
  const double d = row.d + (revolute ? 0.0 : q + row.offset);
  if (convention == DhConvention::kStandard) {
    return RotZ(theta) * TransZ(d) * TransX(row.a) * RotX(row.alpha);
  }
  return RotX(row.alpha) * TransX(row.a) * RotZ(theta) * TransZ(d);
}

Eigen::Isometry3d DhToolPose(const DhTable& table, const Eigen::VectorXd& q) {
  TROCAR_THROW_UNLESS(q.size() == static_cast<Eigen::Index>(table.rows.size()),
                      "DH table: configuration has " << q.size() << " values, expected "
                                                     << table.rows.size());
  Eigen::Isometry3d X = table.X_B0;
  for (std::size_t i = 0; i < table.rows.size(); ++i) {
    X = X * DhRowTransform(table.convention, table.rows[i], q[i]);
  }
  return X * table.X_NT;
}

void AddDhChain(const DhTable& table, RobotModelBuilder* builder) {
  TROCAR_THROW_UNLESS(!table.rows.empty(), builder->source() << ": DH table has no joints");
  builder->AddLink(table.base_link);
  std::string parent = table.base_link;
  // Constant part carried from the previous row into this joint's origin (standard convention).
  Eigen::Isometry3d carry = table.X_B0;
  for (std::size_t i = 0; i < table.rows.size(); ++i) {
    const DhRow& row = table.rows[i];
    const bool revolute = row.type == JointType::kRevolute;
    TROCAR_THROW_UNLESS(row.type != JointType::kFixed,
                        builder->source() << ": DH joint '" << row.joint
                                          << "' must be revolute or prismatic");
    RobotModelBuilder::LinkSpec& link = builder->AddLink(row.link);
    link.visuals = row.visuals;
    link.collisions = row.collisions;
    RobotModelBuilder::JointSpec& joint = builder->AddJoint(row.joint);
    joint.type = row.type;
    joint.parent = parent;
    joint.child = row.link;
    joint.axis = Eigen::Vector3d::UnitZ();
    joint.limits = row.limits;
    // Zero-motion part of the row: everything but the joint's own motion along/about z.
    const Eigen::Isometry3d fixed_motion = revolute ? RotZ(row.theta + row.offset) * TransZ(row.d)
                                                    : RotZ(row.theta) * TransZ(row.d + row.offset);
    if (table.convention == DhConvention::kModified) {
      joint.X_PJ = carry * RotX(row.alpha) * TransX(row.a) * fixed_motion;
      carry = Eigen::Isometry3d::Identity();
    } else {
      // Rz(θ) Tz(d) commute, so the joint's motion can sit at the end of the origin.
      joint.X_PJ = carry * fixed_motion;
      carry = TransX(row.a) * RotX(row.alpha);
    }
    parent = row.link;
  }
  std::string tool_link = parent;
  if (table.convention == DhConvention::kStandard) {
    tool_link = parent + "_dh";
    builder->AddLink(tool_link);
    RobotModelBuilder::JointSpec& joint = builder->AddJoint(tool_link + "_fixed");
    joint.type = JointType::kFixed;
    joint.parent = parent;
    joint.child = tool_link;
    joint.X_PJ = carry;
  }
  builder->SetTool({"tool", tool_link, table.X_NT});
}

}  // namespace trocar::robot
