#include "patient/intercostal.hpp"

#include <cmath>
#include <map>

#include "common/error.hpp"

namespace trocar::patient {

std::vector<IntercostalSpace> FindIntercostalSpaces(const Volume& ct, const Segmentation& seg,
                                                    const IntercostalOptions& o) {
  TROCAR_THROW_UNLESS(o.bin > 0 && o.to_angle > o.from_angle, "intercostal spaces: bad angle range");
  // The body axis: the centre of the body's bounding box across the slices.
  TROCAR_THROW_UNLESS(seg.body_max_P.x() > seg.body_min_P.x(), ct.source << ": empty body mask");
  const Eigen::Vector2d axis = 0.5 * (seg.body_min_P + seg.body_max_P).head<2>();
  const int bins = static_cast<int>(std::ceil((o.to_angle - o.from_angle) / o.bin));

  std::vector<IntercostalSpace> spaces;
  for (int side : {+1, -1}) {
    if ((side > 0 && !o.left) || (side < 0 && !o.right)) continue;
    const auto& ribs = side > 0 ? seg.bones.ribs_left : seg.bones.ribs_right;
    TROCAR_THROW_UNLESS(ribs.size() >= 2, ct.source << ": " << ribs.size() << " rib(s) found on the "
                                                    << (side > 0 ? "left" : "right")
                                                    << ", need two to find a space between them");
    // For each rib and angular bin: the rib's lowest and highest z, and its mean radius.
    std::map<int, int> rib_of_label;
    for (std::size_t r = 0; r < ribs.size(); ++r) rib_of_label[ribs[r].label] = static_cast<int>(r);
    const int n = static_cast<int>(ribs.size());
    std::vector<double> z_lo(n * bins, HUGE_VAL), z_hi(n * bins, -HUGE_VAL), radius(n * bins, 0.0);
    std::vector<int> count(n * bins, 0);
    for (long v = 0; v < static_cast<long>(seg.bones.labels.size()); ++v) {
      const int label = seg.bones.labels[v];
      if (label == 0) continue;
      const auto it = rib_of_label.find(label);
      if (it == rib_of_label.end()) continue;
      const int i = static_cast<int>(v % ct.size.x()), j = static_cast<int>((v / ct.size.x()) % ct.size.y());
      const int k = static_cast<int>(v / (static_cast<long>(ct.size.x()) * ct.size.y()));
      const Eigen::Vector3d p = ct.PatientPoint(i, j, k);
      const Eigen::Vector2d d = p.head<2>() - axis;
      const double angle = std::atan2(side * d.x(), d.y());  // 0 at the back, π at the front
      const int b = static_cast<int>(std::floor((angle - o.from_angle) / o.bin));
      if (angle < o.from_angle || b < 0 || b >= bins) continue;
      const int cell = it->second * bins + b;
      z_lo[cell] = std::min(z_lo[cell], p.z());
      z_hi[cell] = std::max(z_hi[cell], p.z());
      radius[cell] += d.norm();
      ++count[cell];
    }
    auto inside_body = [&](const Eigen::Vector3d& p) {
      const Eigen::Vector3d ijk = ct.IndexOf(p);
      const Eigen::Vector3i q(static_cast<int>(std::lround(ijk.x())), static_cast<int>(std::lround(ijk.y())),
                              static_cast<int>(std::lround(ijk.z())));
      if ((q.array() < 0).any() || (q.array() >= ct.size.array()).any()) return false;
      return seg.body.inside[ct.Index(q.x(), q.y(), q.z())] != 0;
    };
    const double step = 0.5 * ct.spacing().minCoeff();
    for (int r = 0; r + 1 < n; ++r) {
      IntercostalSpace space;
      space.side = side;
      space.upper_rib = r;
      for (int b = 0; b < bins; ++b) {
        const int upper = r * bins + b, lower = (r + 1) * bins + b;
        if (count[upper] == 0 || count[lower] == 0) continue;
        const double gap = z_lo[upper] - z_hi[lower];  // between the upper rib's bottom and the lower rib's top
        if (gap < o.min_gap) continue;
        const double angle = o.from_angle + (b + 0.5) * o.bin;
        const double z = 0.5 * (z_lo[upper] + z_hi[lower]);
        const double rib_radius = 0.5 * (radius[upper] / count[upper] + radius[lower] / count[lower]);
        const Eigen::Vector2d direction(side * std::sin(angle), std::cos(angle));
        // Out along the ray to the skin: the last point inside the body.
        Eigen::Vector3d skin(axis.x() + rib_radius * direction.x(), axis.y() + rib_radius * direction.y(), z);
        if (!inside_body(skin)) continue;
        for (double t = rib_radius; t < rib_radius + 0.2; t += step) {
          const Eigen::Vector3d q(axis.x() + t * direction.x(), axis.y() + t * direction.y(), z);
          if (!inside_body(q)) break;
          skin = q;
        }
        space.skin.push_back(skin);
        space.depth.emplace_back(axis.x() + rib_radius * direction.x(), axis.y() + rib_radius * direction.y(), z);
        space.gap.push_back(gap);
      }
      if (static_cast<int>(space.skin.size()) >= o.min_points) spaces.push_back(space);
    }
  }
  return spaces;
}

}  // namespace trocar::patient
