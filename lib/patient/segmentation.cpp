#include "patient/segmentation.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <iomanip>
#include <limits>
#include <sstream>

#include "common/error.hpp"
#include "common/limits.hpp"

namespace trocar::patient {

long Mask::count() const {
  long n = 0;
  for (std::uint8_t v : inside) n += v != 0;
  return n;
}

int AxialAxis(const Volume& v) {
  int best = 2;
  double best_z = -1.0;
  for (int a = 0; a < 3; ++a) {
    const double z = std::abs(v.index_to_P.col(a).normalized().z());
    if (z > best_z) {
      best_z = z;
      best = a;
    }
  }
  return best;
}

Eigen::Vector2d InPlaneSpacing(const Volume& v) {
  const int axis = AxialAxis(v);
  const Eigen::Vector3d h = v.spacing();
  return {h[(axis + 1) % 3], h[(axis + 2) % 3]};
}

namespace {

Mask Threshold(const Volume& v, double threshold) {
  Mask m;
  m.size = v.size;
  m.inside.resize(v.values.size());
  for (std::size_t i = 0; i < v.values.size(); ++i) m.inside[i] = v.values[i] > threshold;
  return m;
}

// Voxel index of in-slice coordinates (a along axis u, b along axis w) on axial slice s.
struct AxialSlice {
  const Volume& v;
  int axis, u, w, s;
  long operator()(int a, int b) const {
    Eigen::Vector3i ijk;
    ijk[axis] = s;
    ijk[u] = a;
    ijk[w] = b;
    return v.Index(ijk.x(), ijk.y(), ijk.z());
  }
};

// Fills, slice by slice across the axial axis, every region the outside cannot reach.
void FillHolesPerSlice(const Volume& v, Mask* mask) {
  const int axis = AxialAxis(v);
  const int u = axis == 0 ? 1 : 0, w = axis == 2 ? 1 : 2;
  const int nu = v.size[u], nw = v.size[w];
  std::vector<std::uint8_t> outside;
  std::vector<std::pair<int, int>> stack;
  for (int s = 0; s < v.size[axis]; ++s) {
    const AxialSlice at{v, axis, u, w, s};
    outside.assign(static_cast<std::size_t>(nu) * nw, 0);
    stack.clear();
    auto seed = [&](int a, int b) {
      if (!mask->inside[at(a, b)] && !outside[a + static_cast<std::size_t>(nu) * b]) {
        outside[a + static_cast<std::size_t>(nu) * b] = 1;
        stack.emplace_back(a, b);
      }
    };
    for (int a = 0; a < nu; ++a) {
      seed(a, 0);
      seed(a, nw - 1);
    }
    for (int b = 0; b < nw; ++b) {
      seed(0, b);
      seed(nu - 1, b);
    }
    while (!stack.empty()) {
      const auto [a, b] = stack.back();
      stack.pop_back();
      if (a > 0) seed(a - 1, b);
      if (a + 1 < nu) seed(a + 1, b);
      if (b > 0) seed(a, b - 1);
      if (b + 1 < nw) seed(a, b + 1);
    }
    for (int b = 0; b < nw; ++b) {
      for (int a = 0; a < nu; ++a) {
        if (!outside[a + static_cast<std::size_t>(nu) * b]) mask->inside[at(a, b)] = 1;
      }
    }
  }
}

// Fills each axial slice's convex hull of the mask (for windowed volumes whose body outline is
// broken where fat was clipped to the value of air; axial body sections are nearly convex).
void FillConvexPerSlice(const Volume& v, Mask* mask) {
  const int axis = AxialAxis(v);
  const int u = axis == 0 ? 1 : 0, w = axis == 2 ? 1 : 2;
  std::vector<Eigen::Vector2d> points, hull;
  for (int s = 0; s < v.size[axis]; ++s) {
    const AxialSlice at{v, axis, u, w, s};
    points.clear();
    for (int b = 0; b < v.size[w]; ++b) {
      int first = -1, last = -1;
      for (int a = 0; a < v.size[u]; ++a) {
        if (mask->inside[at(a, b)]) {
          if (first < 0) first = a;
          last = a;
        }
      }
      if (first >= 0) {
        points.emplace_back(first, b);
        points.emplace_back(last, b);
      }
    }
    if (points.size() < 6) continue;
    // Andrew's monotone chain (points already sorted by b, then a within a row pair).
    std::sort(points.begin(), points.end(), [](const auto& p, const auto& q) {
      return p.x() < q.x() || (p.x() == q.x() && p.y() < q.y());
    });
    auto cross = [](const Eigen::Vector2d& o, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
      return (a - o).x() * (b - o).y() - (a - o).y() * (b - o).x();
    };
    hull.assign(2 * points.size(), Eigen::Vector2d::Zero());
    std::size_t k = 0;
    for (std::size_t i = 0; i < points.size(); ++i) {
      while (k >= 2 && cross(hull[k - 2], hull[k - 1], points[i]) <= 0) --k;
      hull[k++] = points[i];
    }
    for (std::size_t i = points.size() - 1, t = k + 1; i-- > 0;) {
      while (k >= t && cross(hull[k - 2], hull[k - 1], points[i]) <= 0) --k;
      hull[k++] = points[i];
    }
    hull.resize(k - 1);
    if (hull.size() < 3) continue;
    // Row by row: a convex polygon meets a row in one interval, from the edges crossing it (the
    // hull's vertices are whole voxel indices; points on its boundary are inside).
    for (int b = 0; b < v.size[w]; ++b) {
      double lo = HUGE_VAL, hi = -HUGE_VAL;
      for (std::size_t e = 0; e < hull.size(); ++e) {
        const Eigen::Vector2d& p = hull[e];
        const Eigen::Vector2d& q = hull[(e + 1) % hull.size()];
        if (b < std::min(p.y(), q.y()) || b > std::max(p.y(), q.y())) continue;
        if (p.y() == q.y()) {
          lo = std::min({lo, p.x(), q.x()});
          hi = std::max({hi, p.x(), q.x()});
          continue;
        }
        const double x = p.x() + (q.x() - p.x()) * (b - p.y()) / (q.y() - p.y());
        lo = std::min(lo, x);
        hi = std::max(hi, x);
      }
      if (lo > hi) continue;
      const int from = std::max(0, static_cast<int>(std::ceil(lo - 1e-9)));
      const int to = std::min(v.size[u] - 1, static_cast<int>(std::floor(hi + 1e-9)));
      for (int a = from; a <= to; ++a) mask->inside[at(a, b)] = 1;
    }
  }
}

}  // namespace

std::vector<Component> ConnectedComponents(const Volume& grid, const Mask& mask,
                                           std::vector<int>* labels,
                                           const std::vector<std::uint8_t>* region) {
  TROCAR_THROW_UNLESS(mask.size == grid.size, "connected components: mask and grid sizes differ");
  TROCAR_THROW_UNLESS(region == nullptr || region->size() == mask.inside.size(),
                      "connected components: region and mask sizes differ");
  const int nx = grid.size.x(), ny = grid.size.y(), nz = grid.size.z();
  // Runs of the mask along x (split where the region changes), row by row in raster order, joined
  // by union-find with the runs they touch in the four rows before them that are 26-neighbours:
  // (j-1, k), (j-1, k-1), (j, k-1), (j+1, k-1). Work per run, not per voxel and neighbour.
  struct Run {
    int from, to;  // x, inclusive
    std::uint8_t region;
  };
  std::vector<Run> runs;
  const long rows = static_cast<long>(ny) * nz;
  std::vector<int> row_begin(rows + 1, 0);
  std::vector<int> parent;
  auto find = [&](int r) {
    while (parent[r] != r) {
      parent[r] = parent[parent[r]];
      r = parent[r];
    }
    return r;
  };
  auto join = [&](int a, int b) {
    a = find(a);
    b = find(b);
    if (a == b) return;
    if (a < b) std::swap(a, b);
    parent[a] = b;  // the earlier run is the root: roots come in raster order
  };
  for (long row = 0; row < rows; ++row) {
    TROCAR_THROW_UNLESS(runs.size() < static_cast<std::size_t>(std::numeric_limits<int>::max()),
                        "connected components: too many runs");
    row_begin[row] = static_cast<int>(runs.size());
    const long base = row * nx;
    for (int i = 0; i < nx;) {
      if (!mask.inside[base + i]) {
        ++i;
        continue;
      }
      const std::uint8_t value = region != nullptr ? (*region)[base + i] : 0;
      int end = i + 1;
      while (end < nx && mask.inside[base + end] &&
             (region == nullptr || (*region)[base + end] == value))
        ++end;
      runs.push_back({i, end - 1, value});
      parent.push_back(static_cast<int>(runs.size()) - 1);
      i = end;
    }
    const int first = row_begin[row], last = static_cast<int>(runs.size());
    if (first == last) continue;
    const int j = static_cast<int>(row % ny), k = static_cast<int>(row / ny);
    long before[4];
    int count = 0;
    if (j > 0) before[count++] = row - 1;
    if (k > 0) {
      if (j > 0) before[count++] = row - ny - 1;
      before[count++] = row - ny;
      if (j + 1 < ny) before[count++] = row - ny + 1;
    }
    for (int b = 0; b < count; ++b) {
      // Both rows' runs are sorted by x: walk them together. Runs split by a region change touch
      // end to end, so each run is matched against every run of the other row within its
      // reach (x one beyond each end), not only the next one.
      int p = row_begin[before[b]];
      const int p_end = row_begin[before[b] + 1];
      for (int r = first; r < last; ++r) {
        while (p < p_end && runs[p].to < runs[r].from - 1) ++p;
        for (int q = p; q < p_end && runs[q].from <= runs[r].to + 1; ++q) {
          if (runs[q].region == runs[r].region) join(q, r);
        }
      }
    }
  }
  row_begin[rows] = static_cast<int>(runs.size());
  // Components numbered by their first voxel in raster order, then sorted largest first.
  std::vector<int> id(runs.size(), -1);
  std::vector<Eigen::Vector3d> sum;
  std::vector<Eigen::Vector3i> lo, hi;
  std::vector<long> voxels;
  for (long row = 0; row < rows; ++row) {
    const int j = static_cast<int>(row % ny), k = static_cast<int>(row / ny);
    for (int r = row_begin[row]; r < row_begin[row + 1]; ++r) {
      const int root = find(r);
      if (id[root] < 0) {
        id[root] = static_cast<int>(voxels.size());
        sum.emplace_back(Eigen::Vector3d::Zero());
        lo.emplace_back(nx, ny, nz);
        hi.emplace_back(-1, -1, -1);
        voxels.push_back(0);
      }
      const int c = id[root];
      id[r] = c;
      const long n = runs[r].to - runs[r].from + 1;
      voxels[c] += n;
      // Integers summed in doubles: exact (far below 2^53), as a voxel-by-voxel sum is.
      sum[c] += Eigen::Vector3d(0.5 * static_cast<double>(runs[r].from + runs[r].to) * n,
                                static_cast<double>(j) * n, static_cast<double>(k) * n);
      lo[c] = lo[c].cwiseMin(Eigen::Vector3i(runs[r].from, j, k));
      hi[c] = hi[c].cwiseMax(Eigen::Vector3i(runs[r].to, j, k));
    }
  }
  const double voxel_volume = std::abs(grid.index_to_P.determinant());
  std::vector<int> order(voxels.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return voxels[a] > voxels[b]; });
  std::vector<int> rank_of(voxels.size(), 0);
  std::vector<Component> sorted;
  sorted.reserve(order.size());
  for (std::size_t rank = 0; rank < order.size(); ++rank) {
    const int c0 = order[rank];
    rank_of[c0] = static_cast<int>(rank) + 1;
    Component c;
    c.label = static_cast<int>(rank) + 1;
    c.voxels = voxels[c0];
    const Eigen::Vector3d mean = sum[c0] / static_cast<double>(c.voxels);
    c.centroid_P = grid.PatientPoint(mean.x(), mean.y(), mean.z());
    c.volume = static_cast<double>(c.voxels) * voxel_volume;
    c.min_P = Eigen::Vector3d::Constant(HUGE_VAL);
    c.max_P = Eigen::Vector3d::Constant(-HUGE_VAL);
    for (int corner = 0; corner < 8; ++corner) {
      const Eigen::Vector3d p = grid.PatientPoint(corner & 1 ? hi[c0].x() : lo[c0].x(),
                                                  corner & 2 ? hi[c0].y() : lo[c0].y(),
                                                  corner & 4 ? hi[c0].z() : lo[c0].z());
      c.min_P = c.min_P.cwiseMin(p);
      c.max_P = c.max_P.cwiseMax(p);
    }
    sorted.push_back(c);
  }
  labels->assign(mask.inside.size(), 0);
  for (long row = 0; row < rows; ++row) {
    for (int r = row_begin[row]; r < row_begin[row + 1]; ++r) {
      std::fill(labels->begin() + row * nx + runs[r].from,
                labels->begin() + row * nx + runs[r].to + 1, rank_of[id[r]]);
    }
  }
  return sorted;
}

