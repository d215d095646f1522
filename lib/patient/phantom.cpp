#include "patient/phantom.hpp"

#include <cmath>
#include <filesystem>
#include <iomanip>
#include <random>
#include <sstream>

#include <nlohmann/json.hpp>

#include "common/error.hpp"
#include "common/limits.hpp"
#include "common/file_util.hpp"
#include "patient/markups.hpp"

namespace trocar::patient {
namespace {

void Check(double value, double lo, double hi, const char* name) {
  TROCAR_THROW_UNLESS(std::isfinite(value) && value >= lo && value <= hi,
                      "phantom: " << name << " = " << value << " is outside [" << lo << ", " << hi
                                  << "]");
}

// Rib geometry shared by the volume and the truth.
struct RibLayout {
  double a_r, b_r;        // ellipse of the rib centrelines (m)
  double phi0, phi1;      // rib extent: from beside the spine to the costal cartilage
  double z_top, spacing, drop;
  double Z(int k, double phi) const {
    return z_top - k * spacing - drop * (phi - phi0) / (phi1 - phi0);
  }
  Eigen::Vector3d Point(int side, int k, double phi) const {
    return {side * a_r * std::sin(phi), b_r * std::cos(phi), Z(k, phi)};
  }
};

// Sets every voxel within `radius` of the polyline to `value`.
void StampTube(const Curve& curve, double radius, float value, Volume* v) {
  const Eigen::Matrix3d to_index = v->index_to_P.inverse();
  const double voxel = v->spacing().minCoeff();
  for (std::size_t s = 0; s + 1 < curve.size(); ++s) {
    const Eigen::Vector3d a = curve[s], b = curve[s + 1];
    const int steps = std::max(1, static_cast<int>(std::ceil((b - a).norm() / (0.5 * voxel))));
    for (int t = 0; t <= steps; ++t) {
      const Eigen::Vector3d p = a + (b - a) * (static_cast<double>(t) / steps);
      const Eigen::Vector3d c = to_index * (p - v->origin_P);
      const int reach = static_cast<int>(std::ceil(radius / voxel)) + 1;
      for (int dk = -reach; dk <= reach; ++dk) {
        for (int dj = -reach; dj <= reach; ++dj) {
          for (int di = -reach; di <= reach; ++di) {
            const int i = static_cast<int>(std::lround(c.x())) + di;
            const int j = static_cast<int>(std::lround(c.y())) + dj;
            const int k = static_cast<int>(std::lround(c.z())) + dk;
            if (i < 0 || j < 0 || k < 0 || i >= v->size.x() || j >= v->size.y() || k >= v->size.z()) continue;
            // The voxel nearest the curve always belongs to it, so that a vessel thinner than a
            // voxel still shows.
            const bool nearest = di == 0 && dj == 0 && dk == 0;
            if (nearest || (v->PatientPoint(i, j, k) - p).norm() <= radius) {
              v->values[v->Index(i, j, k)] = value;
            }
          }
        }
      }
    }
  }
}

}  // namespace

namespace {

// GeneratePhantom's checks of its parameters, each naming the parameter and its range.
void CheckParameters(const PhantomParameters& in) {
  Check(in.body_width, 0.20, 0.60, "body_width");
  Check(in.body_depth, 0.14, 0.45, "body_depth");
  Check(in.length, 0.15, 0.60, "length");
  Check(in.fat_thickness, 0.0, 0.06, "fat_thickness");
  Check(in.wall_thickness, 0.003, 0.03, "wall_thickness");
  Check(in.ribs_per_side, 2, 12, "ribs_per_side");
  Check(in.rib_spacing, 0.015, 0.05, "rib_spacing");
  Check(in.rib_radius, 0.002, 0.012, "rib_radius");
  Check(in.rib_drop, 0.0, 0.12, "rib_drop");
  Check(in.heart_scale, 0.6, 1.5, "heart_scale");
  Check(in.voxel_size, 0.0005, 0.005, "voxel_size");
  TROCAR_THROW_UNLESS(!in.shoulders || in.wall_thickness >= 0.02,
                      "phantom: shoulders need wall_thickness of at least 0.02 m (the shoulder blade lies in "
                      "the back's muscle), not " << in.wall_thickness);
  TROCAR_THROW_UNLESS(in.slice_spacing == 0.0 || (std::isfinite(in.slice_spacing) && in.slice_spacing >= 0.0005 &&
                                                  in.slice_spacing <= 0.006),
                      "phantom: slice_spacing " << in.slice_spacing << " outside 0.0005..0.006 m (or 0: the voxel size)");
  TROCAR_THROW_UNLESS(std::isnan(in.table_gap) || (in.table_gap >= -0.01 && in.table_gap <= 0.05),
                      "phantom: table_gap " << in.table_gap << " outside -0.01..0.05 m");
  TROCAR_THROW_UNLESS(in.heart_offset.allFinite() && in.heart_offset.norm() < 0.05,
                      "phantom: heart_offset " << in.heart_offset.transpose()
                                               << " must be finite and under 0.05 m");
  TROCAR_THROW_UNLESS(in.rib_spacing * 1.04 * (in.ribs_per_side - 1) + in.rib_drop + 0.05 <= in.length,
                      "phantom: " << in.ribs_per_side << " ribs " << in.rib_spacing
                                  << " m apart do not fit in a length of " << in.length << " m");
}

// The LAD on the heart's surface in the heart's unit coordinates, base (t = -0.7) to apex
// (t = 0.9) along the long axis, a little toward the left ventricle (u).
Eigen::Vector3d LadUnit(double t) {
  const double u = 0.15;
  return Eigen::Vector3d(t, u, std::sqrt(std::max(0.0, 1.0 - t * t - u * u)));
}

// GeneratePhantom's stages: the body's layout (seeded), the grid, each voxel's tissue, then the
// truth's curves and the tubes stamped along them.
class PhantomBuilder {
 public:
  explicit PhantomBuilder(const PhantomParameters& in) : in_(in) {
    out_.parameters = in;
    Layout();
    PlaceHeart();
  }

