#include "kinematics/appearance.hpp"

#include <Eigen/SVD>
#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <sstream>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "robot/load_robot.hpp"

namespace trocar::kinematics {

bool Dressing::any() const {
  return std::any_of(worn.begin(), worn.end(), [](const auto& g) { return !g.empty(); });
}

namespace {

using robot::Appearance;
using robot::Geometry;
using robot::RobotModel;

// The eight corners of a shape's box, in its link's frame.
std::array<Eigen::Vector3d, 8> Corners(const Geometry& g) {
  Eigen::Vector3d lo, hi;
  switch (g.shape) {
    case Geometry::Shape::kMesh: {
      lo = hi = Eigen::Vector3d::Zero();
      if (g.mesh && !g.mesh->vertices.empty()) {
        lo = hi = g.mesh->vertices[0].cwiseProduct(g.mesh_scale);
        for (const Eigen::Vector3d& v : g.mesh->vertices) {
          lo = lo.cwiseMin(v.cwiseProduct(g.mesh_scale));
          hi = hi.cwiseMax(v.cwiseProduct(g.mesh_scale));
        }
      }
      break;
    }
    case Geometry::Shape::kBox:
      hi = 0.5 * g.size;
      lo = -hi;
      break;
    case Geometry::Shape::kSphere:
      hi = Eigen::Vector3d::Constant(g.size.x());
      lo = -hi;
      break;
    default: {  // cylinder, capsule: radius, length along z
      const double r = g.size.x(),
                   half = 0.5 * g.size.y() + (g.shape == Geometry::Shape::kCapsule ? r : 0.0);
      hi = Eigen::Vector3d(r, r, half);
      lo = -hi;
    }
  }
  std::array<Eigen::Vector3d, 8> out;
  for (int i = 0; i < 8; ++i) {
    const Eigen::Vector3d c((i & 1) ? hi.x() : lo.x(), (i & 2) ? hi.y() : lo.y(),
                            (i & 4) ? hi.z() : lo.z());
    out[i] = g.X_LG * c;
  }
  return out;
}

// The visual shapes of `link` and of the links welded to it by fixed joints, posed in `link`.
std::vector<Geometry> WeldedVisuals(const RobotModel& model, int link) {
  std::vector<Geometry> out;
  std::vector<std::pair<int, Eigen::Isometry3d>> open{{link, Eigen::Isometry3d::Identity()}};
  while (!open.empty()) {
    const auto [l, X_RL] = open.back();
    open.pop_back();
    for (Geometry g : model.link(l).visuals) {
      g.X_LG = X_RL * g.X_LG;
      out.push_back(std::move(g));
    }
    for (int j : model.link(l).child_joints) {
      const robot::Joint& joint = model.joint(j);
      if (!joint.movable()) open.emplace_back(joint.child_link, X_RL * joint.X_PJ);
    }
  }
  return out;
}

Eigen::Vector3d RotationVector(const Eigen::Matrix3d& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.angle() * aa.axis();
}

// The rigid motion X minimising the sum of |X a_i - b_i|^2 (Kabsch).
Eigen::Isometry3d FitRigid(const std::vector<Eigen::Vector3d>& a,
                           const std::vector<Eigen::Vector3d>& b) {
  Eigen::Vector3d ca = Eigen::Vector3d::Zero(), cb = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < a.size(); ++i) {
    ca += a[i];
    cb += b[i];
  }
  ca /= static_cast<double>(a.size());
  cb /= static_cast<double>(b.size());
  Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
  for (std::size_t i = 0; i < a.size(); ++i) H += (a[i] - ca) * (b[i] - cb).transpose();
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  D(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1.0 : 1.0;
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = svd.matrixV() * D * svd.matrixU().transpose();
  X.translation() = cb - X.linear() * ca;
  return X;
}

// One appearance's links, joints and the poses of both models at the seeded configurations.
class Fit {
 public:
  Fit(const RobotModel& model, const Appearance& a, const DressingOptions& options)
      : model_(model), a_(a), options_(options), other_(robot::LoadRobot(a.urdf)) {
    ResolveNames();
    SamplePoses();
  }

