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

// Top to bottom by mean height, each side's spaces in turn.
void AppendTopToBottom(std::vector<IntercostalSpace> side_spaces,
                       std::vector<IntercostalSpace>* spaces) {
  auto mean_z = [](const IntercostalSpace& s) {
    double z = 0.0;
    for (const auto& p : s.depth) z += p.z();
    return z / static_cast<double>(s.depth.size());
  };
  std::stable_sort(
      side_spaces.begin(), side_spaces.end(),
      [&](const IntercostalSpace& a, const IntercostalSpace& c) { return mean_z(a) > mean_z(c); });
  for (auto& space : side_spaces) spaces->push_back(std::move(space));
}

}  // namespace

std::vector<IntercostalSpace> FindIntercostalSpaces(const Volume& ct, const Segmentation& seg,
                                                    const IntercostalOptions& o,
                                                    std::vector<WallReach>* reach) {
  TROCAR_THROW_UNLESS(o.bin > 0 && o.to_angle > o.from_angle,
                      "intercostal spaces: bad angle range");
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
      const int i = static_cast<int>(v % ct.size.x()),
                j = static_cast<int>((v / ct.size.x()) % ct.size.y());
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
        const double gap =
            z_lo[upper] - z_hi[lower];  // between the upper rib's bottom and the lower rib's top
        if (gap < o.min_gap) continue;
        const double angle = o.from_angle + (b + 0.5) * o.bin;
        const double z = 0.5 * (z_lo[upper] + z_hi[lower]);
        const double rib_radius =
            0.5 * (radius[upper] / count[upper] + radius[lower] / count[lower]);
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
        space.depth.emplace_back(axis.x() + rib_radius * direction.x(),
                                 axis.y() + rib_radius * direction.y(), z);
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
    AppendTopToBottom(std::move(side_spaces), &spaces);
  }
  return spaces;
}

namespace {

// FindIntercostalSpacesInLayer's stages: the chart's frame (rows of heights from the body's top
// down, columns of angles round the body's axis) and the wall's depth are set up once; then per
// side the rays' radii, the layer's surface, the rib cells, each column's dark runs between ribs,
// and their linking across columns into spaces.
class LayerSearch {
 public:
  LayerSearch(const Volume& ct, const Segmentation& seg, const IntercostalOptions& o)
      : ct_(ct), seg_(seg), o_(o), axis_(seg.axis_P), voxel_(ct) {
    // Depth under the skin: the distance to the nearest voxel outside the body.
    Mask outside;
    outside.size = ct.size;
    outside.inside.resize(seg.body.inside.size());
    for (std::size_t v = 0; v < outside.inside.size(); ++v) outside.inside[v] = !seg.body.inside[v];
    depth2_ = SquaredDistanceToMask(ct, outside);
    max_depth2_ = static_cast<float>(o.layer_depth * o.layer_depth);
    dz_ = ct.index_to_P.col(AxialAxis(ct)).norm();
    rows_ = std::max(
        1, static_cast<int>(std::floor((seg.body_max_P.z() - seg.body_min_P.z()) / dz_)) + 1);
    cols_ = static_cast<int>(std::ceil(M_PI / o.bin));  // 0 at the back to π at the front
    dr_ = 0.5 * ct.spacing().minCoeff();
    for (double x : {seg.body_min_P.x(), seg.body_max_P.x()}) {
      for (double y : {seg.body_min_P.y(), seg.body_max_P.y()})
        max_r_ = std::max(max_r_, (Eigen::Vector2d(x, y) - axis_).norm());
    }
    // A space lies on the rib cage, round the lungs and the heart: where the band within the
    // wall's depth of the skin reaches the body's middle (the neck's base, below the rib cage)
    // what bounds a dark run is no rib.
    min_cage_radius_ = o.layer_min_cage_radius * 0.5 * (seg.body_max_P.x() - seg.body_min_P.x());
    floor_ = Floor();
  }