  Phantom Build() {
    Grid();
    FillVoxels();
    RibAndSpaceTruth();
    ArteryTruth();
    StampTubes();
    return std::move(out_);
  }

 private:
  // Small seeded variation: body ±3 %, rib spacing ±4 %, heart position ±5 mm.
  void Layout() {
    std::mt19937 rng(in_.seed);
    std::uniform_real_distribution<double> jitter(-1.0, 1.0);
    a_ = 0.5 * in_.body_width * (1.0 + 0.03 * jitter(rng));
    b_ = 0.5 * in_.body_depth * (1.0 + 0.03 * jitter(rng));
    spacing_ = in_.rib_spacing * (1.0 + 0.04 * jitter(rng));
    // Drawn z, y, x: the order g++ evaluated the three arguments of one constructor call in
    // before stop 64 (an order C++ leaves unspecified, so clang's builds drew another heart),
    // kept so that the phantoms stay as they were.
    const double jz = 0.005 * jitter(rng);
    const double jy = 0.005 * jitter(rng);
    const double jx = 0.005 * jitter(rng);
    heart_jitter_ = Eigen::Vector3d(jx, jy, jz);
    ribs_.a_r = a_ - in_.fat_thickness - in_.wall_thickness - in_.rib_radius;
    ribs_.b_r = b_ - in_.fat_thickness - in_.wall_thickness - in_.rib_radius;
    ribs_.phi0 = 0.28;
    ribs_.phi1 = M_PI - 0.42;
    ribs_.z_top = in_.length - 0.03;
    ribs_.spacing = spacing_;
    ribs_.drop = in_.rib_drop;
    a_p_ = ribs_.a_r - in_.rib_radius - 0.004;  // pleura
    b_p_ = ribs_.b_r - in_.rib_radius - 0.004;
    vertebra_y_ = b_p_ - 0.018;
  }