  // Hand-eye: the other description's base in this robot's base frame.
  Eigen::Isometry3d BaseInBase() const {
    Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
    std::vector<std::pair<Eigen::Isometry3d, Eigen::Isometry3d>> motions;
    for (std::size_t s = 1; s < ours_.size(); ++s) {
      for (std::size_t w = 0; w < wears_.size(); ++w) {
        const Eigen::Isometry3d A = ours_[s][w] * ours_[0][w].inverse();
        const Eigen::Isometry3d B = others_[s][w] * others_[0][w].inverse();
        const Eigen::Vector3d alpha = RotationVector(A.linear()), beta = RotationVector(B.linear());
        // Near half a turn an axis's sign is arbitrary in each model alike: such motions say
        // nothing about the rotation between the bases.
        if (alpha.norm() > 0.9 * M_PI || beta.norm() > 0.9 * M_PI) continue;
        if (alpha.norm() > 1e-4 && beta.norm() > 1e-4) {
          H += beta * alpha.transpose();
        } else if (A.translation().norm() > 1e-4 && B.translation().norm() > 1e-4) {
          H += B.translation().normalized() *
               A.translation().normalized().transpose();  // t_A = R t_B
        }
        motions.emplace_back(A, B);
      }
    }
    const Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
    D(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1.0 : 1.0;
    const Eigen::Matrix3d R = svd.matrixV() * D * svd.matrixU().transpose();
    // (R_A - I) t = R t_B - t_A, least squares over every motion.
    Eigen::Matrix3d N = Eigen::Matrix3d::Zero();
    Eigen::Vector3d b = Eigen::Vector3d::Zero();
    for (const auto& [A, B] : motions) {
      const Eigen::Matrix3d M = A.linear() - Eigen::Matrix3d::Identity();
      N += M.transpose() * M;
      b += M.transpose() * (R * B.translation() - A.translation());
    }
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = R;
    X.translation() = N.completeOrthogonalDecomposition().solve(b);
    return X;
  }

  // Adds each worn link's meshes to `out`, checked at every pose.
  void Dress(Dressing* out) const {
    std::vector<std::vector<Geometry>> shapes;
    std::vector<std::vector<Eigen::Vector3d>> corners;  // per worn link, in the other's link frame
    for (const auto& [link, worn] : wears_) {
      shapes.push_back(WeldedVisuals(other_, worn));
      corners.emplace_back(1, Eigen::Vector3d::Zero());
      for (const Geometry& g : shapes.back())
        for (const Eigen::Vector3d& c : Corners(g)) corners.back().push_back(c);
    }
    // The bases' offset from the hand-eye fit, then refined with the links' offsets in turn so
    // that the worn meshes' corners lie as near their own model's as they can (each step a
    // Kabsch fit of points: the drawn distance itself is what is minimised).
    Eigen::Isometry3d X_BO = BaseInBase();
    std::vector<Eigen::Isometry3d> X_LO(wears_.size());
    for (int round = 0; round < 30; ++round) {
      for (std::size_t w = 0; w < wears_.size(); ++w) {
        std::vector<Eigen::Vector3d> a, b;
        for (std::size_t s = 0; s < ours_.size(); ++s) {
          const Eigen::Isometry3d Y = ours_[s][w].inverse() * X_BO * others_[s][w];
          for (const Eigen::Vector3d& c : corners[w]) {
            a.push_back(c);
            b.push_back(Y * c);
          }
        }
        X_LO[w] = FitRigid(a, b);
      }
      std::vector<Eigen::Vector3d> a, b;
      for (std::size_t s = 0; s < ours_.size(); ++s) {
        for (std::size_t w = 0; w < wears_.size(); ++w) {
          for (const Eigen::Vector3d& c : corners[w]) {
            a.push_back(others_[s][w] * c);
            b.push_back(ours_[s][w] * (X_LO[w] * c));
          }
        }
      }
      X_BO = FitRigid(a, b);
    }
    // Each worn link's drift over the poses; the worst over its tolerance is refused.
    double worst_excess = 0.0;
    std::size_t worst_w = 0, worst_s = 0;
    for (std::size_t w = 0; w < wears_.size(); ++w) {
      const int link = wears_[w].first;
      for (std::size_t s = 0; s < ours_.size(); ++s) {
        const Eigen::Isometry3d drawn = ours_[s][w] * X_LO[w], own = X_BO * others_[s][w];
        double off = 0.0;
        for (const Eigen::Vector3d& c : corners[w])
          off = std::max(off, (drawn * c - own * c).norm());
        out->drift[link] = std::max(out->drift[link], off);
        if (off > out->worst_m) {
          out->worst_m = off;
          out->worst_link = model_.link(link).name;
        }
        const double excess = off / tolerance_[w];
        if (excess > worst_excess) {
          worst_excess = excess;
          worst_w = w;
          worst_s = s;
        }
      }
    }
    if (worst_excess > 1.0) {
      const int link = wears_[worst_w].first;
      const double off = worst_excess * tolerance_[worst_w];
      TROCAR_THROW(a_.where << ".links." << model_.link(link).name << ": its mesh from '"
                            << other_.link(wears_[worst_w].second).name << "' would be drawn "
                            << std::round(off * 1e4) / 10 << " mm from where " << a_.urdf
                            << " puts it (" << PoseText(worst_s) << "; at most "
                            << tolerance_[worst_w] * 1e3
                            << " mm): the two models do not move alike there (check "
                               "appearance.joints: a joint driving another one, a sign "
                               "(multiplier: -1) or a zero (offset))");
    }
    for (std::size_t w = 0; w < wears_.size(); ++w) {
      const int link = wears_[w].first;
      for (Geometry g : shapes[w]) {
        g.X_LG = X_LO[w] * g.X_LG;
        out->worn[link].push_back(std::move(g));
      }
    }
  }

 private:
  void ResolveNames() {
    for (const auto& wear : a_.links) {
      const int theirs = other_.FindLink(wear.wears);
      TROCAR_THROW_UNLESS(theirs >= 0, a_.where << ".links." << wear.link << ": '" << wear.wears
                                                << "' is no link of " << a_.urdf);
      wears_.emplace_back(model_.GetLink(wear.link), theirs);
      tolerance_.push_back(a_.ToleranceOf(wear.link));
    }
    for (const auto& drive : a_.joints) {
      const robot::Joint& ours = model_.joint(model_.GetJoint(drive.joint));
      TROCAR_THROW_UNLESS(ours.drive == robot::JointDrive::kActive,
                          a_.where << ".joints." << drive.joint
                                   << ": not an active joint of this robot (only active joints "
                                      "drive a dressing; passive ones follow)");
      const int j = other_.FindJoint(drive.drives);
      TROCAR_THROW_UNLESS(j >= 0, a_.where << ".joints." << drive.joint << ": '" << drive.drives
                                           << "' is no joint of " << a_.urdf);
      TROCAR_THROW_UNLESS(other_.joint(j).drive == robot::JointDrive::kActive,
                          a_.where << ".joints." << drive.joint << ": '" << drive.drives
                                   << "' is not an active joint of " << a_.urdf);
      drives_.push_back({ours.q_index, other_.joint(j).q_index, drive.multiplier, drive.offset});
    }
  }

  void SamplePoses() {
    std::mt19937 rng(options_.seed);
    const Eigen::VectorXd lo = model_.lower_limits(), hi = model_.upper_limits();
    robot::RobotState ours(model_), other(other_);
    for (int attempt = 0;
         static_cast<int>(ours_.size()) < options_.poses && attempt < 4 * options_.poses;
         ++attempt) {
      Eigen::VectorXd q = model_.neutral_configuration(), q_other = other_.neutral_configuration();
      for (const Drive& d : drives_) {
        const bool prismatic =
            model_.joint(model_.active_joints()[d.ours]).type == robot::JointType::kPrismatic;
        const double bound = prismatic ? 0.1 : M_PI;
        const double a = std::isfinite(lo[d.ours]) ? lo[d.ours] : -bound;
        const double b = std::isfinite(hi[d.ours]) ? hi[d.ours] : bound;
        q[d.ours] = std::uniform_real_distribution<double>(a, b)(rng);
        q_other[d.theirs] = d.multiplier * q[d.ours] + d.offset;
      }
      if (!ForwardKinematics(model_, q, &ours).ok() ||
          !ForwardKinematics(other_, q_other, &other).ok())
        continue;  // a closure that cannot follow there: another pose
      std::vector<Eigen::Isometry3d> a, b;
      for (const auto& [link, worn] : wears_) {
        a.push_back(ours.X_WB.inverse() * ours.X_WL[link]);
        b.push_back(other.X_WB.inverse() * other.X_WL[worn]);
      }
      ours_.push_back(std::move(a));
      others_.push_back(std::move(b));
      q_.push_back(q);
    }
    TROCAR_THROW_UNLESS(ours_.size() >= 3, a_.where
                                               << ": the two models could not be posed alike "
                                                  "(closures refused the sampled joint values)");
  }

  std::string PoseText(std::size_t s) const {
    std::ostringstream text;
    text << "at ";
    for (std::size_t i = 0; i < drives_.size(); ++i) {
      text << (i ? ", " : "") << model_.joint(model_.active_joints()[drives_[i].ours]).name << " "
           << q_[s][drives_[i].ours];
    }
    return text.str();
  }

  struct Drive {
    int ours, theirs;
    double multiplier, offset;
  };
  const RobotModel& model_;
  const Appearance& a_;
  const DressingOptions& options_;
  RobotModel other_;
  std::vector<std::pair<int, int>> wears_;  // (our link, their link)
  std::vector<double> tolerance_;           // per worn link (m)
  std::vector<Drive> drives_;
  std::vector<std::vector<Eigen::Isometry3d>> ours_, others_;  // per pose, per worn link: X_BL
  std::vector<Eigen::VectorXd> q_;
};

}  // namespace

Dressing DressRobot(const robot::RobotModel& model, const DressingOptions& options) {
  Dressing out;
  out.worn.resize(model.num_links());
  out.drift.assign(model.num_links(), 0.0);
  for (const Appearance& a : model.defaults().appearances) {
    if (!IsRegularFile(a.urdf)) {
      out.notes.push_back(a.where + ": " + a.urdf +
                          " not found: its links are drawn with their own shapes");
      continue;
    }
    Fit(model, a, options).Dress(&out);
  }
  return out;
}

}  // namespace trocar::kinematics