namespace {

// A CT table (or a pad) under the patient joined to the body (SegmentationOptions::table_*):
// left out of `body` (the body's component, before its holes are filled). Worked on blocks of
// about `table_grid`: erode the body by a ball of `table_thickness` (what stays is the core: the
// trunk, and arms joined to it by a thin contact), grow the core back by the ball; what it does
// not reach is thin. A thin piece that runs through the scan with the same cross-section is the
// table (the body changes along the scan). Where the table lies against the back, its bright
// voxels out of the core go with it. Returns what was left out, in words (empty: nothing).
class TableDetacher {
 public:
  TableDetacher(const Volume& ct, const SegmentationOptions& o, Mask* body)
      : ct_(ct), o_(o), body_(body), axial_(AxialAxis(ct)), nx_(ct.size.x()), ny_(ct.size.y()) {
    const Eigen::Vector3d spacing = ct.spacing();
    for (int a = 0; a < 3; ++a) {
      stride_[a] =
          a == axial_ ? std::max(1, static_cast<int>(std::lround(o.table_grid_slices / spacing[a])))
                      : std::max(1, static_cast<int>(o.table_grid / spacing[a]));
      size_[a] = (ct.size[a] + stride_[a] - 1) / stride_[a];
    }
    grid_.size = size_;
    grid_.index_to_P = ct.index_to_P * stride_.cast<double>().asDiagonal();
    grid_.origin_P = ct.origin_P;
  }