  // Heart: an ellipsoid turned as real hearts lie (docs/phantom.md: the principal axes of the
  // heart masks of two real CTs), its front 8 mm behind the anterior pleura, left of the
  // midline, its apex (the LAD's end) in the 5th intercostal space at the front of the chest,
  // where a surgeon finds it (docs/phantom.md).
  void PlaceHeart() {
    const Eigen::Vector3d e_long = Eigen::Vector3d(0.677, -0.486, -0.548).normalized();
    Eigen::Vector3d e_short = Eigen::Vector3d(0.092, -0.668, 0.724);
    e_short = (e_short - e_short.dot(e_long) * e_long).normalized();
    heart_axes_ << e_long, e_short.cross(e_long), e_short;
    semi_ = Eigen::Vector3d(0.074, 0.053, 0.043) * in_.heart_scale;
    out_.truth.heart_semi_axes = semi_;
    out_.truth.heart_axes = heart_axes_;
    const double front_reach = out_.truth.HeartReach(Eigen::Vector3d(0, -1, 0));
    const double lad_apex_z = (heart_axes_ * LadUnit(0.9).cwiseProduct(semi_)).z();
    const double fifth_space_front = 0.5 * (ribs_.Z(4, ribs_.phi1) + ribs_.Z(5, ribs_.phi1));
    heart_ = Eigen::Vector3d(0.03, -b_p_ + front_reach + 0.008, fifth_space_front - lad_apex_z);
    heart_ += in_.heart_offset + heart_jitter_;
    out_.truth.heart_centre = heart_;
  }

  // The volume's grid: the body, the arms beside it and the table under it, with a margin (or
  // the field of view asked for).
  void Grid() {
    Volume& v = out_.ct;
    const double h = in_.voxel_size;
    const double hz = in_.slice_spacing > 0.0 ? in_.slice_spacing : h;
    const double margin = 0.02;
    TROCAR_THROW_UNLESS(
        in_.field_of_view == 0.0 ||
            (std::isfinite(in_.field_of_view) && in_.field_of_view >= 2 * a_ + 0.01 &&
             in_.field_of_view >= 2 * b_ + 0.01 && in_.field_of_view <= 1.0),
        "phantom: field_of_view " << in_.field_of_view << " m must hold the body (" << 2 * a_
                                  << " x " << 2 * b_ << " m) and be at most 1 m");
    // Upper arms beside the chest: soft tissue round the humerus, touching the body.
    arm_x_ = a_ + kArmR - 0.005;
    const double half_x = in_.shoulders ? arm_x_ + kArmR : a_;
    TROCAR_THROW_UNLESS(in_.field_of_view == 0.0 || in_.field_of_view >= 2 * half_x + 0.01,
                        "phantom: field_of_view " << in_.field_of_view << " m must hold the arms ("
                                                  << 2 * half_x << " m)");
    const double fov_x = in_.field_of_view > 0.0 ? in_.field_of_view : 2 * half_x + 2 * margin;
    // The table: its top's middle `table_gap` behind the back, rising 1 m's cradle to the sides.
    table_ = !std::isnan(in_.table_gap);
    table_top_ = b_ + (table_ ? in_.table_gap : 0.0);
    const double half_y = table_ ? std::max(b_, table_top_ + 2 * kTableShell + kTableCore) : b_;
    const double fov_y = in_.field_of_view > 0.0 ? in_.field_of_view : 2 * half_y + 2 * margin;
    v.size = Eigen::Vector3i(static_cast<int>(std::ceil(fov_x / h - 1e-9)),
                             static_cast<int>(std::ceil(fov_y / h - 1e-9)),
                             static_cast<int>(std::ceil(in_.length / hz)));
    v.index_to_P = Eigen::Vector3d(h, h, hz).asDiagonal();
    v.origin_P = Eigen::Vector3d(-0.5 * fov_x, -0.5 * fov_y, 0.0);
    // Bounded before anything is allocated: the finest voxels over the widest field of view
    // would need tens of GB.
    v.values.assign(static_cast<std::size_t>(CheckedVoxelCount(
                        v.size, "phantom: voxel_size " + std::to_string(h) + " m, slice spacing " +
                                    std::to_string(hz) + " m")),
                    PhantomHu::kAir);
    v.hounsfield = true;
    v.source = "phantom seed " + std::to_string(in_.seed);
  }