  void StartChart(LayerChart* chart) const {
    *chart = LayerChart{};
    chart->floor = floor_;
    chart->top_z = RowZ(0);
    chart->dz = dz_;
    chart->bin = o_.bin;
    chart->rows = rows_;
    chart->cols = cols_;
    chart->outside = o_.layer_outside;
  }

  /// One side's spaces (+1 left, -1 right), unsorted; its wall reach appended to `reach`.
  std::vector<IntercostalSpace> Side(int side, LayerChart* chart,
                                     std::vector<WallReach>* reach) const {
    std::vector<double> inner, thin;
    RayRadii(side, &inner, &thin);
    // The layer's surface: the lower quartile of the innermost radii around (the ribs are the
    // innermost layer; between them the ray meets what lies outside, a shoulder blade or muscle).
    const std::vector<double> surface = LowerQuartile(inner);
    const std::vector<std::uint8_t> rib = RibCells(side, surface);
    if (chart != nullptr) {
      (side > 0 ? chart->rib_left : chart->rib_right) = rib;
      (side > 0 ? chart->surface_left : chart->surface_right) = LowerQuartile(thin);
    }
    std::vector<double> walls;
    const std::vector<std::vector<Candidate>> candidates =
        ColumnCandidates(side, rib, surface, &walls);
    WallReach side_reach = ReachOfWalls(side, walls, o_);
    std::vector<IntercostalSpace> side_spaces = Link(side, candidates, &side_reach);
    if (reach != nullptr && !walls.empty()) reach->push_back(side_reach);
    return side_spaces;
  }

 private:
  struct Run {
    int top, bottom;  // rows, inclusive
  };
  struct Candidate {
    Run run;
    double gap, z, radius;
    SkinPoint skin;
  };

  double RowZ(int row) const { return seg_.body_max_P.z() - row * dz_; }
  Eigen::Vector2d Direction(int side, int col) const {
    const double angle = (col + 0.5) * o_.bin;
    return Eigen::Vector2d(side * std::sin(angle), std::cos(angle));
  }
  bool InWall(long v) const { return v >= 0 && seg_.body.inside[v] && depth2_[v] <= max_depth2_; }
  int ColFrom() const {
    return std::max(0, static_cast<int>(std::ceil(o_.from_angle / o_.bin - 0.5)));
  }
  int ColTo() const {
    return std::min(cols_ - 1, static_cast<int>(std::floor(o_.to_angle / o_.bin - 0.5)));
  }

  // The floor: `layer_floor_fraction` of the way from the wall's soft tissue to the bone
  // threshold.
  double Floor() const {
    if (o_.layer_floor > 0.0) return o_.layer_floor;
    std::vector<float> soft;
    for (std::size_t v = 0; v < depth2_.size(); v += 7) {
      if (InWall(static_cast<long>(v)) && ct_.values[v] > seg_.body_threshold &&
          ct_.values[v] < seg_.bone_threshold)
        soft.push_back(ct_.values[v]);
    }
    TROCAR_THROW_UNLESS(!soft.empty(), ct_.source
                                           << ": no soft tissue in the chest wall (body threshold "
                                           << seg_.body_threshold << ", bone threshold "
                                           << seg_.bone_threshold << ")");
    std::nth_element(soft.begin(), soft.begin() + soft.size() / 2, soft.end());
    const double tissue = soft[soft.size() / 2];
    return tissue + o_.layer_floor_fraction * (seg_.bone_threshold - tissue);
  }