  std::string Run() {
    CoarseBody();
    if (!CoreAndThin()) return {};
    std::vector<int> labels;
    const std::vector<Component> pieces = ConnectedComponents(grid_, thin_, &labels);
    std::ostringstream what;
    const std::vector<int> table_label = TableLabels(pieces, labels, &what);
    if (table_label.empty()) return {};
    Mask table;
    table.size = size_;
    table.inside.assign(labels.size(), 0);
    for (std::size_t v = 0; v < labels.size(); ++v) table.inside[v] = table_label[labels[v]];
    std::vector<long> front;
    std::vector<float> values;
    RemoveTable(table, &front, &values);
    FollowBrightContact(std::move(front), std::move(values));
    std::ostringstream out;
    out << "a thin piece joined to the body that runs through the scan unchanged (a CT table, its "
           "pad or a blanket): "
        << what.str() << "; left out of the body";
    return out.str();
  }

 private:
  long Fine(int i, int j, int k) const { return i + nx_ * (j + ny_ * static_cast<long>(k)); }
  long CoarseOf(int i, int j, int k) const {
    return grid_.Index(i / stride_.x(), j / stride_.y(), k / stride_.z());
  }

  // A coarse voxel is body when any of its block is: a table's shell thinner than the block
  // stays whole.
  void CoarseBody() {
    coarse_.size = size_;
    coarse_.inside.assign(static_cast<std::size_t>(grid_.voxel_count()), 0);
    for (int k = 0; k < ct_.size.z(); ++k) {
      for (int j = 0; j < ct_.size.y(); ++j) {
        const long row = Fine(0, j, k);
        const long coarse_row = grid_.Index(0, j / stride_.y(), k / stride_.z());
        for (int i = 0; i < ct_.size.x(); ++i) {
          if (body_->inside[row + i]) coarse_.inside[coarse_row + i / stride_.x()] = 1;
        }
      }
    }
  }