  void FillVoxels() {
    Volume& v = out_.ct;
    heart_sphere2_ = semi_.maxCoeff() * semi_.maxCoeff() * (1.0 + 1e-6);
    for (int k = 0; k < v.size.z(); ++k) {
      for (int j = 0; j < v.size.y(); ++j) {
        for (int i = 0; i < v.size.x(); ++i)
          v.values[v.Index(i, j, k)] = Tissue(v.PatientPoint(i, j, k));
      }
    }
  }

  // The tissue at a point of the patient frame, each structure drawn over the ones before it.
  float Tissue(const Eigen::Vector3d& p) const {
    const double x = p.x(), y = p.y(), z = p.z();
    auto inside = [&](double ea, double eb) {
      return (x * x) / (ea * ea) + (y * y) / (eb * eb) <= 1.0;
    };
    float hu = PhantomHu::kAir;
    if (inside(a_, b_)) hu = PhantomHu::kFat;
    if (inside(a_ - in_.fat_thickness, b_ - in_.fat_thickness)) hu = PhantomHu::kMuscle;
    if (in_.shoulders && std::hypot(std::abs(x) - arm_x_, y) <= kArmR) {
      const double rh = std::hypot(std::abs(x) - arm_x_, y);
      hu = rh > kHumerusR ? PhantomHu::kMuscle
                          : (rh > kHumerusR - 0.003 ? PhantomHu::kBone : PhantomHu::kMarrow);
    }
    if (table_ && std::abs(x) <= kTableHalfWidth) {
      // Over the fat, muscle and arms: the back pressed onto it is flat whatever its fat.
      // Depth below the table top's surface (positive: into the table).
      const double t = y - (table_top_ - x * x / (2.0 * kCradleRadius));
      if (t >= 0.0 && t <= 2 * kTableShell + kTableCore)
        hu = (t <= kTableShell || t >= kTableShell + kTableCore) ? PhantomHu::kCarbon
                                                                 : PhantomHu::kFoam;
    }
    if (inside(a_p_, b_p_)) {
      hu = PhantomHu::kLung;
      // Mediastinum between the lungs, in front of the spine.
      if ((x * x) / (0.05 * 0.05) + ((y - 0.01) * (y - 0.01)) / (b_p_ * b_p_) <= 1.0)
        hu = PhantomHu::kMuscle;
    }
    // Beyond the sphere round the heart's longest semi-axis the heart coordinates' norm
    // exceeds 1 (the axes are a rotation): the same answer without the rotation.
    const double r =
        (p - heart_).squaredNorm() > heart_sphere2_ ? 2.0 : out_.truth.HeartCoordinates(p).norm();
    if (r <= 1.0)
      hu = r <= 1.0 - 0.008 / semi_.minCoeff() ? PhantomHu::kBlood : PhantomHu::kMyocardium;
    hu = Spine(x, y, z, hu);
    return RibCage(x, y, z, hu);
  }

  // The spine: vertebral bodies (a cortical shell round cancellous bone; a disc between each two,
  // at the level midway between rib heads), the neural arch round the spinal canal behind them,
  // the spinous process behind the arch and the transverse processes beside it.
  float Spine(double x, double y, double z, float hu) const {
    const double canal_y = vertebra_y_ + kVertebraR + 0.008, canal_r = 0.008, arch = 0.0035;
    const double spinous_end = std::min(canal_y + 0.03, b_ - in_.fat_thickness);
    const double disc_z0 = ribs_.z_top - 0.5 * spacing_;
    const double rv = std::hypot(x, y - vertebra_y_);
    if (rv <= kVertebraR) {
      const bool disc = std::abs(std::remainder(z - disc_z0, spacing_)) < 0.002;
      hu = disc ? PhantomHu::kDisc
                : (rv > kVertebraR - 0.0025 ? PhantomHu::kBone : PhantomHu::kCancellous);
    }
    // Each vertebra's arch and processes span 70 % of its height about the rib heads' level;
    // between them the spinal canal is closed by ligament only.
    if (std::abs(std::remainder(z - ribs_.z_top, spacing_)) < 0.35 * spacing_) {
      const double rc = std::hypot(x, y - canal_y);
      if (rc >= canal_r && rc <= canal_r + arch && y > vertebra_y_ + 0.5 * kVertebraR)
        hu = PhantomHu::kBone;
      if (std::abs(x) <= 0.003 && y >= canal_y + canal_r && y <= spinous_end) hu = PhantomHu::kBone;
      if (std::abs(y - canal_y) <= 0.004 && std::abs(x) >= canal_r && std::abs(x) <= 0.03)
        hu = PhantomHu::kBone;
    }
    return hu;
  }