  // The innermost rib-bright voxel in the wall along each ray; and, for the girdle's surface,
  // the inner end of the innermost bright run that ends in the wall and is no deeper along the
  // ray than a rib (`layer_max_rib_depth`), measured whole, inside the wall's depth too: an
  // organ under the ribs (the liver with contrast) is a long run, and a rib whose inner edge
  // lies deeper than the wall's depth (under a shoulder blade and the back's muscles) is a
  // short one.
  void RayRadii(int side, std::vector<double>* inner_out, std::vector<double>* thin_out) const {
    const int rows = rows_, cols = cols_;
    std::vector<double> inner(static_cast<std::size_t>(rows) * cols, NAN);
    std::vector<double> thin(inner.size(), NAN);
    // Rows are independent (each writes its own cells): split over threads.
#pragma omp parallel for schedule(dynamic, 4)
    for (int row = 0; row < rows; ++row) {
      const double z = RowZ(row);
      for (int col = 0; col < cols; ++col) {
        const Eigen::Vector2d d = Direction(side, col);
        double run_from = -1.0;
        bool run_in_wall = false, entered = false, thin_done = false;
        for (double r = 0.0; r <= max_r_; r += dr_) {
          const long v = voxel_(Eigen::Vector3d(axis_.x() + r * d.x(), axis_.y() + r * d.y(), z));
          const bool in_body = v >= 0 && seg_.body.inside[v];
          const bool bright = in_body && ct_.values[v] >= floor_;
          const bool wall = InWall(v);
          if (bright && wall && std::isnan(inner[row * cols + col])) inner[row * cols + col] = r;
          if (!thin_done) {
            if (bright) {
              if (run_from < 0.0) run_from = r;
              run_in_wall = wall;
            } else if (run_from >= 0.0) {
              if (run_in_wall && r - run_from <= o_.layer_max_rib_depth) {
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
    *inner_out = std::move(inner);
    *thin_out = std::move(thin);
  }

  // Each cell's lower quartile of the radii within the smoothing window around it.
  std::vector<double> LowerQuartile(const std::vector<double>& radii) const {
    const int wa = std::max(1, static_cast<int>(std::lround(o_.layer_smooth_angle / o_.bin)));
    const int wz = std::max(1, static_cast<int>(std::lround(o_.layer_smooth_height / dz_)));
    const int rows = rows_, cols = cols_;
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
  }

  // Rib or not, per chart cell: any voxel of the band reaching the floor.
  std::vector<std::uint8_t> RibCells(int side, const std::vector<double>& surface) const {
    const int cols = cols_;
    std::vector<std::uint8_t> rib(surface.size(), 0);
    for (int row = 0; row < rows_; ++row) {
      const double z = RowZ(row);
      for (int col = 0; col < cols; ++col) {
        const double s = surface[row * cols + col];
        if (std::isnan(s)) continue;
        const Eigen::Vector2d d = Direction(side, col);
        for (double r = std::max(0.0, s - o_.layer_inside); r <= s + o_.layer_outside; r += dr_) {
          const long v = voxel_(Eigen::Vector3d(axis_.x() + r * d.x(), axis_.y() + r * d.y(), z));
          if (InWall(v) && ct_.values[v] >= floor_) {
            rib[row * cols + col] = 1;
            break;
          }
        }
      }
    }
    return rib;
  }

  // Per angle, the dark runs between two rib runs, and their rays out to the skin (the side's
  // walls, appended to `walls`, bound what is an arm).
  std::vector<std::vector<Candidate>> ColumnCandidates(int side,
                                                       const std::vector<std::uint8_t>& rib,
                                                       const std::vector<double>& surface,
                                                       std::vector<double>* walls) const {
    const int rows = rows_, cols = cols_;
    std::vector<std::vector<Candidate>> candidates(cols);
    for (int col = ColFrom(); col <= ColTo(); ++col) {
      // A space lies between two ribs: rib runs no taller than `layer_max_rib`, a dark run no
      // taller than `layer_max_gap` (taller bright runs are organs in the layer's band, below the
      // rib cage or against it; taller dark ones are no space between neighbouring ribs).
      std::vector<Run> runs;
      int row = 0;
      while (row < rows && !rib[row * cols + col]) ++row;  // above the first rib
      while (row < rows) {
        const int rib_top = row;
        while (row < rows && rib[row * cols + col]) ++row;
        const bool slender = (row - rib_top) * dz_ <= o_.layer_max_rib;
        const int top = row;
        while (row < rows && !rib[row * cols + col]) ++row;
        int rib_bottom = row;
        while (rib_bottom < rows && rib[rib_bottom * cols + col]) ++rib_bottom;
        const bool below = row < rows && (rib_bottom - row) * dz_ <= o_.layer_max_rib;
        if (slender && below && row > top && (row - top) * dz_ <= o_.layer_max_gap)
          runs.push_back({top, row - 1});
      }
      const Eigen::Vector2d d = Direction(side, col);
      for (const Run& run : runs) {
        const double gap = (run.bottom - run.top + 1) * dz_;
        if (gap < o_.min_gap) continue;
        const int mid = (run.top + run.bottom) / 2;
        const double z = 0.5 * (RowZ(run.top) + RowZ(run.bottom));
        const double radius = surface[mid * cols + col];
        if (std::isnan(radius) || radius < min_cage_radius_) continue;
        const std::optional<SkinPoint> skin =
            SkinAlongRay(voxel_, seg_.body, axis_, d, z, radius, o_.longest_ray, dr_);
        if (!skin) continue;
        candidates[col].push_back({run, gap, z, radius, *skin});
        walls->push_back(skin->exit_radius - radius);
      }
    }
    return candidates;
  }

  // The dark runs linked across neighbouring angles (their rows overlapping) into curves; those
  // beyond the wall's reach (an arm against the chest: no port) are counted in `side_reach`.
  std::vector<IntercostalSpace> Link(int side,
                                     const std::vector<std::vector<Candidate>>& candidates,
                                     WallReach* side_reach) const {
    struct Chain {
      IntercostalSpace space;
      Run last{0, 0};
      int last_col = 0;
    };
    std::vector<Chain> chains;
    for (int col = ColFrom(); col <= ColTo(); ++col) {
      const Eigen::Vector2d d = Direction(side, col);
      std::vector<std::uint8_t> taken(chains.size(), 0);
      for (const Candidate& candidate : candidates[col]) {
        const Run& run = candidate.run;
        const double gap = candidate.gap, z = candidate.z, radius = candidate.radius;
        if (!(candidate.skin.exit_radius <= radius + side_reach->limit)) {
          ++side_reach->dropped;
          continue;
        }
        ++side_reach->kept;
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
        chain.space.depth.emplace_back(axis_.x() + radius * d.x(), axis_.y() + radius * d.y(), z);
        chain.space.gap.push_back(gap);
      }
    }
    std::vector<IntercostalSpace> side_spaces;
    for (Chain& chain : chains) {
      if (static_cast<int>(chain.space.skin.size()) >= o_.min_points)
        side_spaces.push_back(std::move(chain.space));
    }
    return side_spaces;
  }

  const Volume& ct_;
  const Segmentation& seg_;
  const IntercostalOptions& o_;
  const Eigen::Vector2d axis_;
  const Lookup voxel_;
  std::vector<float> depth2_;
  float max_depth2_ = 0.0F;
  double dz_ = 0.0, dr_ = 0.0, max_r_ = 0.0, min_cage_radius_ = 0.0, floor_ = 0.0;
  int rows_ = 0, cols_ = 0;
};

}  // namespace

std::vector<IntercostalSpace> FindIntercostalSpacesInLayer(const Volume& ct,
                                                           const Segmentation& seg,
                                                           const IntercostalOptions& o,
                                                           LayerChart* chart,
                                                           std::vector<WallReach>* reach) {
  TROCAR_THROW_UNLESS(o.bin > 0 && o.to_angle > o.from_angle,
                      "intercostal spaces: bad angle range");
  TROCAR_THROW_UNLESS(seg.body_max_P.x() > seg.body_min_P.x(), ct.source << ": empty body mask");
  const LayerSearch search(ct, seg, o);
  if (chart != nullptr) search.StartChart(chart);
  std::vector<IntercostalSpace> spaces;
  for (int side : {+1, -1}) {
    if ((side > 0 && !o.left) || (side < 0 && !o.right)) continue;
    AppendTopToBottom(search.Side(side, chart, reach), &spaces);
  }
  return spaces;
}

}  // namespace trocar::patient