  // The core: the body eroded by the ball (the trunk, and arms joined to it by a thin contact).
  // Outside is what lies outside the body's outline: the lungs and airways (holes in each
  // slice) are not, so a thin chest wall over them is not thin. Thin: the body the core grown
  // back by the ball does not reach (with a coarse voxel's diagonal more, so the skin the grid
  // samples unevenly stays with the core). False when nothing is left of the core.
  bool CoreAndThin() {
    Mask outside = coarse_;
    FillHolesPerSlice(grid_, &outside);
    for (auto& in : outside.inside) in = !in;
    to_outside_ = SquaredDistanceToMask(grid_, outside);
    r2_ = static_cast<float>(o_.table_thickness * o_.table_thickness);
    Mask core = coarse_;
    for (std::size_t v = 0; v < to_outside_.size(); ++v) core.inside[v] = to_outside_[v] > r2_;
    if (core.count() == 0) return false;
    to_core_ = SquaredDistanceToMask(grid_, core);
    reach_ = o_.table_thickness + grid_.spacing().norm();
    thin_ = coarse_;
    for (std::size_t v = 0; v < to_core_.size(); ++v)
      thin_.inside[v] = coarse_.inside[v] && to_core_[v] > static_cast<float>(reach_ * reach_);
    return true;
  }