  // The ribs, the shoulder blades over them and the sternum between the ribs' front ends.
  float RibCage(double x, double y, double z, float hu) const {
    // Ribs: distance to the rib centreline at this voxel's angle about the body axis.
    const double ex = std::abs(x) / ribs_.a_r, ey = y / ribs_.b_r;
    const double rho = std::hypot(ex, ey);
    const double phi = std::atan2(ex, ey);
    if (phi >= ribs_.phi0 && phi <= ribs_.phi1 && rho > 0.5) {
      const double local = std::hypot(ribs_.a_r * std::sin(phi), ribs_.b_r * std::cos(phi));
      const double radial = (rho - 1.0) * local;
      for (int rib = 0; rib < in_.ribs_per_side; ++rib) {
        const double dz = z - ribs_.Z(rib, phi);
        if (radial * radial + dz * dz <= in_.rib_radius * in_.rib_radius) hu = PhantomHu::kBone;
      }
    }
    // Shoulder blades: plates in the back's muscle over ribs 2 to 8, 1 cm off the ribs.
    if (in_.shoulders && phi >= 0.25 && phi <= 0.95 && z <= ribs_.z_top - spacing_ &&
        z >= ribs_.z_top - 7.5 * spacing_) {
      const double local = std::hypot(ribs_.a_r * std::sin(phi), ribs_.b_r * std::cos(phi));
      const double radial = (rho - 1.0) * local;
      if (radial >= 0.015 && radial <= 0.0195) hu = PhantomHu::kBone;
    }
    // Sternum: a plate at the front between the rib ends.
    if (std::abs(x) <= 0.02 && std::abs(y + ribs_.b_r) <= 0.007 && z <= ribs_.z_top + 0.01 &&
        z >= ribs_.Z(in_.ribs_per_side - 1, ribs_.phi1) - 0.01) {
      hu = PhantomHu::kBone;
    }
    return hu;
  }

  // Truth: ribs and the intercostal spaces between them, on the skin.
  void RibAndSpaceTruth() {
    for (int side : {+1, -1}) {
      for (int rib = 0; rib < in_.ribs_per_side; ++rib) {
        PhantomTruth::Rib truth{side, rib, {}};
        if (in_.ribs_reach_spine) {
          // The rib's neck, from its head against the vertebral body out to where the rib bends.
          const Eigen::Vector3d head(side * (kVertebraR + 0.001), vertebra_y_ + 0.004,
                                     ribs_.Z(rib, ribs_.phi0));
          const Eigen::Vector3d bend = ribs_.Point(side, rib, ribs_.phi0);
          for (int s = 0; s < 8; ++s) truth.centreline.push_back(head + (bend - head) * (s / 8.0));
        }
        for (int s = 0; s <= 60; ++s) {
          truth.centreline.push_back(
              ribs_.Point(side, rib, ribs_.phi0 + (ribs_.phi1 - ribs_.phi0) * s / 60.0));
        }
        out_.truth.ribs.push_back(truth);
      }
    }
    for (int side : {+1, -1}) {
      for (int rib = 0; rib + 1 < in_.ribs_per_side; ++rib) {
        Curve space;
        for (int s = 0; s <= 30; ++s) {  // from the side of the chest to the front
          const double phi = 0.45 * M_PI + (ribs_.phi1 - 0.45 * M_PI) * s / 30.0;
          const double z = 0.5 * (ribs_.Z(rib, phi) + ribs_.Z(rib + 1, phi));
          space.emplace_back(side * a_ * std::sin(phi), b_ * std::cos(phi), z);
        }
        out_.truth.intercostal_spaces.push_back(space);
        out_.truth.intercostal_side.push_back(side);
      }
    }
  }

