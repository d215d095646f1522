#include "kinematics/dh_extraction.hpp"

#include <cmath>

#include "kinematics/forward_kinematics.hpp"

namespace trocar::kinematics {

using robot::DhRow;
using robot::DhTable;
using robot::JointType;

namespace {

constexpr double kEps = 1e-10;

double SignedAngle(const Eigen::Vector3d& from, const Eigen::Vector3d& to,
                   const Eigen::Vector3d& about) {
  return std::atan2(from.cross(to).dot(about), from.dot(to));
}

Eigen::Vector3d AnyPerpendicular(const Eigen::Vector3d& z, const Eigen::Vector3d& hint) {
  Eigen::Vector3d x = hint - hint.dot(z) * z;
  if (x.norm() < 1e-9) {
    const Eigen::Vector3d other =
        std::abs(z.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
    x = other - other.dot(z) * z;
  }
  return x.normalized();
}

}  // namespace

std::optional<DhTable> ExtractModifiedDh(const robot::RobotModel& model, std::string* why_not) {
  const std::vector<int>& path = model.movable_path(model.tool_frame().link);
  if (path.empty()) {
    *why_not = "no movable joint between the base and the tool";
    return std::nullopt;
  }
  if (path != model.active_joints()) {
    *why_not =
        "the active joints are not one serial chain from the base to the tool (mimic, closure "
        "or held joints on the way, or active joints on other branches)";
    return std::nullopt;
  }
  const int n = static_cast<int>(path.size());
  robot::RobotState state(model);
  state.joint_values.setZero();
  ForwardKinematics(model, &state);
  const Eigen::Isometry3d X_BW = state.X_WL[model.base_link()].inverse();

  std::vector<Eigen::Vector3d> o(n), z(n);
  for (int i = 0; i < n; ++i) {
    const robot::Joint& joint = model.joint(path[i]);
    const Eigen::Isometry3d X_BC = X_BW * state.X_WL[joint.child_link];
    o[i] = X_BC.translation();
    z[i] = X_BC.linear() * joint.axis_J;
  }
  const Eigen::Isometry3d X_BT = X_BW * FramePose(state, model.tool_frame());

  // Frames F_i: origin O[i] on axis i, x[i] along the common normal to axis i+1.
  std::vector<Eigen::Vector3d> O(n), x(n), foot(n);  // foot[i]: where normal i meets axis i+1
  std::vector<double> a(n, 0.0);
  Eigen::Vector3d previous_foot = o[0];
  // Where the sign of x is free (intersecting axes), keep it close to the previous x, starting
  // from the base's x, so that offsets stay small and familiar tables come out as published.
  const Eigen::Vector3d x_hint = Eigen::Vector3d::UnitX();
  for (int i = 0; i + 1 < n; ++i) {
    const Eigen::Vector3d w = z[i].cross(z[i + 1]);
    if (w.norm() > 1e-9) {
      const Eigen::Vector3d r = o[i + 1] - o[i];
      const double t = r.cross(z[i + 1]).dot(w) / w.squaredNorm();
      const double s = r.cross(z[i]).dot(w) / w.squaredNorm();
      O[i] = o[i] + t * z[i];
      foot[i] = o[i + 1] + s * z[i + 1];
    } else {
      // Parallel axes: the normal through where the previous one met this axis (d = 0).
      O[i] = o[i] + (previous_foot - o[i]).dot(z[i]) * z[i];
      foot[i] = o[i + 1] + (O[i] - o[i + 1]).dot(z[i + 1]) * z[i + 1];
    }
    const Eigen::Vector3d normal = foot[i] - O[i];
    if (normal.norm() > kEps) {
      x[i] = normal.normalized();
      a[i] = normal.norm();
    } else if (w.norm() > 1e-9) {
      x[i] = w.normalized();
      const Eigen::Vector3d& previous_x = i > 0 ? x[i - 1] : x_hint;
      if (x[i].dot(previous_x) < 0) x[i] = -x[i];
    } else {
      x[i] = AnyPerpendicular(z[i], i > 0 ? x[i - 1] : x_hint);
    }
    previous_foot = foot[i];
  }
  // Last frame: on the previous normal's foot, x carried over (so d_n = 0 and θ offset_n = 0).
  O[n - 1] = n > 1 ? foot[n - 2] : o[0];
  x[n - 1] = n > 1 ? x[n - 2] : AnyPerpendicular(z[0], x_hint);

  auto frame = [&](int i) {
    Eigen::Isometry3d F = Eigen::Isometry3d::Identity();
    F.linear().col(0) = x[i];
    F.linear().col(1) = z[i].cross(x[i]);
    F.linear().col(2) = z[i];
    F.translation() = O[i];
    return F;
  };

  DhTable table;
  table.convention = robot::DhConvention::kModified;
  table.base_link = model.link(model.base_link()).name;
  table.X_B0 = frame(0);
  for (int i = 0; i < n; ++i) {
    const robot::Joint& joint = model.joint(path[i]);
    DhRow row;
    row.joint = joint.name;
    row.link = model.link(joint.child_link).name;
    row.type = joint.type;
    row.limits = joint.limits;
    double theta = 0.0, d = 0.0;
    if (i > 0) {
      row.alpha = SignedAngle(z[i - 1], z[i], x[i - 1]);
      row.a = a[i - 1];
      theta = SignedAngle(x[i - 1], x[i], z[i]);
      d = (O[i] - foot[i - 1]).dot(z[i]);
    }
    if (joint.type == JointType::kRevolute) {
      row.offset = theta;
      row.d = d;
    } else {
      row.theta = theta;
      row.offset = d;
    }
    table.rows.push_back(row);
  }
  table.X_NT = frame(n - 1).inverse() * X_BT;
  return table;
}

}  // namespace trocar::kinematics