  // Per thin piece of `table_min_volume` or more: the table when it spans `table_min_slices` of
  // the body's slices with the same in-plane footprint (`table_constant`). 1 per table label
  // (index: label), empty when there is none; what it took in words on `what`.
  std::vector<int> TableLabels(const std::vector<Component>& pieces, const std::vector<int>& labels,
                               std::ostringstream* what) const {
    const int a0 = (axial_ + 1) % 3, a1 = (axial_ + 2) % 3;
    const int slices = size_[axial_];
    std::vector<std::uint8_t> body_slice(slices, 0);
    {
      Eigen::Vector3i n;
      for (n.z() = 0; n.z() < size_.z(); ++n.z()) {
        for (n.y() = 0; n.y() < size_.y(); ++n.y()) {
          for (n.x() = 0; n.x() < size_.x(); ++n.x()) {
            if (coarse_.inside[grid_.Index(n.x(), n.y(), n.z())]) body_slice[n[axial_]] = 1;
          }
        }
      }
    }
    const int body_slices = static_cast<int>(std::count(body_slice.begin(), body_slice.end(), 1));
    std::vector<int> table_label(pieces.size() + 1, 0);
    double removed = 0.0;
    for (const Component& c : pieces) {
      if (c.volume < o_.table_min_volume) continue;
      const int label = c.label;
      std::vector<int> footprint(static_cast<std::size_t>(size_[a0]) * size_[a1], 0);
      std::vector<std::uint8_t> in_slice(slices, 0);
      long voxels = 0;
      Eigen::Vector3i n;
      for (n.z() = 0; n.z() < size_.z(); ++n.z()) {
        for (n.y() = 0; n.y() < size_.y(); ++n.y()) {
          for (n.x() = 0; n.x() < size_.x(); ++n.x()) {
            const long v = grid_.Index(n.x(), n.y(), n.z());
            if (labels[v] != label) continue;
            ++voxels;
            in_slice[n[axial_]] = 1;
            ++footprint[n[a0] + static_cast<long>(size_[a0]) * n[a1]];
          }
        }
      }
      const int spanned = static_cast<int>(std::count(in_slice.begin(), in_slice.end(), 1));
      long constant = 0;
      for (int f : footprint) {
        if (f >= 0.8 * spanned) constant += f;
      }
      const double constant_share = static_cast<double>(constant) / static_cast<double>(voxels);
      if (spanned < o_.table_min_slices * body_slices || constant_share < o_.table_constant)
        continue;
      table_label[label] = 1;
      removed += pieces[label - 1].volume;
      const double slice = grid_.index_to_P.col(axial_).norm();
      *what << std::fixed << std::setprecision(0) << (what->tellp() > 0 ? "; " : "") << "about "
            << pieces[label - 1].volume * 1e6 << " ml over " << 1e3 * spanned * slice
            << " of the body's " << 1e3 * body_slices * slice << " mm head to foot, "
            << 100.0 * constant_share << " % of it the same in 80 % of its slices";
    }
    if (removed == 0.0) return {};
    return table_label;
  }

  // Out of the fine body: each voxel whose coarse voxel is the table's, or lies near it and
  // further from the core than the ball (the table's contact with the back: what the body opened
  // by the ball does not hold). The voxels taken are the front of the bright contact's growth;
  // the table's own voxels' values are kept for its threshold.
  void RemoveTable(const Mask& table, std::vector<long>* front, std::vector<float>* values) {
    const std::vector<float> to_table = SquaredDistanceToMask(grid_, table);
    const float near_table = static_cast<float>(4.0 * reach_ * reach_);
    for (int k = 0; k < ct_.size.z(); ++k) {
      for (int j = 0; j < ct_.size.y(); ++j) {
        for (int i = 0; i < ct_.size.x(); ++i) {
          const long c = CoarseOf(i, j, k), v = Fine(i, j, k);
          if (!body_->inside[v]) continue;
          if (table.inside[c] || (to_table[c] <= near_table && to_core_[c] > r2_)) {
            body_->inside[v] = 0;
            front->push_back(v);
            if (table.inside[c]) values->push_back(ct_.values[v]);
          }
        }
      }
    }
  }

  // Where the table lies against the back (within the ball of the core: in voxels the two
  // touch over a patch) shape cannot tell its shell from the skin, but brightness can: from what
  // was taken, on through voxels out of the core at least as bright as the table's lower
  // quartile and 150 HU (above skin and muscle).
  void FollowBrightContact(std::vector<long> front, std::vector<float> values) {
    if (values.empty()) return;
    std::nth_element(values.begin(), values.begin() + values.size() / 4, values.end());
    const float bright = std::max(150.0f, values[values.size() / 4]);
    while (!front.empty()) {
      const long v = front.back();
      front.pop_back();
      const int i = static_cast<int>(v % nx_), j = static_cast<int>((v / nx_) % ny_),
                k = static_cast<int>(v / (nx_ * ny_));
      for (int dk = -1; dk <= 1; ++dk) {
        for (int dj = -1; dj <= 1; ++dj) {
          for (int di = -1; di <= 1; ++di) {
            const int a = i + di, b = j + dj, c = k + dk;
            if (a < 0 || b < 0 || c < 0 || a >= ct_.size.x() || b >= ct_.size.y() ||
                c >= ct_.size.z())
              continue;
            const long n = Fine(a, b, c);
            if (!body_->inside[n] || ct_.values[n] < bright || to_outside_[CoarseOf(a, b, c)] > r2_)
              continue;
            body_->inside[n] = 0;
            front.push_back(n);
          }
        }
      }
    }
  }

  const Volume& ct_;
  const SegmentationOptions& o_;
  Mask* body_;
  const int axial_;
  const long nx_, ny_;
  Eigen::Vector3i stride_, size_;
  Volume grid_;  // the coarse grid (blocks of about `table_grid`)
  Mask coarse_, thin_;
  std::vector<float> to_outside_, to_core_;
  float r2_ = 0.0F;
  double reach_ = 0.0;
};

std::string DetachTable(const Volume& ct, const SegmentationOptions& o, Mask* body) {
  // Hounsfield units only: in a windowed volume fat reads as air, and the skin over thick fat
  // is as thin as a table's shell.
  if (!ct.hounsfield || o.table_thickness <= 0.0 || o.table_grid <= 0.0 ||
      o.table_grid_slices <= 0.0)
    return {};
  return TableDetacher(ct, o, body).Run();
}

}  // namespace