  void ArteryTruth() {
    // LAD: down the anterior interventricular groove on the sternocostal surface, from the base
    // (behind the sternum's left edge) to the apex (left, forward, low), a little toward the left
    // ventricle's side of the surface, on the epicardium.
    for (int s = 0; s <= 24; ++s) {
      const Eigen::Vector3d unit = LadUnit(-0.7 + 1.6 * s / 24.0);
      const Eigen::Vector3d surface = heart_ + heart_axes_ * unit.cwiseProduct(semi_);
      const Eigen::Vector3d normal = (heart_axes_ * unit.cwiseQuotient(semi_)).normalized();
      out_.truth.lad.push_back(surface + 0.0015 * normal);
      out_.truth.lad_normals.push_back(normal);
    }
    // LIMA: inside the anterior chest wall, 3 cm left of the midline, over the stretch a harvest
    // takes down: from the first rib's front end to the 6th intercostal space, where the artery
    // divides (docs/phantom.md); with fewer ribs, to the lowest space.
    const int lowest_space = std::min(5, in_.ribs_per_side - 2);
    const double lima_top = ribs_.Z(0, ribs_.phi1);
    const double lima_bottom =
        0.5 * (ribs_.Z(lowest_space, ribs_.phi1) + ribs_.Z(lowest_space + 1, ribs_.phi1));
    for (int s = 0; s <= 20; ++s) {
      const double z = lima_top + (lima_bottom - lima_top) * s / 20.0;
      out_.truth.lima.emplace_back(0.03, -b_p_ - 0.002, z);
    }
  }

  // Tubes that the voxel rule does not draw: the ribs' necks, the collarbones, the arteries.
  void StampTubes() {
    Volume& v = out_.ct;
    for (const auto& rib : out_.truth.ribs) {
      if (in_.ribs_reach_spine)
        StampTube(Curve(rib.centreline.begin(), rib.centreline.begin() + 9), in_.rib_radius,
                  PhantomHu::kBone, &v);
    }
    if (in_.shoulders) {
      // Collarbones: over the first ribs' front half, 16 mm outside them and 4 mm higher.
      for (int side : {+1, -1}) {
        Curve clavicle;
        for (int s = 0; s <= 20; ++s) {
          const double phi = ribs_.phi1 - 0.05 - (ribs_.phi1 - 0.05 - 1.35) * s / 20.0;
          clavicle.emplace_back(side * (ribs_.a_r + 0.016) * std::sin(phi),
                                (ribs_.b_r + 0.016) * std::cos(phi), ribs_.Z(0, phi) + 0.004);
        }
        StampTube(clavicle, 0.006, PhantomHu::kBone, &v);
      }
    }
    StampTube(out_.truth.lad, 0.0016, PhantomHu::kArtery, &v);
    StampTube(out_.truth.lima, 0.0015, PhantomHu::kArtery, &v);
  }

  static constexpr double kArmR = 0.045, kHumerusR = 0.011;
  static constexpr double kTableShell = 0.002, kTableCore = 0.030, kTableHalfWidth = 0.23,
                          kCradleRadius = 1.0;
  static constexpr double kVertebraR = 0.02;

