#include "patient/intercostal.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <optional>
#include <utility>

#include "common/error.hpp"
#include "patient/segmentation.hpp"

namespace trocar::patient {

namespace {

// A voxel lookup by patient point, nearest voxel; -1 outside the grid.
struct Lookup {
  const Volume& ct;
  Eigen::Matrix3d P_to_index;
  explicit Lookup(const Volume& v) : ct(v), P_to_index(v.index_to_P.inverse()) {}
  long operator()(const Eigen::Vector3d& p) const {
    const Eigen::Vector3d ijk = P_to_index * (p - ct.origin_P);
    const long i = std::lround(ijk.x()), j = std::lround(ijk.y()), k = std::lround(ijk.z());
    if (i < 0 || j < 0 || k < 0 || i >= ct.size.x() || j >= ct.size.y() || k >= ct.size.z())
      return -1;
    return ct.Index(static_cast<int>(i), static_cast<int>(j), static_cast<int>(k));
  }
};

// The skin over a space: out from `radius` along the ray from the body's axis in direction `d`
// at height z, the last point inside the body, in steps of `step`, and the radius of the first
// point outside it (infinite when the ray stays in the body further than `longest` beyond
// `radius`). None when the ray starts outside the body.
struct SkinPoint {
  Eigen::Vector3d skin;
  double exit_radius = 0.0;
};
std::optional<SkinPoint> SkinAlongRay(const Lookup& voxel, const Mask& body,
                                      const Eigen::Vector2d& axis, const Eigen::Vector2d& d,
                                      double z, double radius, double longest, double step) {
  auto inside = [&](const Eigen::Vector3d& p) {
    const long v = voxel(p);
    return v >= 0 && body.inside[v] != 0;
  };
  Eigen::Vector3d skin(axis.x() + radius * d.x(), axis.y() + radius * d.y(), z);
  if (!inside(skin)) return std::nullopt;
  for (double r = radius; r <= radius + longest; r += step) {
    const Eigen::Vector3d q(axis.x() + r * d.x(), axis.y() + r * d.y(), z);
    if (!inside(q)) return SkinPoint{skin, r};
    skin = q;
  }
  return SkinPoint{skin, HUGE_VAL};
}

// The side's bound on the wall: a ray whose skin lies further beyond the ribs runs into an arm
// against the chest. `walls`: each ray's exit beyond its radius, +inf for a ray that never left
// the body within the longest ray.
WallReach ReachOfWalls(int side, std::vector<double> walls, const IntercostalOptions& o) {
  WallReach reach;
  reach.side = side;
  reach.limit = o.max_wall_depth;
  if (walls.empty()) return reach;
  std::nth_element(walls.begin(), walls.begin() + walls.size() / 4, walls.end());
  reach.typical = walls[walls.size() / 4];
  if (std::isfinite(reach.typical))
    reach.limit = std::max(o.max_wall_depth, reach.typical + o.arm_margin);
  return reach;
}

}  // namespace

std::vector<IntercostalSpace> FindIntercostalSpaces(const Volume& ct, const Segmentation& seg,
                                                    const IntercostalOptions& o,
                                                    std::vector<WallReach>* reach) {
  TROCAR_THROW_UNLESS(o.bin > 0 && o.to_angle > o.from_angle, "intercostal spaces: bad angle range");
  // About the body's axis (Segmentation::axis_P).
  TROCAR_THROW_UNLESS(seg.body_max_P.x() > seg.body_min_P.x(), ct.source << ": empty body mask");
  const Eigen::Vector2d axis = seg.axis_P;
  const int bins = static_cast<int>(std::ceil((o.to_angle - o.from_angle) / o.bin));

  std::vector<IntercostalSpace> spaces;
  for (int side : {+1, -1}) {
    if ((side > 0 && !o.left) || (side < 0 && !o.right)) continue;
    const auto& ribs = side > 0 ? seg.bones.ribs_left : seg.bones.ribs_right;
    if (ribs.size() < 2) {
      // Say what the scan holds: a crop about the heart holds little of the rib cage.
      const double extent = ct.index_to_P.col(AxialAxis(ct)).norm() * ct.size[AxialAxis(ct)];
      const char* name = side > 0 ? "left" : "right";
      TROCAR_THROW(ct.source << ": " << ribs.size() << " rib(s) found on the " << name
                             << ", need two to find a space between them (the scan spans "
                             << std::lround(extent * 1e3)
                             << " mm head to foot; the rib cage's height is 25-30 cm): give the "
                                "ports as annotated curves (port_candidates), or a label map "
                                "with the ribs (labels), or leave this side out (intercostal: {"
                             << name << ": false})");
    }
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
    const Lookup voxel(ct);
    const double step = 0.5 * ct.spacing().minCoeff();
    // In each bin, the ribs there from top to bottom: each one and the next below it bound a
    // space. Pieces of one rib (not joined) and ribs that end (the first, the lowest) are taken
    // as they come at each angle; a space is the run of bins between the same two ribs.
    std::map<std::pair<int, int>, IntercostalSpace> found;
    // Per space, each point's ray: where it left the body and the radius it started from.
    std::map<std::pair<int, int>, std::vector<std::pair<double, double>>> rays;
    std::vector<double> walls;
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
        // Out to the skin (within the chest wall's reach, below: an arm against the chest is no
        // port site).
        const std::optional<SkinPoint> skin =
            SkinAlongRay(voxel, seg.body, axis, direction, z, rib_radius, o.longest_ray, step);
        if (!skin) continue;
        IntercostalSpace& space = found[{here[t], here[t + 1]}];
        space.side = side;
        space.upper_rib = here[t];
        space.lower_rib = here[t + 1];
        space.skin.push_back(skin->skin);
        space.depth.emplace_back(axis.x() + rib_radius * direction.x(), axis.y() + rib_radius * direction.y(), z);
        space.gap.push_back(gap);
        rays[{here[t], here[t + 1]}].emplace_back(skin->exit_radius, rib_radius);
        walls.push_back(skin->exit_radius - rib_radius);
      }
    }
    WallReach side_reach = ReachOfWalls(side, walls, o);
    std::vector<IntercostalSpace> side_spaces;
    for (auto& [key, space] : found) {
      IntercostalSpace within;
      within.side = space.side;
      within.upper_rib = space.upper_rib;
      within.lower_rib = space.lower_rib;
      const auto& ray = rays[key];
      for (std::size_t i = 0; i < space.skin.size(); ++i) {
        if (!(ray[i].first <= ray[i].second + side_reach.limit)) {
          ++side_reach.dropped;
          continue;
        }
        ++side_reach.kept;
        within.skin.push_back(space.skin[i]);
        within.depth.push_back(space.depth[i]);
        within.gap.push_back(space.gap[i]);
      }
      if (static_cast<int>(within.skin.size()) >= o.min_points)
        side_spaces.push_back(std::move(within));
    }
    if (reach != nullptr && !walls.empty()) reach->push_back(side_reach);
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

std::vector<IntercostalSpace> FindIntercostalSpacesInLayer(const Volume& ct,
                                                           const Segmentation& seg,
                                                           const IntercostalOptions& o,
                                                           LayerChart* chart,
                                                           std::vector<WallReach>* reach) {
  TROCAR_THROW_UNLESS(o.bin > 0 && o.to_angle > o.from_angle,
                      "intercostal spaces: bad angle range");
  TROCAR_THROW_UNLESS(seg.body_max_P.x() > seg.body_min_P.x(), ct.source << ": empty body mask");
  const Eigen::Vector2d axis = seg.axis_P;
  const Lookup voxel(ct);
  // Depth under the skin: the distance to the nearest voxel outside the body.
  std::vector<float> depth2;
  {
    Mask outside;
    outside.size = ct.size;
    outside.inside.resize(seg.body.inside.size());
    for (std::size_t v = 0; v < outside.inside.size(); ++v) outside.inside[v] = !seg.body.inside[v];
    depth2 = SquaredDistanceToMask(ct, outside);
  }
  const float max_depth2 = static_cast<float>(o.layer_depth * o.layer_depth);
  auto in_wall = [&](long v) { return v >= 0 && seg.body.inside[v] && depth2[v] <= max_depth2; };
  // The chart's rows: heights from the body's top down, one voxel apart along the slices' axis.
  const double dz = ct.index_to_P.col(AxialAxis(ct)).norm();
  const int rows =
      std::max(1, static_cast<int>(std::floor((seg.body_max_P.z() - seg.body_min_P.z()) / dz)) + 1);
  auto row_z = [&](int row) { return seg.body_max_P.z() - row * dz; };
  const int cols = static_cast<int>(std::ceil(M_PI / o.bin));  // 0 at the back to π at the front
  const double dr = 0.5 * ct.spacing().minCoeff();
  double max_r = 0.0;
  for (double x : {seg.body_min_P.x(), seg.body_max_P.x()}) {
    for (double y : {seg.body_min_P.y(), seg.body_max_P.y()})
      max_r = std::max(max_r, (Eigen::Vector2d(x, y) - axis).norm());
  }
  // A space lies on the rib cage, round the lungs and the heart: where the band within the
  // wall's depth of the skin reaches the body's middle (the neck's base, below the rib cage)
  // what bounds a dark run is no rib.
  const double min_cage_radius =
      o.layer_min_cage_radius * 0.5 * (seg.body_max_P.x() - seg.body_min_P.x());
  auto direction = [&](int side, int col) {
    const double angle = (col + 0.5) * o.bin;
    return Eigen::Vector2d(side * std::sin(angle), std::cos(angle));
  };
  // The floor: `layer_floor_fraction` of the way from the wall's soft tissue to the bone
  // threshold.
  double floor = o.layer_floor;
  if (floor <= 0.0) {
    std::vector<float> soft;
    for (std::size_t v = 0; v < depth2.size(); v += 7) {
      if (in_wall(static_cast<long>(v)) && ct.values[v] > seg.body_threshold &&
          ct.values[v] < seg.bone_threshold)
        soft.push_back(ct.values[v]);
    }
    TROCAR_THROW_UNLESS(!soft.empty(), ct.source
                                           << ": no soft tissue in the chest wall (body threshold "
                                           << seg.body_threshold << ", bone threshold "
                                           << seg.bone_threshold << ")");
    std::nth_element(soft.begin(), soft.begin() + soft.size() / 2, soft.end());
    const double tissue = soft[soft.size() / 2];
    floor = tissue + o.layer_floor_fraction * (seg.bone_threshold - tissue);
  }
  if (chart != nullptr) {
    *chart = LayerChart{};
    chart->floor = floor;
    chart->top_z = row_z(0);
    chart->dz = dz;
    chart->bin = o.bin;
    chart->rows = rows;
    chart->cols = cols;
    chart->outside = o.layer_outside;
  }

  std::vector<IntercostalSpace> spaces;
  for (int side : {+1, -1}) {
    if ((side > 0 && !o.left) || (side < 0 && !o.right)) continue;
    // The innermost rib-bright voxel in the wall along each ray; and, for the girdle's surface,
    // the inner end of the innermost bright run that ends in the wall and is no deeper along the
    // ray than a rib (`layer_max_rib_depth`), measured whole, inside the wall's depth too: an
    // organ under the ribs (the liver with contrast) is a long run, and a rib whose inner edge
    // lies deeper than the wall's depth (under a shoulder blade and the back's muscles) is a
    // short one.
    std::vector<double> inner(static_cast<std::size_t>(rows) * cols, NAN);
    std::vector<double> thin(inner.size(), NAN);
    // Rows are independent (each writes its own cells): split over threads.
#pragma omp parallel for schedule(dynamic, 4)
    for (int row = 0; row < rows; ++row) {
      const double z = row_z(row);
      for (int col = 0; col < cols; ++col) {
        const Eigen::Vector2d d = direction(side, col);
        double run_from = -1.0;
        bool run_in_wall = false, entered = false, thin_done = false;
        for (double r = 0.0; r <= max_r; r += dr) {
          const long v = voxel(Eigen::Vector3d(axis.x() + r * d.x(), axis.y() + r * d.y(), z));
          const bool in_body = v >= 0 && seg.body.inside[v];
          const bool bright = in_body && ct.values[v] >= floor;
          const bool wall = in_wall(v);
          if (bright && wall && std::isnan(inner[row * cols + col])) inner[row * cols + col] = r;
          if (!thin_done) {
            if (bright) {
              if (run_from < 0.0) run_from = r;
              run_in_wall = wall;
            } else if (run_from >= 0.0) {
              if (run_in_wall && r - run_from <= o.layer_max_rib_depth) {
                thin[row * cols + col] = run_from;
                thin_done = true;
              }
              run_from = -1.0;
            }
            // Out through the skin: an arm beyond it is not the chest wall's.
            thin_done = thin_done || (entered && !in_body);
            entered = entered || in_body;
          }
          if (thin_done && !std::isnan(inner[row * cols + col])) break;
        }
      }
    }
    // The layer's surface: the lower quartile of the innermost radii around (the ribs are the
    // innermost layer; between them the ray meets what lies outside, a shoulder blade or muscle).
    const int wa = std::max(1, static_cast<int>(std::lround(o.layer_smooth_angle / o.bin)));
    const int wz = std::max(1, static_cast<int>(std::lround(o.layer_smooth_height / dz)));
    auto lower_quartile = [&](const std::vector<double>& radii) {
      std::vector<double> smooth(radii.size(), NAN);
      std::vector<double> near;
      for (int row = 0; row < rows; ++row) {
        for (int col = 0; col < cols; ++col) {
          near.clear();
          for (int r2 = std::max(0, row - wz); r2 <= std::min(rows - 1, row + wz); ++r2) {
            for (int c2 = std::max(0, col - wa); c2 <= std::min(cols - 1, col + wa); ++c2) {
              if (!std::isnan(radii[r2 * cols + c2])) near.push_back(radii[r2 * cols + c2]);
            }
          }
          if (near.size() < 3) continue;
          std::nth_element(near.begin(), near.begin() + near.size() / 4, near.end());
          smooth[row * cols + col] = near[near.size() / 4];
        }
      }
      return smooth;
    };
    const std::vector<double> surface = lower_quartile(inner);
    // Rib or not, per chart cell: any voxel of the band reaching the floor.
    std::vector<std::uint8_t> rib(inner.size(), 0);
    for (int row = 0; row < rows; ++row) {
      const double z = row_z(row);
      for (int col = 0; col < cols; ++col) {
        const double s = surface[row * cols + col];
        if (std::isnan(s)) continue;
        const Eigen::Vector2d d = direction(side, col);
        for (double r = std::max(0.0, s - o.layer_inside); r <= s + o.layer_outside; r += dr) {
          const long v = voxel(Eigen::Vector3d(axis.x() + r * d.x(), axis.y() + r * d.y(), z));
          if (in_wall(v) && ct.values[v] >= floor) {
            rib[row * cols + col] = 1;
            break;
          }
        }
      }
    }
    if (chart != nullptr) {
      (side > 0 ? chart->rib_left : chart->rib_right) = rib;
      (side > 0 ? chart->surface_left : chart->surface_right) = lower_quartile(thin);
    }
    // Per angle, the dark runs between two rib runs; linked across neighbouring angles (their
    // rows overlapping) into curves.
    struct Run {
      int top, bottom;  // rows, inclusive
    };
    struct Chain {
      IntercostalSpace space;
      Run last{0, 0};
      int last_col = 0;
    };
    std::vector<Chain> chains;
    const int col_from = static_cast<int>(std::ceil(o.from_angle / o.bin - 0.5));
    const int col_to = std::min(cols - 1, static_cast<int>(std::floor(o.to_angle / o.bin - 0.5)));
    // First each column's spaces and their rays out to the skin (the side's walls bound what is
    // an arm), then the linking.
    struct Candidate {
      Run run;
      double gap, z, radius;
      SkinPoint skin;
    };
    std::vector<std::vector<Candidate>> candidates(cols);
    std::vector<double> walls;
    for (int col = std::max(0, col_from); col <= col_to; ++col) {
      // A space lies between two ribs: rib runs no taller than `layer_max_rib`, a dark run no
      // taller than `layer_max_gap` (taller bright runs are organs in the layer's band, below the
      // rib cage or against it; taller dark ones are no space between neighbouring ribs).
      std::vector<Run> runs;
      int row = 0;
      while (row < rows && !rib[row * cols + col]) ++row;  // above the first rib
      while (row < rows) {
        const int rib_top = row;
        while (row < rows && rib[row * cols + col]) ++row;
        const bool slender = (row - rib_top) * dz <= o.layer_max_rib;
        const int top = row;
        while (row < rows && !rib[row * cols + col]) ++row;
        int rib_bottom = row;
        while (rib_bottom < rows && rib[rib_bottom * cols + col]) ++rib_bottom;
        const bool below = row < rows && (rib_bottom - row) * dz <= o.layer_max_rib;
        if (slender && below && row > top && (row - top) * dz <= o.layer_max_gap)
          runs.push_back({top, row - 1});
      }
      const Eigen::Vector2d d = direction(side, col);
      for (const Run& run : runs) {
        const double gap = (run.bottom - run.top + 1) * dz;
        if (gap < o.min_gap) continue;
        const int mid = (run.top + run.bottom) / 2;
        const double z = 0.5 * (row_z(run.top) + row_z(run.bottom));
        const double radius = surface[mid * cols + col];
        if (std::isnan(radius) || radius < min_cage_radius) continue;
        const std::optional<SkinPoint> skin =
            SkinAlongRay(voxel, seg.body, axis, d, z, radius, o.longest_ray, dr);
        if (!skin) continue;
        candidates[col].push_back({run, gap, z, radius, *skin});
        walls.push_back(skin->exit_radius - radius);
      }
    }
    WallReach side_reach = ReachOfWalls(side, walls, o);
    for (int col = std::max(0, col_from); col <= col_to; ++col) {
      const Eigen::Vector2d d = direction(side, col);
      std::vector<std::uint8_t> taken(chains.size(), 0);
      for (const Candidate& candidate : candidates[col]) {
        const Run& run = candidate.run;
        const double gap = candidate.gap, z = candidate.z, radius = candidate.radius;
        // Within the chest wall's reach (an arm against the chest: no port).
        if (!(candidate.skin.exit_radius <= radius + side_reach.limit)) {
          ++side_reach.dropped;
          continue;
        }
        ++side_reach.kept;
        const Eigen::Vector3d skin = candidate.skin.skin;
        // The chain this run continues: the one ending at the last angle or the one before, whose
        // rows overlap most.
        int best = -1, best_overlap = 0;
        for (std::size_t c = 0; c < chains.size(); ++c) {
          if (taken[c] || col - chains[c].last_col > 2) continue;
          const int overlap = std::min(run.bottom, chains[c].last.bottom) -
                              std::max(run.top, chains[c].last.top) + 1;
          if (overlap > best_overlap) {
            best_overlap = overlap;
            best = static_cast<int>(c);
          }
        }
        if (best < 0) {
          chains.emplace_back();
          chains.back().space.side = side;
          chains.back().space.upper_rib = chains.back().space.lower_rib = -1;
          taken.push_back(0);
          best = static_cast<int>(chains.size()) - 1;
        }
        Chain& chain = chains[best];
        taken[best] = 1;
        chain.last = run;
        chain.last_col = col;
        chain.space.skin.push_back(skin);
        chain.space.depth.emplace_back(axis.x() + radius * d.x(), axis.y() + radius * d.y(), z);
        chain.space.gap.push_back(gap);
      }
    }
    if (reach != nullptr && !walls.empty()) reach->push_back(side_reach);
    std::vector<IntercostalSpace> side_spaces;
    for (Chain& chain : chains) {
      if (static_cast<int>(chain.space.skin.size()) >= o.min_points)
        side_spaces.push_back(std::move(chain.space));
    }
    auto mean_z = [](const IntercostalSpace& s) {
      double z = 0.0;
      for (const auto& p : s.depth) z += p.z();
      return z / static_cast<double>(s.depth.size());
    };
    std::stable_sort(side_spaces.begin(), side_spaces.end(),
                     [&](const IntercostalSpace& a, const IntercostalSpace& c) {
                       return mean_z(a) > mean_z(c);
                     });
    for (auto& space : side_spaces) spaces.push_back(std::move(space));
  }
  return spaces;
}

}  // namespace trocar::patient