Segmentation Segment(const Volume& ct, const SegmentationOptions& o) {
  Segmentation s;
  s.body_threshold = ct.hounsfield ? o.body_hu : o.raw_body;
  s.bone_threshold = ct.hounsfield ? o.bone_hu : o.raw_bone;
  const std::string units = ct.hounsfield ? " HU" : " (raw)";

  // Body: the largest component above the body threshold, holes filled.
  std::vector<int> labels;
  Mask above = Threshold(ct, s.body_threshold);
  const double closing = ct.hounsfield ? o.body_closing : o.raw_body_closing;
  if (closing > 0.0) {
    // Closing by a ball: bridges the gaps where windowing clipped fat to the value of air.
    const float r2 = static_cast<float>(closing * closing);
    const std::vector<float> to_body = SquaredDistanceToMask(ct, above);
    Mask outside_dilated = above;
    for (std::size_t i = 0; i < to_body.size(); ++i) outside_dilated.inside[i] = to_body[i] > r2;
    const std::vector<float> to_outside = SquaredDistanceToMask(ct, outside_dilated);
    for (std::size_t i = 0; i < to_outside.size(); ++i) above.inside[i] = to_outside[i] > r2;
  }
  const auto body_parts = ConnectedComponents(ct, above, &labels);
  TROCAR_THROW_UNLESS(!body_parts.empty(), ct.source << ": no voxel above the body threshold "
                                                     << s.body_threshold << units
                                                     << ": empty segmentation");
  s.body_min_P = body_parts.front().min_P;  // filling holes inside does not move the bounds
  s.body_max_P = body_parts.front().max_P;
  s.body.size = ct.size;
  s.body.inside.resize(labels.size());
  for (std::size_t i = 0; i < labels.size(); ++i) s.body.inside[i] = labels[i] == 1;
  s.body_table = DetachTable(ct, o, &s.body);
  if (!s.body_table.empty()) {
    // What stays of the body once the table is out: its largest part, and its bounds.
    const auto parts = ConnectedComponents(ct, s.body, &labels);
    s.body_min_P = parts.front().min_P;
    s.body_max_P = parts.front().max_P;
    for (std::size_t i = 0; i < labels.size(); ++i) s.body.inside[i] = labels[i] == 1;
  }
  s.axis_P = 0.5 * (s.body_min_P + s.body_max_P).head<2>();
  std::vector<int>().swap(labels);  // 4 bytes a voxel: not held while the bone is labelled
  std::vector<std::uint8_t>().swap(above.inside);
  if (ct.hounsfield ? o.body_convex_fill : o.raw_body_convex_fill) {
    // The convex fill, unless the outline held (filling the holes closes the lungs in): then an
    // arm beside the chest is not bridged to it.
    Mask holes = s.body;
    FillHolesPerSlice(ct, &holes);
    FillConvexPerSlice(ct, &s.body);
    const double share = static_cast<double>(holes.count()) / static_cast<double>(s.body.count());
    std::ostringstream why;
    why << std::fixed << std::setprecision(0) << "filling each slice's holes gives "
        << 100.0 * share << " % of the convex fill's volume";
    if (share >= o.convex_fill_below) {
      s.body = std::move(holes);
      why << ": the outline held, holes filled (an arm beside the chest stays apart)";
    } else {
      why << ": the outline is broken (fat at the value of air), each slice filled to its convex "
             "hull";
    }
    s.body_fill = why.str();
  } else {
    FillHolesPerSlice(ct, &s.body);
  }

  // Bone: above the bone threshold and inside the body (so the table is left out).
  s.bone = Threshold(ct, s.bone_threshold);
  for (std::size_t i = 0; i < s.bone.inside.size(); ++i) s.bone.inside[i] &= s.body.inside[i];
  TROCAR_THROW_UNLESS(s.bone.count() > 0, ct.source << ": no bone above " << s.bone_threshold
                                                     << units << " inside the body: empty segmentation");
  if (o.shape_anatomy) {
    ClassifyBones(ct, &s, o.anatomy, o.min_bone_volume);
    return s;
  }
  // Place only (`bones: place`, the earlier rule kept for comparison, docs/decisions.md):
  // each bone component by where it lies in the body's bounding box.
  const auto bone_parts = ConnectedComponents(ct, s.bone, &s.bones.labels);
  const Eigen::Vector3d centre = 0.5 * (s.body_min_P + s.body_max_P);
  const Eigen::Vector3d half = 0.5 * (s.body_max_P - s.body_min_P);
  for (const Component& c : bone_parts) {
    if (c.volume < o.min_bone_volume) continue;
    const double lateral = (c.centroid_P.x() - centre.x()) / half.x();
    const bool straddles_midline = c.min_P.x() < centre.x() && c.max_P.x() > centre.x();
    if (straddles_midline || std::abs(lateral) < 0.12) {
      (c.centroid_P.y() > centre.y() ? s.bones.spine : s.bones.sternum).push_back(c);
    } else {
      (lateral > 0 ? s.bones.ribs_left : s.bones.ribs_right).push_back(c);
    }
  }
  auto by_height = [](const Component& a, const Component& b) { return a.centroid_P.z() > b.centroid_P.z(); };
  std::sort(s.bones.ribs_left.begin(), s.bones.ribs_left.end(), by_height);
  std::sort(s.bones.ribs_right.begin(), s.bones.ribs_right.end(), by_height);
  return s;
}