  const PhantomParameters& in_;
  Phantom out_;
  double a_ = 0.0, b_ = 0.0, spacing_ = 0.0, a_p_ = 0.0, b_p_ = 0.0, vertebra_y_ = 0.0;
  Eigen::Vector3d heart_jitter_ = Eigen::Vector3d::Zero();
  RibLayout ribs_{};
  Eigen::Matrix3d heart_axes_ = Eigen::Matrix3d::Identity();
  Eigen::Vector3d semi_ = Eigen::Vector3d::Zero(), heart_ = Eigen::Vector3d::Zero();
  double arm_x_ = 0.0, table_top_ = 0.0, heart_sphere2_ = 0.0;
  bool table_ = false;
};

}  // namespace

Phantom GeneratePhantom(const PhantomParameters& in) {
  CheckParameters(in);
  return PhantomBuilder(in).Build();
}

namespace {

// Curves named `name` and their number, joined by `separator` ("ICS-L" "" 3: the 3rd space, below
// rib 3: the generator lays the ribs out from rib 1 down).
std::vector<Markup> CurveMarkups(const std::string& name, const std::vector<Curve>& curves,
                                 const std::vector<Eigen::Vector3d>& normals = {},
                                 const std::string& separator = "-") {
  std::vector<Markup> out;
  for (std::size_t c = 0; c < curves.size(); ++c) {
    Markup m;
    m.type = "Curve";
    m.name = curves.size() == 1 ? name : name + separator + std::to_string(c + 1);
    m.points = curves[c];
    for (std::size_t i = 0; i < curves[c].size(); ++i) {
      m.labels.push_back(name + "-" + std::to_string(c + 1) + "-" + std::to_string(i + 1));
    }
    m.normals = normals;
    out.push_back(std::move(m));
  }
  return out;
}

}  // namespace

bool PhantomCaseIsCurrent(const std::string& dir) {
  const std::string path = JoinPath(dir, "truth.json");
  if (!IsRegularFile(path)) return false;
  try {
    const nlohmann::json truth = nlohmann::json::parse(ReadTextFile(path));
    const auto it = truth.find("generator_version");
    return it != truth.end() && it->is_number_integer() &&
           it->get<int>() == kPhantomGeneratorVersion;
  } catch (const std::exception&) {
    return false;
  }
}

void WritePhantomCase(const Phantom& phantom, const std::string& dir, CtFormat format,
                      bool write_patient_yaml) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::create_directories(dir, ec);
  TROCAR_THROW_UNLESS(!ec, dir << ": cannot create the case folder: " << ec.message());
  // Everything is written into a temporary folder inside the case, then moved into place with
  // the CT last: the CT's presence means the case is whole, so a run killed half-way leaves a
  // case that the next import regenerates instead of one that fails on every import.
  // A folder left by a generation that was killed is removed by the next one (only once its
  // writer is gone: RemoveStaleTemporaries).
  const fs::path target = fs::path(dir) / ".phantom";
  RemoveStaleTemporaries(target);
  const fs::path temp = TemporaryName(target.string());
  fs::create_directories(temp / "markups", ec);
  TROCAR_THROW_UNLESS(!ec, temp.string() << ": cannot create a temporary folder: " << ec.message());
  struct Cleanup {
    fs::path path;
    ~Cleanup() {
      std::error_code ignored;
      fs::remove_all(path, ignored);
    }
  } cleanup{temp};
  const std::string tmp = temp.string();
  const std::string ct_name = format == CtFormat::kDicom ? "ct" : "ct.nrrd";
  if (format == CtFormat::kDicom) {
    DicomWriteOptions options;
    options.patient_name = "PHANTOM^SEED" + std::to_string(phantom.parameters.seed);
    options.patient_id = "phantom-seed-" + std::to_string(phantom.parameters.seed);
    options.series_description = "trocar thorax phantom";
    WriteDicomSeries(phantom.ct, JoinPath(tmp, ct_name), options);
  } else {
    WriteNrrd(phantom.ct, JoinPath(tmp, ct_name), format == CtFormat::kNrrdRas);
  }
  const PhantomTruth& t = phantom.truth;
  WriteMarkups(CurveMarkups("LAD", {t.lad}, t.lad_normals), JoinPath(tmp, "markups/LAD.mrk.json"));
  WriteMarkups(CurveMarkups("LIMA", {t.lima}), JoinPath(tmp, "markups/LIMA.mrk.json"));
  std::vector<Curve> left;
  for (std::size_t s = 0; s < t.intercostal_spaces.size(); ++s) {
    if (t.intercostal_side[s] > 0) left.push_back(t.intercostal_spaces[s]);
  }
  WriteMarkups(CurveMarkups("ICS-L", left, {}, ""), JoinPath(tmp, "markups/intercostal_left.mrk.json"));
  nlohmann::json truth;
  for (const auto& rib : t.ribs) {
    nlohmann::json points = nlohmann::json::array();
    for (const auto& p : rib.centreline) points.push_back({p.x(), p.y(), p.z()});
    truth["ribs"].push_back({{"side", rib.side > 0 ? "left" : "right"}, {"index", rib.index}, {"centreline_m", points}});
  }
  truth["heart_centre_m"] = {t.heart_centre.x(), t.heart_centre.y(), t.heart_centre.z()};
  truth["heart_semi_axes_m"] = {t.heart_semi_axes.x(), t.heart_semi_axes.y(), t.heart_semi_axes.z()};
  for (int c = 0; c < 3; ++c)
    truth["heart_axes"].push_back({t.heart_axes(0, c), t.heart_axes(1, c), t.heart_axes(2, c)});
  truth["generator_version"] = kPhantomGeneratorVersion;
  WriteFileAtomically(JoinPath(tmp, "truth.json"), truth.dump(1));
  if (write_patient_yaml) {
    const PhantomParameters& p = phantom.parameters;
    std::ostringstream yaml;
    yaml << std::setprecision(12) << "# Generated by trocar phantom (seed " << p.seed << "); the CT is in Hounsfield units.\n"
         << "# Fields: patients/README.md. `trocar import` on this folder builds the patient model.\n"
         << "name: phantom-seed-" << p.seed << "\n"
         << "ct: " << ct_name << "\n"
         << "units: hounsfield\n"
         << "pose: {left_side_up: 25 deg}\n"
         << "targets:\n"
         << "  - {name: LAD, markups: markups/LAD.mrk.json, surface: heart}\n"
         << "  - {name: LIMA, markups: markups/LIMA.mrk.json, surface: skin, facing: inward}\n"
         << "port_candidates: markups/intercostal_left.mrk.json\n"
         << "phantom: {seed: " << p.seed << ", body_width: " << p.body_width << ", body_depth: "
         << p.body_depth << ", length: " << p.length << ", ribs_per_side: " << p.ribs_per_side
         << ", rib_spacing: " << p.rib_spacing << ", heart_scale: " << p.heart_scale
         << ", voxel_size: " << p.voxel_size;
    // Non-default grid fields only; 12 digits so a regenerated CT has the very same grid.
    if (p.slice_spacing > 0.0) yaml << ", slice_spacing: " << p.slice_spacing;
    if (p.field_of_view > 0.0) yaml << ", field_of_view: " << p.field_of_view;
    // Every other field that is not its default: the record regenerates this very phantom.
    const PhantomParameters defaults;
    if (p.fat_thickness != defaults.fat_thickness) yaml << ", fat_thickness: " << p.fat_thickness;
    if (p.wall_thickness != defaults.wall_thickness)
      yaml << ", wall_thickness: " << p.wall_thickness;
    if (p.rib_radius != defaults.rib_radius) yaml << ", rib_radius: " << p.rib_radius;
    if (p.rib_drop != defaults.rib_drop) yaml << ", rib_drop: " << p.rib_drop;
    if (p.heart_offset != defaults.heart_offset)
      yaml << ", heart_offset: [" << p.heart_offset.x() << ", " << p.heart_offset.y() << ", "
           << p.heart_offset.z() << "]";
    if (p.ribs_reach_spine) yaml << ", ribs_reach_spine: true";
    if (p.shoulders) yaml << ", shoulders: true";
    if (!std::isnan(p.table_gap)) yaml << ", table_gap: " << p.table_gap;
    yaml << "}\n";
    WriteFileAtomically(JoinPath(tmp, "patient.yaml"), yaml.str());
  }
  auto move_in = [&](const std::string& name) {
    const fs::path target = fs::path(dir) / name;
    if (name == ct_name && fs::is_directory(target, ec)) fs::remove_all(target, ec);  // DICOM folder
    fs::create_directories(target.parent_path(), ec);
    fs::rename(temp / name, target, ec);
    TROCAR_THROW_UNLESS(!ec, target.string() << ": cannot move into place: " << ec.message());
  };
  for (const char* name : {"markups/LAD.mrk.json", "markups/LIMA.mrk.json",
                           "markups/intercostal_left.mrk.json", "truth.json"}) {
    move_in(name);
  }
  if (write_patient_yaml) move_in("patient.yaml");
  move_in(ct_name);
}

}  // namespace trocar::patient
