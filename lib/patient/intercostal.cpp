#include "patient/intercostal.hpp"

#include <cmath>
#include <algorithm>
#include <map>
#include <utility>

#include "common/error.hpp"

namespace trocar::patient {

std::vector<IntercostalSpace> FindIntercostalSpaces(const Volume& ct, const Segmentation& seg,
                                                    const IntercostalOptions& o) {
  TROCAR_THROW_UNLESS(o.bin > 0 && o.to_angle > o.from_angle, "intercostal spaces: bad angle range");
  // About the body's axis (Segmentation::axis_P).
  TROCAR_THROW_UNLESS(seg.body_max_P.x() > seg.body_min_P.x(), ct.source << ": empty body mask");
  const Eigen::Vector2d axis = seg.axis_P;
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
    // In each bin, the ribs there from top to bottom: each one and the next below it bound a
    // space. Pieces of one rib (not joined) and ribs that end (the first, the lowest) are taken
    // as they come at each angle; a space is the run of bins between the same two ribs.
    std::map<std::pair<int, int>, IntercostalSpace> found;
    for (int b = 0; b < bins; ++b) {
      std::vector<int> here;
      for (int r = 0; r < n; ++r) {
        if (count[r * bins + b] > 0) here.push_back(r);
      }
      std::sort(here.begin(), here.end(), [&](int a, int c) {
        return z_lo[a * bins + b] + z_hi[a * bins + b] > z_lo[c * bins + b] + z_hi[c * bins + b];
      });
      for (std::size_t t = 0; t + 1 < here.size(); ++t) {
        const int upper = here[t] * bins + b, lower = here[t + 1] * bins + b;
        const double gap = z_lo[upper] - z_hi[lower];  // between the upper rib's bottom and the lower rib's top
        if (gap < o.min_gap) continue;
        const double angle = o.from_angle + (b + 0.5) * o.bin;
        const double z = 0.5 * (z_lo[upper] + z_hi[lower]);
        const double rib_radius = 0.5 * (radius[upper] / count[upper] + radius[lower] / count[lower]);
        const Eigen::Vector2d direction(side * std::sin(angle), std::cos(angle));
        // Out along the ray to the skin: the last point inside the body.
        Eigen::Vector3d skin(axis.x() + rib_radius * direction.x(), axis.y() + rib_radius * direction.y(), z);
        if (!inside_body(skin)) continue;
        // Out to the skin within the chest wall's reach: a ray that stays in the body further
        // runs into an arm lying against the chest (no port there).
        bool out = false;
        for (double d = rib_radius; d <= rib_radius + o.max_wall_depth; d += step) {
          const Eigen::Vector3d q(axis.x() + d * direction.x(), axis.y() + d * direction.y(), z);
          if (!inside_body(q)) {
            out = true;
            break;
          }
          skin = q;
        }
        if (!out) continue;
        IntercostalSpace& space = found[{here[t], here[t + 1]}];
        space.side = side;
        space.upper_rib = here[t];
        space.lower_rib = here[t + 1];
        space.skin.push_back(skin);
        space.depth.emplace_back(axis.x() + rib_radius * direction.x(), axis.y() + rib_radius * direction.y(), z);
        space.gap.push_back(gap);
      }
    }
    std::vector<IntercostalSpace> side_spaces;
    for (auto& [key, space] : found) {
      if (static_cast<int>(space.skin.size()) >= o.min_points) side_spaces.push_back(std::move(space));
    }
    // Top to bottom by mean height.
    auto mean_z = [](const IntercostalSpace& s) {
      double z = 0.0;
      for (const auto& p : s.depth) z += p.z();
      return z / static_cast<double>(s.depth.size());
    };
    std::stable_sort(side_spaces.begin(), side_spaces.end(),
                     [&](const IntercostalSpace& a, const IntercostalSpace& c) { return mean_z(a) > mean_z(c); });
    for (auto& space : side_spaces) spaces.push_back(std::move(space));
  }
  return spaces;
}

}  // namespace trocar::patient