Mask ResampleMask(const Volume& mask_volume, const Volume& grid, double threshold) {
  Mask m;
  m.size = grid.size;
  m.inside.assign(static_cast<std::size_t>(grid.voxel_count()), 0);
  const Eigen::Matrix3d to_index = mask_volume.index_to_P.inverse();
  long hits = 0;
  for (int k = 0; k < grid.size.z(); ++k) {
    for (int j = 0; j < grid.size.y(); ++j) {
      for (int i = 0; i < grid.size.x(); ++i) {
        const Eigen::Vector3d ijk = to_index * (grid.PatientPoint(i, j, k) - mask_volume.origin_P);
        const Eigen::Vector3i n(static_cast<int>(std::lround(ijk.x())), static_cast<int>(std::lround(ijk.y())),
                                static_cast<int>(std::lround(ijk.z())));
        if ((n.array() < 0).any() || (n.array() >= mask_volume.size.array()).any()) continue;
        if (mask_volume.at(n.x(), n.y(), n.z()) > threshold) {
          m.inside[grid.Index(i, j, k)] = 1;
          ++hits;
        }
      }
    }
  }
  TROCAR_THROW_UNLESS(hits > 0, mask_volume.source << ": the mask does not overlap " << grid.source
                                                   << " (no voxel above " << threshold << " lands on it)");
  return m;
}

BodyRoll MeasureBodyRoll(const Volume& ct, const Mask& body) {
  // Moments in index space, carried into the patient frame through the grid's geometry.
  // Per row (j, k fixed) only the count and the sums of i and i² go voxel by voxel.
  const int nx = ct.size.x(), ny = ct.size.y(), nz = ct.size.z();
  double n = 0.0;
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  Eigen::Matrix3d products = Eigen::Matrix3d::Zero();
  for (int k = 0; k < nz; ++k) {
    for (int j = 0; j < ny; ++j) {
      const std::uint8_t* row =
          &body.inside[static_cast<std::size_t>(nx) * (j + static_cast<std::size_t>(ny) * k)];
      std::int64_t count = 0, si = 0, sii = 0;
      for (int i = 0; i < nx; ++i) {
        const std::int64_t in = row[i] != 0;
        count += in;
        si += in * i;
        sii += in * i * i;
      }
      if (count == 0) continue;
      const double c = static_cast<double>(count), a = static_cast<double>(si),
                   b = static_cast<double>(j), d = static_cast<double>(k);
      n += c;
      sum += Eigen::Vector3d(a, c * b, c * d);
      products(0, 0) += static_cast<double>(sii);
      products(0, 1) += a * b;
      products(0, 2) += a * d;
      products(1, 1) += c * b * b;
      products(1, 2) += c * b * d;
      products(2, 2) += c * d * d;
    }
  }
  products(1, 0) = products(0, 1);
  products(2, 0) = products(0, 2);
  products(2, 1) = products(1, 2);
  BodyRoll roll;
  if (n < 2.0) return roll;
  const Eigen::Vector3d mean = sum / n;
  const Eigen::Matrix3d covariance_index = products / n - mean * mean.transpose();
  const Eigen::Matrix3d covariance = ct.index_to_P * covariance_index * ct.index_to_P.transpose();
  roll.centre_P = ct.origin_P + ct.index_to_P * mean;
  const double cxx = covariance(0, 0), cyy = covariance(1, 1), cxy = covariance(0, 1);
  roll.angle = 0.5 * std::atan2(2.0 * cxy, cxx - cyy);
  const double half_trace = 0.5 * (cxx + cyy);
  const double spread = std::sqrt(std::max(0.0, 0.25 * (cxx - cyy) * (cxx - cyy) + cxy * cxy));
  const double minor = half_trace - spread;
  roll.aspect = minor > 0.0 ? std::sqrt((half_trace + spread) / minor) : HUGE_VAL;
  return roll;
}

double GridObliquity(const Volume& v) {
  double worst = 0.0;
  for (int axis = 0; axis < 3; ++axis) {
    const Eigen::Vector3d u = v.index_to_P.col(axis);
    const double length = u.norm();
    if (!(length > 0.0)) continue;
    worst = std::max(worst, std::acos(std::min(1.0, u.cwiseAbs().maxCoeff() / length)));
  }
  return worst;
}

void MoveVolumeFrame(const Eigen::Isometry3d& X_DP, Volume* v) {
  v->origin_P = X_DP * v->origin_P;
  v->index_to_P = X_DP.linear() * v->index_to_P;
}

Volume ResampleTurned(const Volume& v, const Eigen::Isometry3d& X_DP, float fill, const Mask* cover,
                      int margin) {
  const int axial = AxialAxis(v);
  const double step = InPlaneSpacing(v).minCoeff();
  const double dz = std::abs(v.index_to_P.col(axial).z());
  TROCAR_THROW_UNLESS(step > 0.0 && dz > 0.0, v.source << ": cannot turn a volume without slices");
  // The original's corners (voxel centres) in D; in-plane, the covered voxels' box and the
  // margin when a cover is given.
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(HUGE_VAL), hi = -lo;
  for (int corner = 0; corner < 8; ++corner) {
    const Eigen::Vector3d ijk((corner & 1) ? v.size.x() - 1 : 0, (corner & 2) ? v.size.y() - 1 : 0,
                              (corner & 4) ? v.size.z() - 1 : 0);
    const Eigen::Vector3d p_D = X_DP * v.PatientPoint(ijk.x(), ijk.y(), ijk.z());
    lo = lo.cwiseMin(p_D);
    hi = hi.cwiseMax(p_D);
  }
  if (cover != nullptr && cover->count() > 0) {
    Eigen::Vector2d in_lo = Eigen::Vector2d::Constant(HUGE_VAL), in_hi = -in_lo;
    for (int k = 0; k < v.size.z(); ++k) {
      for (int j = 0; j < v.size.y(); ++j) {
        for (int i = 0; i < v.size.x(); ++i) {
          if (!cover->inside[v.Index(i, j, k)]) continue;
          const Eigen::Vector2d p_D = (X_DP * v.PatientPoint(i, j, k)).head<2>();
          in_lo = in_lo.cwiseMin(p_D);
          in_hi = in_hi.cwiseMax(p_D);
        }
      }
    }
    lo.head<2>() = lo.head<2>().cwiseMax(in_lo - Eigen::Vector2d::Constant(margin * step));
    hi.head<2>() = hi.head<2>().cwiseMin(in_hi + Eigen::Vector2d::Constant(margin * step));
  }
  Volume out;
  out.hounsfield = v.hounsfield;
  out.source = v.source;
  out.files = v.files;
  // Slices dz apart over the corners' heights: the original's count unless its slices are
  // sheared along the table (a gantry tilt), whose corners reach further. A header sheared
  // beyond any scanner's tilt asks for a grid too large: refused by the voxel limit, naming it.
  auto count = [&](double n, const char* axis) {
    TROCAR_THROW_UNLESS(n >= 1.0 && n <= 1e6, v.source
                                                  << ": resampled along the patient's axes, its "
                                                  << axis << " axis would hold " << n
                                                  << " voxels: check the header's directions");
    return static_cast<int>(n);
  };
  const int slices =
      v.size[axial] == 1 ? 1 : count(std::floor((hi.z() - lo.z()) / dz + 0.5) + 1.0, "z");
  out.size = Eigen::Vector3i(count(std::floor((hi.x() - lo.x()) / step + 1e-9) + 1.0, "x"),
                             count(std::floor((hi.y() - lo.y()) / step + 1e-9) + 1.0, "y"), slices);
  CheckedVoxelCount(out.size, v.source + ": the grid resampled along the patient's axes");
  out.index_to_P =
      Eigen::Vector3d(step, step, slices > 1 ? (hi.z() - lo.z()) / (slices - 1) : dz).asDiagonal();
  out.origin_P = lo;
  out.values.assign(static_cast<std::size_t>(out.size.x()) * out.size.y() * out.size.z(), fill);
  const Eigen::Isometry3d X_PD = X_DP.inverse();
  const Eigen::Matrix3d to_index = v.index_to_P.inverse();
#pragma omp parallel for schedule(static)
  for (int k = 0; k < out.size.z(); ++k) {
    for (int j = 0; j < out.size.y(); ++j) {
      for (int i = 0; i < out.size.x(); ++i) {
        const Eigen::Vector3d f = to_index * (X_PD * out.PatientPoint(i, j, k) - v.origin_P);
        const long a = std::lround(f.x()), b = std::lround(f.y()), c = std::lround(f.z());
        if (a < 0 || b < 0 || c < 0 || a >= v.size.x() || b >= v.size.y() || c >= v.size.z())
          continue;
        out.values[out.Index(i, j, k)] =
            v.values[v.Index(static_cast<int>(a), static_cast<int>(b), static_cast<int>(c))];
      }
    }
  }
  return out;
}

}  // namespace trocar::patient
