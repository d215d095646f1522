#include "patient/anatomy.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iomanip>
#include <map>
#include <set>
#include <sstream>

#include "common/error.hpp"
#include "patient/intercostal.hpp"
#include "patient/segmentation.hpp"
#include "patient/volume.hpp"

namespace trocar::patient {
namespace {

template <typename T>
void Release(std::vector<T>* v) {
  std::vector<T>().swap(*v);
}

// Axial slices binned by the patient's z (the scan's slices whatever its index order).
struct Slices {
  double z0 = 0.0, dz = 1.0;
  double z_top = 0.0;  // the scan's highest z (z0 its lowest)
  int count = 0;
  explicit Slices(const Volume& v) {
    double lo = HUGE_VAL, hi = -HUGE_VAL;
    for (int corner = 0; corner < 8; ++corner) {
      const double z =
          v.PatientPoint(corner & 1 ? v.size.x() - 1 : 0, corner & 2 ? v.size.y() - 1 : 0,
                         corner & 4 ? v.size.z() - 1 : 0)
              .z();
      lo = std::min(lo, z);
      hi = std::max(hi, z);
    }
    dz = HUGE_VAL;
    for (int a = 0; a < 3; ++a) {
      const double step = std::abs(v.index_to_P.col(a).z());
      if (step > 1e-6) dz = std::min(dz, step);
    }
    if (!std::isfinite(dz)) dz = 1.0;
    z0 = lo;
    z_top = hi;
    count = static_cast<int>(std::floor((hi - lo) / dz + 1.5));
  }
  int Of(double z) const {
    return std::clamp(static_cast<int>(std::lround((z - z0) / dz)), 0, count - 1);
  }
};

// Voxels of `bone` a ball of `radius` fits in, grown back by the ball (a morphological opening),
// on a grid coarsened to about radius/4 (or `min_cell`, m, when larger) so that a clinical CT's
// opening stays cheap.
Mask ThickParts(const Volume& ct, const Mask& bone, double radius, double min_cell = 0.0) {
  const Eigen::Vector3d h = ct.spacing();
  Eigen::Vector3i f;
  for (int a = 0; a < 3; ++a)
    f[a] = std::max(1, static_cast<int>(std::lround(std::max(0.25 * radius, min_cell) / h[a])));
  Volume coarse;
  coarse.size = (ct.size.array() + f.array() - 1) / f.array();
  coarse.index_to_P = ct.index_to_P * f.cast<double>().asDiagonal();
  coarse.origin_P =
      ct.origin_P + ct.index_to_P * (0.5 * (f.cast<double>() - Eigen::Vector3d::Ones()));
  const long cells = static_cast<long>(coarse.size.x()) * coarse.size.y() * coarse.size.z();
  std::vector<int> count(cells, 0), total(cells, 0);
  // Each fine index's coarse index, per axis (no division per voxel); a coarse slab of f.z fine
  // slices per thread, so that no two threads add to one cell.
  std::vector<int> ci(ct.size.x()), cj(ct.size.y());
  for (int i = 0; i < ct.size.x(); ++i) ci[i] = i / f.x();
  for (int j = 0; j < ct.size.y(); ++j) cj[j] = j / f.y();
  const long nxc = coarse.size.x(), nyc = coarse.size.y();
#pragma omp parallel for schedule(static)
  for (int kc = 0; kc < coarse.size.z(); ++kc) {
    for (int k = kc * f.z(); k < std::min(ct.size.z(), (kc + 1) * f.z()); ++k) {
      for (int j = 0; j < ct.size.y(); ++j) {
        const long row = ct.Index(0, j, k);
        const long cell_row = nxc * (cj[j] + nyc * kc);
        for (int i = 0; i < ct.size.x(); ++i) {
          const long c = cell_row + ci[i];
          ++total[c];
          count[c] += bone.inside[row + i] != 0;
        }
      }
    }
  }
  Mask outside;  // cells mostly not bone
  outside.size = coarse.size;
  outside.inside.resize(cells);
  for (long c = 0; c < cells; ++c) outside.inside[c] = 2 * count[c] < total[c];
  Release(&count);
  Release(&total);
  Mask thick;
  thick.size = ct.size;
  thick.inside.assign(bone.inside.size(), 0);
  const float r2 = static_cast<float>(radius * radius);
  Mask core;
  core.size = coarse.size;
  core.inside.resize(cells);
  {
    const std::vector<float> to_outside = SquaredDistanceToMask(coarse, outside);
    bool any = false;
    for (long c = 0; c < cells; ++c) any |= (core.inside[c] = to_outside[c] > r2) != 0;
    if (!any) return thick;
  }
  const std::vector<float> to_core = SquaredDistanceToMask(coarse, core);
#pragma omp parallel for schedule(static)
  for (int k = 0; k < ct.size.z(); ++k) {
    const int kc = k / f.z();
    for (int j = 0; j < ct.size.y(); ++j) {
      const long row = ct.Index(0, j, k);
      const long cell_row = nxc * (cj[j] + nyc * kc);
      for (int i = 0; i < ct.size.x(); ++i) {
        const long v = row + i;
        const long c = cell_row + ci[i];
        thick.inside[v] = bone.inside[v] && !outside.inside[c] && to_core[c] <= r2;
      }
    }
  }
  return thick;
}

// The spine's axis in each axial slice: the mirror line of the thin bone near the posterior
// midline (posterior arches, the vertebral bodies' cortex, the ribs' heads), filled across slices
// without any.
struct SpineAxis {
  std::vector<double> x, y;
  std::vector<std::uint8_t> known;
  bool any = false;
};

double Median(std::vector<double>* v) {
  std::nth_element(v->begin(), v->begin() + v->size() / 2, v->end());
  return (*v)[v->size() / 2];
}

// The body in each slice: its front-back extent (the spine lies in its back 40 %) and its
// left-right centre.
struct BodyPerSlice {
  std::vector<double> y_lo, y_hi, x_sum;
  std::vector<long> x_n;
  double Back(int s) const {
    return y_lo[s] + 0.6 * (y_hi[s] - y_lo[s]);
  }  // the back 40 % from here
  double Centre(int s) const { return x_n[s] ? x_sum[s] / x_n[s] : 0.0; }
};

BodyPerSlice MeasureBodyPerSlice(const Volume& ct, const Mask& body, const Slices& slices) {
  BodyPerSlice b;
  b.y_lo.assign(slices.count, HUGE_VAL);
  b.y_hi.assign(slices.count, -HUGE_VAL);
  b.x_sum.assign(slices.count, 0.0);
  b.x_n.assign(slices.count, 0);
  const Eigen::Vector3d step_i = ct.index_to_P.col(0);
  for (int k = 0; k < ct.size.z(); ++k) {
    for (int j = 0; j < ct.size.y(); ++j) {
      const long row = ct.Index(0, j, k);
      const Eigen::Vector3d row_P = ct.PatientPoint(0, j, k);
      for (int i = 0; i < ct.size.x(); ++i) {
        if (!body.inside[row + i]) continue;
        const Eigen::Vector3d p = row_P + i * step_i;
        const int s = slices.Of(p.z());
        b.y_lo[s] = std::min(b.y_lo[s], p.y());
        b.y_hi[s] = std::max(b.y_hi[s], p.y());
        b.x_sum[s] += p.x();
        ++b.x_n[s];
      }
    }
  }
  return b;
}

// The bone in each slice's back 40 %, within `spine_search` of its centre left-right: thin bone
// first (the posterior arches, the bodies' cortex); in slices without any, the thick (a solid
// vertebral body).
std::vector<std::vector<Eigen::Vector2d>> BackBone(const Volume& ct, const Mask& bone,
                                                   const Mask& exclude, const Slices& slices,
                                                   const BodyPerSlice& body,
                                                   const AnatomyOptions& o) {
  std::vector<std::vector<Eigen::Vector2d>> candidates(slices.count), thick(slices.count);
  for (int k = 0; k < ct.size.z(); ++k) {
    for (int j = 0; j < ct.size.y(); ++j) {
      for (int i = 0; i < ct.size.x(); ++i) {
        const long v = ct.Index(i, j, k);
        if (!bone.inside[v]) continue;
        const Eigen::Vector3d p = ct.PatientPoint(i, j, k);
        const int s = slices.Of(p.z());
        if (p.y() < body.Back(s)) continue;
        if (std::abs(p.x() - body.x_sum[s] / body.x_n[s]) > o.spine_search) continue;
        (exclude.inside[v] ? thick : candidates)[s].push_back(p.head<2>());
      }
    }
  }
  const double area = InPlaneSpacing(ct).prod();
  for (int s = 0; s < slices.count; ++s) {
    if (candidates[s].size() * area < 20e-6) candidates[s].swap(thick[s]);
  }
  return candidates;
}

// The midline in each slice: the left-right mirror line of the back's thin bone (vertebrae,
// their processes, the ribs' heads and necks), where bone on one side answers bone on the
// other at the same height front-back, over a slab of slices. A band of densest bone was pulled
// aside by one side's rib necks by up to 2 cm on a real slab; the spine is symmetric where no
// single band is. Only pairs between `kPairGap` and `kPairReach` either side of the line count:
// no dense piece scores by mirroring onto itself, and the ribs' shafts further out, which pair
// across any line on a crop off the body's centre, do not.
class MirrorSearch {
 public:
  MirrorSearch(const Volume& ct, const Slices& slices, const BodyPerSlice& body,
               const AnatomyOptions& o)
      : ct_(ct), slices_(slices), body_(body) {
    bin_ = std::max(InPlaneSpacing(ct).mean(), 1e-3);
    search_ = static_cast<int>(std::floor(o.spine_search / bin_));
    gap_ = static_cast<int>(std::ceil(kPairGap / bin_));
    reach_ = static_cast<int>(std::floor(kPairReach / bin_));
    half_bins_ = search_ + reach_ + 1;
    bins_ = 2 * half_bins_ + 1;  // x about each slice's body centre
    double y_max = -HUGE_VAL;
    for (int s = 0; s < slices.count; ++s) {
      if (body.y_hi[s] < body.y_lo[s]) continue;
      y_min_ = std::min(y_min_, body.Back(s));
      y_max = std::max(y_max, body.y_hi[s]);
    }
    rows_ = y_max >= y_min_ ? static_cast<int>(std::floor((y_max - y_min_) / kRowHeight)) + 1 : 0;
    centre_.assign(slices.count, 0.0);
    for (int s = 0; s < slices.count; ++s) centre_[s] = body.Centre(s);
  }

  /// Per slice with candidates, the mirror line's x (`mirrored` set where one was found).
  void Find(const Mask& bone, const Mask& exclude,
            const std::vector<std::vector<Eigen::Vector2d>>& candidates,
            std::vector<double>* mirror_x, std::vector<std::uint8_t>* mirrored) const {
    std::vector<std::vector<float>> grid = ThinBoneCounts(bone, exclude);
    const int slab = std::max(0, static_cast<int>(std::lround(0.01 / slices_.dz)));  // ±1 cm
    mirror_x->assign(slices_.count, 0.0);
    mirrored->assign(slices_.count, 0);
    std::vector<float> h(static_cast<std::size_t>(rows_) * bins_);
    for (int s = 0; s < slices_.count; ++s) {
      if (candidates[s].empty()) continue;
      SumSlab(grid, s, slab, &h);
      const int best_m = BestMirror(h);
      if (best_m < 0) continue;
      (*mirror_x)[s] = centre_[s] + (0.5 * best_m - half_bins_) * bin_;
      (*mirrored)[s] = 1;
    }
  }

 private:
  static constexpr double kPairGap = 0.008, kPairReach = 0.045, kRowHeight = 0.002;

  // Thin bone counts per slice, row (front-back) and column (left-right).
  std::vector<std::vector<float>> ThinBoneCounts(const Mask& bone, const Mask& exclude) const {
    const Volume& ct = ct_;
    const Eigen::Vector3d step_i = ct.index_to_P.col(0);
    std::vector<std::vector<float>> grid(slices_.count);
    for (int k = 0; k < ct.size.z(); ++k) {
      for (int j = 0; j < ct.size.y(); ++j) {
        const long row = ct.Index(0, j, k);
        const Eigen::Vector3d row_P = ct.PatientPoint(0, j, k);
        for (int i = 0; i < ct.size.x(); ++i) {
          if (!bone.inside[row + i] || exclude.inside[row + i]) continue;  // thin bone, no vessel
          const Eigen::Vector3d p = row_P + i * step_i;
          const int s = slices_.Of(p.z());
          if (p.y() < body_.Back(s)) continue;
          const int b = static_cast<int>(std::lround((p.x() - centre_[s]) / bin_)) + half_bins_;
          const int r = static_cast<int>(std::floor((p.y() - y_min_) / kRowHeight));
          if (b < 0 || b >= bins_ || r < 0 || r >= rows_) continue;
          if (grid[s].empty()) grid[s].assign(static_cast<std::size_t>(rows_) * bins_, 0.f);
          grid[s][static_cast<std::size_t>(r) * bins_ + b] += 1.f;
        }
      }
    }
    return grid;
  }

  // The counts of the slab of slices about s, each slice's columns about its own body centre
  // re-centred on this slice's.
  void SumSlab(const std::vector<std::vector<float>>& grid, int s, int slab,
               std::vector<float>* h) const {
    std::fill(h->begin(), h->end(), 0.f);
    for (int t = std::max(0, s - slab); t <= std::min(slices_.count - 1, s + slab); ++t) {
      if (grid[t].empty()) continue;
      const int shift = static_cast<int>(std::lround((centre_[t] - centre_[s]) / bin_));
      for (int r = 0; r < rows_; ++r) {
        const float* from = &grid[t][static_cast<std::size_t>(r) * bins_];
        float* to = &(*h)[static_cast<std::size_t>(r) * bins_];
        for (int b = std::max(0, -shift); b < std::min(bins_, bins_ - shift); ++b)
          to[b + shift] += from[b];
      }
    }
  }

  // Mirror about the half-bin position m/2: columns a and m − a meet (rows without bone
  // skipped). The m of the highest score, -1 when no pair scores.
  int BestMirror(const std::vector<float>& h) const {
    std::vector<int> busy;
    for (int r = 0; r < rows_; ++r) {
      const float* row = &h[static_cast<std::size_t>(r) * bins_];
      if (std::any_of(row, row + bins_, [](float x) { return x > 0.f; })) busy.push_back(r);
    }
    double best = 0.0;
    int best_m = -1;
    for (int m = 2 * half_bins_ - 2 * search_; m <= 2 * half_bins_ + 2 * search_; ++m) {
      double score = 0.0;
      for (const int r : busy) {
        const float* row = &h[static_cast<std::size_t>(r) * bins_];
        // d = (m − a) − a, the pair's spread, of m's parity.
        for (int d = 2 * gap_ + ((m - 2 * gap_) & 1); d <= 2 * reach_; d += 2) {
          const int a = (m - d) / 2;
          if (a < 0 || m - a >= bins_) continue;
          score += static_cast<double>(row[a]) * row[m - a];
        }
      }
      if (score > best) {
        best = score;
        best_m = m;
      }
    }
    return best_m;
  }

  const Volume& ct_;
  const Slices& slices_;
  const BodyPerSlice& body_;
  double bin_ = 0.0, y_min_ = HUGE_VAL;
  int search_ = 0, gap_ = 0, reach_ = 0, half_bins_ = 0, bins_ = 0, rows_ = 0;
  std::vector<double> centre_;
};

// A running median over more than a vertebra's height (`axis_smoothing` either side) smooths
// out a slice caught on a disc or on one side's processes: the spine bends slowly.
void SmoothAxis(const Slices& slices, const AnatomyOptions& o, SpineAxis* a) {
  const int w = std::max(1, static_cast<int>(std::lround(o.axis_smoothing / slices.dz)));
  std::vector<double> sx = a->x, sy = a->y;
  for (int s = 0; s < slices.count; ++s) {
    if (!a->known[s]) continue;
    std::vector<double> nx, ny;
    for (int t = std::max(0, s - w); t <= std::min(slices.count - 1, s + w); ++t) {
      if (!a->known[t]) continue;
      nx.push_back(a->x[t]);
      ny.push_back(a->y[t]);
    }
    sx[s] = Median(&nx);
    sy[s] = Median(&ny);
  }
  a->x = sx;
  a->y = sy;
}

// Slices without midline bone (an intervertebral disc) take the nearest known slice's axis
// within 2 cm.
void FillAxisGaps(const Slices& slices, SpineAxis* a) {
  const int fill_reach = static_cast<int>(std::lround(0.02 / slices.dz));
  std::vector<std::uint8_t> filled = a->known;
  for (int s = 0; s < slices.count; ++s) {
    if (a->known[s]) continue;
    for (int d = 1; d <= fill_reach; ++d) {
      const int t = s - d >= 0 && a->known[s - d]
                        ? s - d
                        : (s + d < slices.count && a->known[s + d] ? s + d : -1);
      if (t < 0) continue;
      a->x[s] = a->x[t];
      a->y[s] = a->y[t];
      filled[s] = 1;
      break;
    }
  }
  a->known = filled;
}

SpineAxis FindSpineAxis(const Volume& ct, const Mask& body, const Mask& bone, const Mask& exclude,
                        const Slices& slices, const AnatomyOptions& o) {
  const BodyPerSlice extent = MeasureBodyPerSlice(ct, body, slices);
  std::vector<std::vector<Eigen::Vector2d>> candidates =
      BackBone(ct, bone, exclude, slices, extent, o);
  std::vector<double> mirror_x;
  std::vector<std::uint8_t> mirrored;
  MirrorSearch(ct, slices, extent, o).Find(bone, exclude, candidates, &mirror_x, &mirrored);
  // The axis' front-back place is the median of the midline band's bone.
  std::vector<std::vector<double>> xs(slices.count), ys(slices.count);
  for (int s = 0; s < slices.count; ++s) {
    if (!mirrored[s]) continue;
    for (const Eigen::Vector2d& c : candidates[s]) {
      if (std::abs(c.x() - mirror_x[s]) > o.midline_band) continue;
      xs[s].push_back(c.x());
      ys[s].push_back(c.y());
    }
  }
  Release(&candidates);
  SpineAxis a;
  a.x.assign(slices.count, 0.0);
  a.y.assign(slices.count, 0.0);
  a.known.assign(slices.count, 0);
  const double voxel_area = InPlaneSpacing(ct).prod();
  for (int s = 0; s < slices.count; ++s) {
    if (xs[s].size() * voxel_area < 20e-6) continue;  // 20 mm² of midline bone at least
    a.x[s] = mirror_x[s];
    a.y[s] = Median(&ys[s]);
    a.known[s] = 1;
    a.any = true;
  }
  SmoothAxis(slices, o, &a);
  FillAxisGaps(slices, &a);
  return a;
}

bool InColumn(const SpineAxis& a, int s, const Eigen::Vector3d& p, const AnatomyOptions& o) {
  if (!a.known[s]) return false;
  const double dy = p.y() - a.y[s];
  return std::abs(p.x() - a.x[s]) <= o.spine_half_width && dy >= -o.spine_front &&
         dy <= o.spine_back;
}

// Whether no enhanced blood or organ shows: under `enhanced_share` of the body between
// `unenhanced_max_hu` and the bone threshold, more than two voxels from bone (a bone's partial-
// volume edge reads between the two as well). Reported either way.
bool Unenhanced(const Volume& ct, const Mask& body, double bone_threshold, const AnatomyOptions& o,
                std::vector<std::string>* report) {
  if (o.unenhanced_max_hu >= bone_threshold) return false;
  const int nx = ct.size.x(), ny = ct.size.y(), nz = ct.size.z();
  long inside = 0, between = 0;
  for (int k = 0; k < nz; ++k) {
    for (int j = 0; j < ny; ++j) {
      for (int i = 0; i < nx; ++i) {
        const long v = ct.Index(i, j, k);
        if (!body.inside[v]) continue;
        ++inside;
        const float h = ct.values[v];
        if (h < o.unenhanced_max_hu || h >= bone_threshold) continue;
        bool near_bone = false;
        for (int c = std::max(0, k - 2); c <= std::min(nz - 1, k + 2) && !near_bone; ++c) {
          for (int b = std::max(0, j - 2); b <= std::min(ny - 1, j + 2) && !near_bone; ++b) {
            for (int a = std::max(0, i - 2); a <= std::min(nx - 1, i + 2) && !near_bone; ++a) {
              near_bone = ct.values[ct.Index(a, b, c)] >= bone_threshold;
            }
          }
        }
        between += !near_bone;
      }
    }
  }
  const double share =
      inside > 0 ? static_cast<double>(between) / static_cast<double>(inside) : 1.0;
  const bool plain = share < o.enhanced_share;
  std::ostringstream s;
  s << std::fixed << std::setprecision(2) << share * 100 << " % of the body reads "
    << std::setprecision(0) << o.unenhanced_max_hu << "-" << bone_threshold
    << " HU away from bone: "
    << (plain ? "unenhanced, bone grown into its partial-volume stretches above "
              : "enhanced blood or organs, bone grown only near its cortex, above ")
    << (plain ? o.unenhanced_max_hu : o.grow_hu) << " HU";
  report->push_back(s.str());
  return plain;
}

// Grows labelled voxels into unlabelled ones that pass `accept`, breadth first, at most `steps`
// voxels away (26-neighbours); each grown voxel takes the label it was reached from, the smallest
// (the largest component's) when labels reach it in the same step: the result does not depend on
// the order the file stores its axes in. Labels are non-negative; during a step a voxel claimed
// holds its label negated.
template <typename Accept>
void Grow(const Volume& grid, std::vector<int>* labels, int steps, const Accept& accept) {
  std::vector<long> front, next;
  for (long v = 0; v < static_cast<long>(labels->size()); ++v) {
    TROCAR_THROW_UNLESS((*labels)[v] >= 0, "Grow: negative label");
    if ((*labels)[v] != 0) front.push_back(v);
  }
  const int nx = grid.size.x(), ny = grid.size.y(), nz = grid.size.z();
  for (int step = 0; step < steps && !front.empty(); ++step) {
    next.clear();
    for (const long v : front) {
      const int i = static_cast<int>(v % nx), j = static_cast<int>((v / nx) % ny);
      const int k = static_cast<int>(v / (static_cast<long>(nx) * ny));
      for (int dk = -1; dk <= 1; ++dk) {
        for (int dj = -1; dj <= 1; ++dj) {
          for (int di = -1; di <= 1; ++di) {
            const int ii = i + di, jj = j + dj, kk = k + dk;
            if (ii < 0 || jj < 0 || kk < 0 || ii >= nx || jj >= ny || kk >= nz) continue;
            const long n = grid.Index(ii, jj, kk);
            int& l = (*labels)[n];
            if (l < 0) {
              l = std::max(l, -(*labels)[v]);  // reached again this step: the smaller label
              continue;
            }
            if (l != 0 || !accept(n)) continue;
            l = -(*labels)[v];
            next.push_back(n);
          }
        }
      }
    }
    for (const long n : next) (*labels)[n] = -(*labels)[n];
    front.swap(next);
  }
}

std::string Ml(double m3) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(0) << m3 * 1e6 << " ml";
  return s.str();
}

// Thick bright blobs: heart chambers and vessels full of contrast, or solid vertebral bodies,
// with their rims (bright voxels within the ball's radius of them); the spine's axis from the
// other bone near the posterior midline. Blobs mostly in the spine's column are vertebrae; the
// others are returned as vessels.
Mask FindVessels(const Volume& ct, const Mask& body, const Mask& bone, const Slices& slices,
                 const AnatomyOptions& o, SpineAxis* axis, Mask* thick_bone) {
  Mask vessels;
  vessels.size = ct.size;
  vessels.inside.assign(bone.inside.size(), 0);
  thick_bone->size = ct.size;
  thick_bone->inside.assign(bone.inside.size(), 0);
  // Thick parts of what is as bright as contrast-filled blood (or brighter): blood hovering
  // about the bone threshold is spongy above it, solid above the blood threshold.
  const double blood = ct.hounsfield ? o.blood_hu : 0.0;
  Mask bright;
  if (blood > 0.0) {
    bright.size = ct.size;
    bright.inside.resize(bone.inside.size());
    for (std::size_t i = 0; i < bright.inside.size(); ++i) {
      bright.inside[i] = bone.inside[i] || (body.inside[i] && ct.values[i] > blood);
    }
  }
  const Mask& pool = blood > 0.0 ? bright : bone;
  const double core_radius = ct.hounsfield ? o.vessel_core_radius : o.raw_vessel_core_radius;
  const Mask thick = ThickParts(ct, pool, core_radius);
  std::vector<int> labels;
  const auto blobs = ConnectedComponents(ct, thick, &labels);
  const int steps =
      std::max(1, static_cast<int>(std::lround(core_radius / ct.spacing().minCoeff())));
  // Rims grow through blood, never into cortical bone (a rib or the sternum against the heart).
  const double cortex_level = ct.hounsfield ? o.cortical_hu : HUGE_VAL;
  Grow(ct, &labels, steps,
       [&](long n) { return pool.inside[n] && !thick.inside[n] && ct.values[n] <= cortex_level; });
  {
    Mask rimmed;
    rimmed.size = ct.size;
    rimmed.inside.resize(labels.size());
    for (long v = 0; v < static_cast<long>(labels.size()); ++v) rimmed.inside[v] = labels[v] != 0;
    *axis = FindSpineAxis(ct, body, bone, rimmed, slices, o);
  }
  std::vector<long> in_column(blobs.size() + 1, 0), size(blobs.size() + 1, 0),
      cortical(blobs.size() + 1, 0);
  const double cortex = ct.hounsfield ? o.cortical_hu : o.raw_cortical;
  // The shell test needs the cortex in the blob: grow the bone blobs' rims once more through it.
  Grow(ct, &labels, 2, [&](long n) { return pool.inside[n] && ct.values[n] > cortex_level; });
  for (int k = 0; k < ct.size.z(); ++k) {
    for (int j = 0; j < ct.size.y(); ++j) {
      for (int i = 0; i < ct.size.x(); ++i) {
        const long v = ct.Index(i, j, k);
        if (labels[v] == 0) continue;
        const Eigen::Vector3d p = ct.PatientPoint(i, j, k);
        in_column[labels[v]] += InColumn(*axis, slices.Of(p.z()), p, o);
        cortical[labels[v]] += ct.values[v] > cortex;
        ++size[labels[v]];
      }
    }
  }
  std::vector<std::uint8_t> is_vessel(blobs.size() + 1, 0);
  for (const Component& b : blobs) {
    // Cancellous bone (vertebral bodies, humeral heads, the pelvis) sits in a cortical shell;
    // blood does not (a calcified or stented wall only here and there).
    const bool shelled = cortical[b.label] > o.cortical_fraction * size[b.label];
    const bool spine = 2 * in_column[b.label] >= size[b.label];
    is_vessel[b.label] = cortex > 0.0 ? !shelled && !spine : !spine;
  }
  for (long v = 0; v < static_cast<long>(labels.size()); ++v) {
    vessels.inside[v] = labels[v] != 0 && is_vessel[labels[v]];
    thick_bone->inside[v] = labels[v] != 0 && !is_vessel[labels[v]] && thick.inside[v];
  }
  return vessels;
}

Mask Above(const Volume& ct, const Mask& body, double threshold) {
  Mask m;
  m.size = ct.size;
  m.inside.resize(ct.values.size());
  for (std::size_t i = 0; i < m.inside.size(); ++i)
    m.inside[i] = body.inside[i] && ct.values[i] > threshold;
  return m;
}

// A rib piece's course about the body's axis: per 3° bin of the angle (0 at the back, π/2 at the
// side, π at the front, mirrored for the right), its voxel count, mean height and radius.
constexpr int kProfileBins = 120;

double SideAngle(const Eigen::Vector2d& d, int side) {
  double a = std::atan2(side * d.x(), d.y());
  if (a < -0.5 * M_PI) a += 2.0 * M_PI;  // [-π/2, 3π/2): a rib's course does not wrap
  return a;
}
int ProfileBin(double angle) {
  return std::clamp(static_cast<int>((angle + 0.5 * M_PI) / (2.0 * M_PI) * kProfileBins), 0,
                    kProfileBins - 1);
}
double BinAngle(double b) { return (b + 0.5) * 2.0 * M_PI / kProfileBins - 0.5 * M_PI; }

struct RibProfile {
  std::vector<long> n = std::vector<long>(kProfileBins, 0);
  std::vector<double> z = std::vector<double>(kProfileBins, 0.0),
                      r = std::vector<double>(kProfileBins, 0.0);
  int first = kProfileBins, last = -1;
  bool Has(int b) const { return b >= 0 && b < kProfileBins && n[b] >= 2; }
  void Finish() {
    for (int b = 0; b < kProfileBins; ++b) {
      if (n[b] == 0) continue;
      z[b] /= static_cast<double>(n[b]);
      r[b] /= static_cast<double>(n[b]);
      if (!Has(b)) continue;
      first = std::min(first, b);
      last = std::max(last, b);
    }
  }
  // Height and radius at bin `b`, by a line through the populated bins at one end (the last
  // ones when `from_last`); with fewer than three, their mean.
  Eigen::Vector2d At(double b, bool from_last) const {
    std::vector<int> used;
    for (int t = from_last ? last : first; t >= first && t <= last && used.size() < 6;
         t += from_last ? -1 : 1) {
      if (Has(t)) used.push_back(t);
    }
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    double bm = 0.0;
    for (int t : used) {
      mean += Eigen::Vector2d(z[t], r[t]);
      bm += t;
    }
    mean /= static_cast<double>(used.size());
    bm /= static_cast<double>(used.size());
    if (used.size() < 3) return mean;
    Eigen::Vector2d cov = Eigen::Vector2d::Zero();
    double var = 0.0;
    for (int t : used) {
      cov += (t - bm) * (Eigen::Vector2d(z[t], r[t]) - mean);
      var += (t - bm) * (t - bm);
    }
    return mean + (b - bm) * cov / var;
  }
};

// Pieces of one rib joined: a crop face cuts a rib in two (its middle runs outside the scan),
// and a thin stretch below the threshold breaks it. Two pieces of one side are one rib when one
// ends where the other begins (at most two 3° bins of overlap), the stretch between them is
// outside the scan or at most `rib_break_angle` long with no other rib in it, and their ends,
// carried on by their own course, meet: heights within `rib_join_pitch` of the side's rib pitch,
// radii within `rib_join_radius`. The best matches join first; a piece joins at most one piece at
// each end. Labels of joined pieces are rewritten to the first piece's.
void JoinRibPieces(const Volume& ct, const Eigen::Vector2d& centre, const AnatomyOptions& o,
                   std::vector<int>* labels, std::vector<Component>* left,
                   std::vector<Component>* right, std::vector<std::string>* report) {
  int max_label = 0;
  for (const auto* ribs : {left, right}) {
    for (const Component& c : *ribs) max_label = std::max(max_label, c.label);
  }
  if (max_label == 0) return;
  std::vector<int> slot(max_label + 1, -1), side_of(max_label + 1, 0);
  std::vector<RibProfile> profile;
  for (int side : {+1, -1}) {
    for (const Component& c : *(side > 0 ? left : right)) {
      slot[c.label] = static_cast<int>(profile.size());
      side_of[c.label] = side;
      profile.emplace_back();
    }
  }
  for (int k = 0; k < ct.size.z(); ++k) {
    for (int j = 0; j < ct.size.y(); ++j) {
      for (int i = 0; i < ct.size.x(); ++i) {
        const int l = (*labels)[ct.Index(i, j, k)];
        if (l <= 0 || l > max_label || slot[l] < 0) continue;
        const Eigen::Vector3d p = ct.PatientPoint(i, j, k);
        const Eigen::Vector2d d = p.head<2>() - centre;
        RibProfile& f = profile[slot[l]];
        const int b = ProfileBin(SideAngle(d, side_of[l]));
        ++f.n[b];
        f.z[b] += p.z();
        f.r[b] += d.norm();
      }
    }
  }
  for (RibProfile& f : profile) f.Finish();
  auto in_scan = [&](const Eigen::Vector3d& p) {
    const Eigen::Vector3d ijk = ct.IndexOf(p);
    return (ijk.array() >= -0.5).all() &&
           (ijk.array() <= ct.size.cast<double>().array() - 0.5).all();
  };
  for (int side : {+1, -1}) {
    std::vector<Component>& ribs = *(side > 0 ? left : right);
    const int n = static_cast<int>(ribs.size());
    auto prof = [&](int r) -> const RibProfile& { return profile[slot[ribs[r].label]]; };
    // The rib pitch: the median height between pieces one above the other in a bin.
    std::vector<double> steps;
    for (int b = 0; b < kProfileBins; ++b) {
      std::vector<double> zs;
      for (int r = 0; r < n; ++r) {
        if (prof(r).Has(b)) zs.push_back(prof(r).z[b]);
      }
      std::sort(zs.begin(), zs.end());
      for (std::size_t t = 1; t < zs.size(); ++t) {
        if (zs[t] - zs[t - 1] > 0.004 && zs[t] - zs[t - 1] < o.max_rib_pitch)
          steps.push_back(zs[t] - zs[t - 1]);
      }
    }
    const double pitch = steps.empty() ? 0.025 : Median(&steps);
    const double tolerance = o.rib_join_pitch * pitch;
    struct Join {
      double score;
      int before, after;
    };
    std::vector<Join> joins;
    for (int a = 0; a < n; ++a) {
      for (int c = 0; c < n; ++c) {
        const RibProfile& P = prof(a);
        const RibProfile& Q = prof(c);
        if (a == c || P.last < 0 || Q.last < 0) continue;
        if (!(P.first < Q.first && P.last < Q.last && P.last - Q.first + 1 <= 2)) continue;
        const double mid = 0.5 * (P.last + Q.first);
        const Eigen::Vector2d end = P.At(mid, true), start = Q.At(mid, false);
        const double dz = std::abs(end.x() - start.x());
        if (dz > tolerance || std::abs(end.y() - start.y()) > o.rib_join_radius) continue;
        // The stretch between: out of the scan, or a short break with no other rib in it.
        double in_view = 0.0;
        bool blocked = false;
        for (int b = P.last + 1; b < Q.first; ++b) {
          const double t = (b - P.last) / static_cast<double>(Q.first - P.last);
          const double z = (1 - t) * P.At(P.last, true).x() + t * Q.At(Q.first, false).x();
          const double radius = (1 - t) * P.At(P.last, true).y() + t * Q.At(Q.first, false).y();
          const double angle = BinAngle(b);
          const Eigen::Vector2d xy =
              centre + radius * Eigen::Vector2d(side * std::sin(angle), std::cos(angle));
          if (!in_scan(Eigen::Vector3d(xy.x(), xy.y(), z))) continue;
          in_view += 2.0 * M_PI / kProfileBins;
          for (int r = 0; r < n; ++r) {
            blocked = blocked || (r != a && r != c && prof(r).Has(b) &&
                                  std::abs(prof(r).z[b] - z) < tolerance);
          }
        }
        if (blocked || in_view > o.rib_break_angle + 1e-9) continue;
        joins.push_back({dz / tolerance, a, c});
      }
    }
    std::sort(joins.begin(), joins.end(), [](const Join& x, const Join& y) {
      return x.score != y.score
                 ? x.score < y.score
                 : std::make_pair(x.before, x.after) < std::make_pair(y.before, y.after);
    });
    std::vector<int> next(n, -1), previous(n, -1);
    for (const Join& j : joins) {
      if (next[j.before] >= 0 || previous[j.after] >= 0) continue;
      next[j.before] = j.after;
      previous[j.after] = j.before;
    }
    std::vector<Component> kept;
    std::vector<int> relabel(max_label + 1, 0);
    int joined = 0;
    for (int r = 0; r < n; ++r) {
      if (previous[r] >= 0) continue;  // joined to the piece before it
      Component whole = ribs[r];
      Eigen::Vector3d sum = whole.centroid_P * static_cast<double>(whole.voxels);
      for (int t = next[r]; t >= 0; t = next[t]) {
        const Component& c = ribs[t];
        relabel[c.label] = whole.label;
        sum += c.centroid_P * static_cast<double>(c.voxels);
        whole.voxels += c.voxels;
        whole.volume += c.volume;
        whole.min_P = whole.min_P.cwiseMin(c.min_P);
        whole.max_P = whole.max_P.cwiseMax(c.max_P);
        ++joined;
      }
      whole.centroid_P = sum / static_cast<double>(whole.voxels);
      kept.push_back(whole);
    }
    if (joined == 0) continue;
    for (int& l : *labels) {
      if (l > 0 && l <= max_label && relabel[l] != 0) l = relabel[l];
    }
    ribs = std::move(kept);
    std::ostringstream s;
    s << (side > 0 ? "left" : "right")
      << " rib pieces joined across a crop face or a break: " << joined << " (rib pitch "
      << std::fixed << std::setprecision(0) << pitch * 1e3 << " mm)";
    report->push_back(s.str());
  }
}

// The sternum is a flat bar of marrow in a thin cortex, and on a coarse slice its cortex reads
// above the bone threshold only in pieces (lidc-idri-0001: its labelled sternum's median is
// 146 HU), so its holes are not closed and the ribs' fill finds none. Its cross-section in a slice
// is convex: a voxel that lies between the sternum's voxels along its row and along its column
// of the slice (both ends the same piece), inside the body, above `floor` and not in `vessels` (a
// contrast-filled vessel passing behind the manubrium between its joints), is its marrow.
long FillSternumSections(const Volume& ct, const Mask& body, const Mask& vessels,
                         const std::vector<std::uint8_t>& is_sternum, double floor,
                         std::vector<int>* labels, Mask* bone) {
  const int axis = AxialAxis(ct);
  const int u = axis == 0 ? 1 : 0, w = axis == 2 ? 1 : 2;
  const long stride[3] = {1, ct.size.x(), static_cast<long>(ct.size.x()) * ct.size.y()};
  const int nu = ct.size[u], nw = ct.size[w];
  auto sternum_at = [&](long v) {
    const int l = (*labels)[v];
    return l > 0 && l < static_cast<int>(is_sternum.size()) && is_sternum[l] ? l : 0;
  };
  // Per row (fixed b) and per column (fixed a) of a slice: the first and last sternum voxel and
  // their label (0 when the two ends differ or there is none).
  struct Span {
    int lo = 0, hi = -1, label = 0;
  };
  std::vector<Span> rows(nw), cols(nu);
  long filled = 0;
  for (int s = 0; s < ct.size[axis]; ++s) {
    const long base = s * stride[axis];
    auto at = [&](int a, int b) { return base + a * stride[u] + b * stride[w]; };
    bool any = false;
    std::fill(rows.begin(), rows.end(), Span{});
    std::fill(cols.begin(), cols.end(), Span{});
    auto extend = [](Span* span, int i, int l) {
      if (span->hi < span->lo) {
        *span = {i, i, l};
      } else {
        span->hi = i;
        if (span->label != l) span->label = 0;
      }
    };
    for (int b = 0; b < nw; ++b) {
      for (int a = 0; a < nu; ++a) {
        const int l = sternum_at(at(a, b));
        if (l == 0) continue;
        any = true;
        if (rows[b].hi < rows[b].lo || rows[b].label == l || rows[b].label == 0)
          extend(&rows[b], a, l);
        extend(&cols[a], b, l);
      }
    }
    if (!any) continue;
    for (int b = 0; b < nw; ++b) {
      const Span& r = rows[b];
      if (r.label == 0) continue;
      for (int a = r.lo + 1; a < r.hi; ++a) {
        const Span& c = cols[a];
        if (c.label != r.label || b <= c.lo || b >= c.hi) continue;
        const long v = at(a, b);
        if ((*labels)[v] != 0 || !body.inside[v] || vessels.inside[v] || ct.values[v] <= floor)
          continue;
        (*labels)[v] = r.label;
        bone->inside[v] = 1;
        ++filled;
      }
    }
  }
  return filled;
}

// A rib is a cortical tube; its marrow lies below the bone threshold. In each slice, a hole a
// rib's cross-section encloses (4-connected voxels inside the body and above `floor`, bounded by
// that rib alone, at most `max_area` m²) is that rib's.
long FillRibMarrow(const Volume& ct, const Mask& body, const std::vector<std::uint8_t>& is_rib,
                   double floor, double max_area, std::vector<int>* labels, Mask* bone) {
  const int axis = AxialAxis(ct);
  const int u = axis == 0 ? 1 : 0, w = axis == 2 ? 1 : 2;
  const long stride[3] = {1, ct.size.x(), static_cast<long>(ct.size.x()) * ct.size.y()};
  const int nu = ct.size[u], nw = ct.size[w];
  const double cell = ct.index_to_P.col(u).norm() * ct.index_to_P.col(w).norm();
  const long cap = std::max<long>(1, static_cast<long>(max_area / cell));
  auto rib_at = [&](long v) {
    const int l = (*labels)[v];
    return l > 0 && l < static_cast<int>(is_rib.size()) && is_rib[l] ? l : 0;
  };
  // stamp: the slice a voxel of the plane was last reached in; open: it belongs to no hole (a
  // flood from it reached the slice's edge, the outside, air, other bone or the area cap). A
  // flood stops as soon as it is open, so the lungs beside the ribs are not flooded whole.
  std::vector<int> stamp(static_cast<std::size_t>(nu) * nw, -1);
  std::vector<std::uint8_t> open(static_cast<std::size_t>(nu) * nw, 0);
  std::vector<std::pair<int, int>> region, stack;
  long filled = 0;
  for (int s = 0; s < ct.size[axis]; ++s) {
    const long base = s * stride[axis];
    auto at = [&](int a, int b) { return base + a * stride[u] + b * stride[w]; };
    auto cell_of = [&](int a, int b) { return a + static_cast<std::size_t>(nu) * b; };
    for (int b = 0; b < nw; ++b) {
      for (int a = 0; a < nu; ++a) {
        if (rib_at(at(a, b)) == 0) continue;
        const int da[4] = {1, -1, 0, 0}, db[4] = {0, 0, 1, -1};
        for (int d = 0; d < 4; ++d) {
          const int a0 = a + da[d], b0 = b + db[d];
          if (a0 < 0 || b0 < 0 || a0 >= nu || b0 >= nw) continue;
          const long v0 = at(a0, b0);
          if ((*labels)[v0] != 0 || stamp[cell_of(a0, b0)] == s) continue;
          // Flood the hole, noting the ribs around it.
          region.clear();
          stack.assign(1, {a0, b0});
          stamp[cell_of(a0, b0)] = s;
          open[cell_of(a0, b0)] = 0;
          int around = 0;
          bool hole = true;
          while (hole && !stack.empty()) {
            const auto [p, q] = stack.back();
            stack.pop_back();
            region.emplace_back(p, q);
            const long v = at(p, q);
            if (!body.inside[v] || ct.values[v] <= floor || static_cast<long>(region.size()) > cap)
              hole = false;
            for (int e = 0; e < 4 && hole; ++e) {
              const int p1 = p + da[e], q1 = q + db[e];
              if (p1 < 0 || q1 < 0 || p1 >= nu || q1 >= nw) {
                hole = false;
                break;
              }
              const long v1 = at(p1, q1);
              if ((*labels)[v1] != 0) {
                const int r = rib_at(v1);
                if (r == 0 || (around != 0 && around != r)) hole = false;
                around = r;
                continue;
              }
              const std::size_t c1 = cell_of(p1, q1);
              if (stamp[c1] == s) {
                if (open[c1]) hole = false;
                continue;
              }
              stamp[c1] = s;
              open[c1] = 0;
              stack.emplace_back(p1, q1);
            }
          }
          if (!hole) {
            for (const auto& [p, q] : region) open[cell_of(p, q)] = 1;
            for (const auto& [p, q] : stack) open[cell_of(p, q)] = 1;
            continue;
          }
          if (around == 0) continue;
          for (const auto& [p, q] : region) {
            const long v = at(p, q);
            (*labels)[v] = around;
            bone->inside[v] = 1;
            ++filled;
          }
        }
      }
    }
  }
  return filled;
}

// One sorting of the bone (ClassifyBones: with the vessel core of `o`), as numbered stages over
// the state they share: (1) contrast-filled heart and vessels taken out and the threshold
// adapted, (2) the bone's pieces sorted into ribs, sternum, spine and the rest, (3) the rib cage
// kept to its one layer, (4) the ribs, sternum and spine grown into their marrow and measured,
// (5) one rib's pieces joined and the stack of ribs kept, (6) the ribs numbered per side.
struct BoneSorting {
  BoneSorting(const Volume& ct, Segmentation* seg, const AnatomyOptions& o, double min_bone_volume)
      : ct(ct),
        seg(seg),
        o(o),
        min_bone_volume(min_bone_volume),
        slices(ct),
        centre(0.5 * (seg->body_min_P + seg->body_max_P).head<2>()),
        half_width(0.5 * (seg->body_max_P.x() - seg->body_min_P.x())),
        voxel_volume(std::abs(ct.index_to_P.determinant())),
        bone(seg->bone),
        parts(seg->bones) {
    parts = BoneParts{};
  }
  void Run() {
    SeparateContrast();
    SortPieces();
    KeepToTheLayer();
    GrowAndMeasure();
    JoinRibs();
    KeepCollarbonesOut();
    NumberRibs();
  }

  void SeparateContrast() {
    // 1. Contrast-filled heart and vessels; the bone threshold adapted to the scan: the lowest of
    //    the plain thresholds at which no blood shows above it, else the contrast threshold with
    //    the vessels sorted out by their thickness.
    const long voxels_min_vessel = static_cast<long>(o.contrast_min_volume / voxel_volume);
    seg->vessels = FindVessels(ct, seg->body, bone, slices, o, &axis, &thick_bone);
    // The body's axis, that rays about it run from: the bounding box's centre, but left-right at
    // the spine's midline when the box's centre is more than `axis_box_offset` off it (a crop face
    // or an arm beside the body pulls the box aside; within it, the box is the steadier estimate).
    if (axis.any) {
      std::vector<double> xs;
      for (int s = 0; s < slices.count; ++s) {
        if (axis.known[s]) xs.push_back(axis.x[s]);
      }
      const double midline = Median(&xs);
      if (std::abs(midline - centre.x()) > o.axis_box_offset) centre.x() = midline;
    }
    seg->axis_P = centre;
    if (ct.hounsfield && !o.plain_bone_hu.empty() &&
        o.plain_bone_hu.front() < seg->bone_threshold) {
      // Contrast: a blood pool thick and bright enough to be found at all, beside the bone. Without
      // it, the plain threshold keeps thin ribs and coarse slices' partial-volume bone.
      long blood = 0, other = 0;
      const double t = o.plain_bone_hu.front();
      for (long v = 0; v < static_cast<long>(bone.inside.size()); ++v) {
        if (seg->vessels.inside[v]) {
          ++blood;
        } else if (seg->body.inside[v] && ct.values[v] > t) {
          ++other;
        }
      }
      seg->contrast = blood >= std::max<double>(voxels_min_vessel, o.contrast_bone_ratio * other);
      if (!seg->contrast) {
        std::ostringstream s;
        s << "no contrast-filled blood pool (" << Ml(blood * voxel_volume)
          << " of bright blobs off the bone): bone threshold " << t << " HU";
        seg->anatomy.push_back(s.str());
        seg->bone_threshold = t;
        bone = Above(ct, seg->body, t);
      }
    } else {
      seg->contrast = seg->vessels.count() >= voxels_min_vessel;
    }
    seg->shoulder.size = ct.size;
    seg->shoulder.inside.assign(bone.inside.size(), 0);
    {
      long count = 0;
      for (long v = 0; v < static_cast<long>(bone.inside.size()); ++v) {
        if (!seg->vessels.inside[v]) continue;
        bone.inside[v] = 0;
        ++count;
      }
      if (count > 0) {
        seg->anatomy.push_back(
            "contrast-filled heart or vessels brighter than the bone threshold: " +
            Ml(count * voxel_volume) + ", kept out of the bone");
      }
      seg->contrast_volume = count * voxel_volume;
    }

    // Enhanced or not (bone grows differently; bright pieces without a cortex can be contrast).
    plain = ct.hounsfield && !seg->contrast &&
            Unenhanced(ct, seg->body, seg->bone_threshold, o, &seg->anatomy);
  }

  void SortPieces() {
    // 2. Pieces: the spine's column and the rest, never joined (ribs are cut from the vertebrae at
    //    the column's edge).
    std::vector<std::uint8_t> region(bone.inside.size(), 0);
    for (int k = 0; k < ct.size.z(); ++k) {
      for (int j = 0; j < ct.size.y(); ++j) {
        for (int i = 0; i < ct.size.x(); ++i) {
          const long v = ct.Index(i, j, k);
          if (!bone.inside[v]) continue;
          const Eigen::Vector3d p = ct.PatientPoint(i, j, k);
          region[v] = InColumn(axis, slices.Of(p.z()), p, o) ? 2 : 1;
        }
      }
    }
    pieces = ConnectedComponents(ct, bone, &parts.labels, &region);
    kind.assign(pieces.size() + 1, 0);
    std::vector<long> column_voxels(pieces.size() + 1, 0), cortical_voxels(pieces.size() + 1, 0),
        seed_voxels(pieces.size() + 1, 0);
    const double cortex_hu = ct.hounsfield ? o.cortical_hu : HUGE_VAL;
    // Enhanced: the bone threshold lies within the blood's range; a bone piece holds a voxel above
    // the seed level (AnatomyOptions::enhanced_seed_hu).
    const bool seeded = ct.hounsfield && seg->contrast && o.enhanced_seed_hu > seg->bone_threshold;
    for (long v = 0; v < static_cast<long>(region.size()); ++v) {
      if (parts.labels[v] != 0 && region[v] == 2) ++column_voxels[parts.labels[v]];
      if (parts.labels[v] != 0 && ct.values[v] > cortex_hu) ++cortical_voxels[parts.labels[v]];
      if (parts.labels[v] != 0 && ct.values[v] > o.enhanced_seed_hu) ++seed_voxels[parts.labels[v]];
    }
    Release(&thick_bone.inside);
    Release(&region);
    // The body's front and back along the midline, per slice (±2 cm of the spine's line): the
    // sternum lies in the front wall.
    std::vector<double> wall_front(slices.count, HUGE_VAL), wall_back(slices.count, -HUGE_VAL);
    {
      const Eigen::Vector3d step_i = ct.index_to_P.col(0);
      for (int k = 0; k < ct.size.z(); ++k) {
        for (int j = 0; j < ct.size.y(); ++j) {
          const std::uint8_t* row = &seg->body.inside[ct.Index(0, j, k)];
          Eigen::Vector3d p = ct.PatientPoint(0, j, k);
          for (int i = 0; i < ct.size.x(); ++i, p += step_i) {
            if (!row[i]) continue;
            const int s = slices.Of(p.z());
            if (std::abs(p.x() - (axis.known[s] ? axis.x[s] : centre.x())) > 0.02) continue;
            wall_front[s] = std::min(wall_front[s], p.y());
            wall_back[s] = std::max(wall_back[s], p.y());
          }
        }
      }
    }
    double calcified_volume = 0.0, mediastinal_volume = 0.0, axial_volume = 0.0,
           unseeded_volume = 0.0;
    for (const Component& c : pieces) {
      if (c.volume < min_bone_volume) continue;
      // A fragment: the stubs the column leaves of a rib's neck or a process' tip.
      if ((c.volume < o.min_rib_volume || (c.max_P - c.min_P).norm() < o.min_rib_length) &&
          column_voxels[c.label] == 0) {
        continue;
      }
      const int s = slices.Of(c.centroid_P.z());
      if (column_voxels[c.label] > 0) {
        // A small piece of the column, detached and wholly in front of the vertebral bodies' back
        // wall (a centimetre ahead of the axis), is no vertebra: a calcified vessel wall (the
        // aorta lies against the vertebral bodies' front and left), kept out of the bone's
        // structures.
        // So is a larger one without a cortex (under `cortical_fraction` above `cortical_hu`) in an
        // enhanced scan: the contrast in an aorta too narrow to be found as a pool, pressed against
        // the vertebrae (in a plain one, coarse voxels blur a vertebral body's cortex below it).
        const bool ahead = axis.known[s] && c.max_P.y() < axis.y[s] - o.calcification_ahead;
        const bool shell =
            !ct.hounsfield ||
            cortical_voxels[c.label] > o.cortical_fraction * static_cast<double>(c.voxels);
        kind[c.label] = ahead && (c.volume < o.min_rib_volume || (!plain && !shell)) ? 0 : 3;
        if (kind[c.label] == 0) calcified_volume += c.volume;
        continue;
      }
      if (seeded && seed_voxels[c.label] == 0) {
        // No voxel above the seed level: contrast in a thin vessel, not a bone's cortex.
        unseeded_volume += c.volume;
        continue;
      }
      const double front = axis.known[s] ? axis.y[s] - o.spine_front : centre.y();
      const double mid_x = axis.known[s] ? axis.x[s] : centre.x();
      const bool midline = (c.min_P.x() < mid_x && c.max_P.x() > mid_x) ||
                           std::abs(c.centroid_P.x() - mid_x) < o.sternum_lateral * half_width;
      if (midline) {
        kind[c.label] = c.centroid_P.y() < front ? 2 : 3;
        // In front of the spine but behind the front wall: the mediastinum, where bright means
        // contrast in a vessel too narrow to be found as a pool (a narrow stretch of a dissected
        // aorta) or a calcification, never the sternum.
        if (kind[c.label] == 2 && wall_front[s] < wall_back[s] &&
            c.centroid_P.y() > wall_front[s] + o.sternum_wall * (wall_back[s] - wall_front[s])) {
          kind[c.label] = 0;
          mediastinal_volume += c.volume;
        }
      } else {
        const Eigen::Vector3d extent = c.max_P - c.min_P;
        const bool along_axis = extent.z() > o.max_rib_axial_ratio * extent.head<2>().maxCoeff();
        kind[c.label] = along_axis ? 0 : 1;
        if (along_axis) axial_volume += c.volume;
      }
    }
    if (unseeded_volume > 0.0) {
      std::ostringstream why;
      why << "bright pieces off the spine with no voxel above " << o.enhanced_seed_hu
          << " HU, no bone's cortex (contrast in thin vessels: coronary or mammary arteries): "
          << Ml(unseeded_volume) << ", not bone";
      seg->anatomy.push_back(why.str());
    }
    if (axial_volume > 0.0) {
      seg->anatomy.push_back(
          "bright tubes off the midline running along the body's axis, not around it like a rib "
          "(a mammary vessel with contrast, a calcified vessel wall): " +
          Ml(axial_volume) + ", not ribs");
    }

    if (mediastinal_volume > 0.0) {
      seg->anatomy.push_back(
          "bright pieces in the mediastinum, behind the front wall and ahead of the spine (narrow "
          "contrast-filled vessels, calcifications): " +
          Ml(mediastinal_volume) + ", not sternum");
    }
    if (calcified_volume > 0.0) {
      seg->anatomy.push_back(
          "bone-bright pieces in front of the vertebral bodies, apart from them (vessel-wall "
          "calcifications, small or without a cortex: contrast in a narrow aorta): " +
          Ml(calcified_volume) + ", kept out of the spine");
    }
  }

  void KeepToTheLayer() {
    // 3. Along the rays from the body's axis the rib cage is one layer: bone inside it (vessel-wall
    //    calcifications, bits beside the spine) is not rib, and bone outside it (shoulder blades
    //    behind the ribs, arms beside them, collarbones in front of the first ribs) is the shoulder
    //    girdle. Inner pieces are taken out first, so they cannot make the ribs look outside.
    {
      constexpr int kBins = 120;  // 3° each
      const int cells = slices.count * kBins;
      auto cell_of = [&](const Eigen::Vector3d& p, double* r) {
        const Eigen::Vector2d d = p.head<2>() - centre;
        *r = d.norm();
        const double angle = std::atan2(d.y(), d.x()) + M_PI;
        const int b = std::min(kBins - 1, static_cast<int>(angle / (2 * M_PI) * kBins));
        return slices.Of(p.z()) * kBins + b;
      };
      // The rib candidates' voxels with their cell and radius, gathered once (a few per mille of
      // the scan): the passes below run over them, not over the whole grid.
      struct RayVoxel {
        int label, cell;
        float r;
      };
      std::vector<RayVoxel> ray_voxels;
      for (int k = 0; k < ct.size.z(); ++k) {
        for (int j = 0; j < ct.size.y(); ++j) {
          const long row = ct.Index(0, j, k);
          for (int i = 0; i < ct.size.x(); ++i) {
            const int l = parts.labels[row + i];
            if (l == 0 || kind[l] != 1) continue;
            double r;
            const int cell = cell_of(ct.PatientPoint(i, j, k), &r);
            ray_voxels.push_back({l, cell, static_cast<float>(r)});
          }
        }
      }
      // Calls f(label, cell, r) for every voxel of a piece that is still a rib candidate.
      auto for_each_candidate = [&](const auto& f) {
        for (const RayVoxel& rv : ray_voxels) {
          if (kind[rv.label] == 1) f(rv.label, rv.cell, static_cast<double>(rv.r));
        }
      };
      // Per piece: the share of its voxels with another candidate beyond it by the gap along the
      // same ray (inner) or before it (outer), of all its voxels (`fraction`) and of those whose
      // ray meets another candidate first (`shared`, outer only).
      struct Layer {
        std::vector<double> fraction, shared, of_shared;
      };
      auto layer_fractions = [&](bool outer) {
        std::vector<float> r_ext(cells, outer ? HUGE_VALF : -HUGE_VALF);
        std::vector<int> owner(cells, 0);
        for_each_candidate([&](int l, int cell, double r) {
          if (outer ? r < r_ext[cell] : r > r_ext[cell]) {
            r_ext[cell] = static_cast<float>(r);
            owner[cell] = l;
          }
        });
        Layer layer;
        layer.fraction.assign(pieces.size() + 1, 0.0);
        layer.shared.assign(pieces.size() + 1, 0.0);
        layer.of_shared.assign(pieces.size() + 1, 0.0);
        for_each_candidate([&](int l, int cell, double r) {
          if (owner[cell] == l) return;
          layer.shared[l] += 1.0;
          if (outer ? r > r_ext[cell] + o.shoulder_gap : r < r_ext[cell] - o.shoulder_gap)
            layer.fraction[l] += 1.0;
        });
        for (const Component& c : pieces) {
          layer.of_shared[c.label] =
              layer.shared[c.label] > 0.0 ? layer.fraction[c.label] / layer.shared[c.label] : 0.0;
          layer.fraction[c.label] /= static_cast<double>(c.voxels);
          layer.shared[c.label] /= static_cast<double>(c.voxels);
        }
        return layer;
      };
      auto take_inner = [&](int as_kind) {
        const Layer inner = layer_fractions(false);
        bool any = false;
        for (const Component& c : pieces) {
          if (kind[c.label] == 1 && inner.fraction[c.label] > o.inner_fraction) {
            kind[c.label] = as_kind;
            any = true;
          }
        }
        return any;
      };
      // Until no piece moves: a piece taken out leaves the pieces behind it to be judged against
      // the ribs. An arm's cortex broken into strips along its length (a scan resampled, nearest
      // voxel, 20 degrees turned) has its strips in each other's shadow by less than the gap where
      // no rib crosses their rays; judged once, one 1-voxel strip through the whole scan stayed a
      // "rib" and the side lost its numbers.
      auto take_outer = [&] {
        for (bool moved = true; moved;) {
          moved = false;
          const Layer outer = layer_fractions(true);
          for (const Component& c : pieces) {
            // Outside: much of it behind other bone; or, where its rays meet other bone at all (a
            // long arm bone beside the chest meets ribs only in the slices they cross), mostly
            // behind it.
            const bool behind = outer.fraction[c.label] > o.shoulder_fraction ||
                                (outer.shared[c.label] >= o.shoulder_shared_min &&
                                 outer.of_shared[c.label] >= o.shoulder_of_shared);
            if (kind[c.label] == 1 && behind) {
              kind[c.label] = 4;
              moved = true;
            }
          }
        }
      };
      // Inside means inside the ribs, not inside the shoulder girdle: a first rib under its
      // collarbone and shoulder blade is taken out as "inside" at first (kind 5), and put back
      // once the girdle is known; the girdle is then looked for again with it in place.
      constexpr int kTentative = 5;
      if (take_inner(kTentative)) {
        take_outer();
        for (int& k : kind) k = k == kTentative ? 1 : k;
      }
      take_inner(kTentative);
      take_outer();
      double inner_volume = 0.0, shoulder_volume = 0.0;
      for (const Component& c : pieces) {
        if (kind[c.label] == kTentative) {
          kind[c.label] = 0;
          inner_volume += c.volume;
        }
        if (kind[c.label] == 4) shoulder_volume += c.volume;
      }
      if (inner_volume > 0.0) {
        seg->anatomy.push_back(
            "bone inside the rib cage (not rib; calcifications, bits beside the spine): " +
            Ml(inner_volume));
      }
      if (shoulder_volume > 0.0) {
        seg->anatomy.push_back("bone outside the rib cage (shoulder girdle, arms): " +
                               Ml(shoulder_volume) + ", kept out of the ribs");
      }
    }
  }

  void GrowAndMeasure() {
    // 4. Grow ribs, sternum and spine from their bright cortex into the marrow and rim.
    const double grow = !ct.hounsfield ? o.raw_grow : plain ? o.unenhanced_max_hu : o.grow_hu;
    const double grow_distance = plain ? o.plain_grow_distance : o.grow_distance;
    if (grow > 0.0 && grow_distance > 0.0) {
      for (long v = 0; v < static_cast<long>(parts.labels.size()); ++v) {
        const int l = parts.labels[v];
        if (l != 0 && (kind[l] == 0 || kind[l] == 4)) {
          if (kind[l] == 4) seg->shoulder.inside[v] = 1;
          parts.labels[v] = -l;  // kept, not grown from
        }
      }
      const int steps =
          std::max(1, static_cast<int>(std::lround(grow_distance / InPlaneSpacing(ct).mean())));
      std::vector<int> grown = parts.labels;
      for (int& l : grown) l = l > 0 ? l : 0;
      Grow(ct, &grown, steps, [&](long n) {
        return parts.labels[n] == 0 && seg->body.inside[n] && !seg->vessels.inside[n] &&
               ct.values[n] > grow;
      });
      for (long v = 0; v < static_cast<long>(grown.size()); ++v) {
        if (parts.labels[v] == 0 && grown[v] != 0) {
          parts.labels[v] = grown[v];
          bone.inside[v] = 1;
        }
        if (parts.labels[v] < 0) parts.labels[v] = -parts.labels[v];
      }
    } else {
      for (long v = 0; v < static_cast<long>(parts.labels.size()); ++v) {
        const int l = parts.labels[v];
        if (l != 0 && kind[l] == 4) seg->shoulder.inside[v] = 1;
      }
    }

    // 4b. Marrow: the holes each rib's cross-section encloses in a slice are the rib's.
    if (ct.hounsfield && o.marrow_max_area > 0.0) {
      std::vector<std::uint8_t> is_rib(pieces.size() + 1, 0);
      for (const Component& c : pieces) is_rib[c.label] = kind[c.label] == 1;
      const long filled = FillRibMarrow(ct, seg->body, is_rib, o.marrow_floor_hu, o.marrow_max_area,
                                        &parts.labels, &bone);
      if (filled > 0)
        seg->anatomy.push_back("rib marrow enclosed by the cortex: " + Ml(filled * voxel_volume) +
                               ", taken into the ribs");
      std::vector<std::uint8_t> is_sternum(pieces.size() + 1, 0);
      for (const Component& c : pieces) is_sternum[c.label] = kind[c.label] == 2;
      const long sternal = FillSternumSections(ct, seg->body, seg->vessels, is_sternum,
                                               o.marrow_floor_hu, &parts.labels, &bone);
      if (sternal > 0)
        seg->anatomy.push_back("sternal marrow between its cortex's pieces in each slice: " +
                               Ml(sternal * voxel_volume) + ", taken into the sternum");
    }

    // Component statistics after growth.
    std::vector<Component> stats(pieces.begin(), pieces.end());
    {
      std::vector<long> n(pieces.size() + 1, 0);
      std::vector<Eigen::Vector3d> sum(pieces.size() + 1, Eigen::Vector3d::Zero());
      std::vector<Eigen::Vector3d> lo(pieces.size() + 1, Eigen::Vector3d::Constant(HUGE_VAL)),
          hi(pieces.size() + 1, Eigen::Vector3d::Constant(-HUGE_VAL));
      for (int k = 0; k < ct.size.z(); ++k) {
        for (int j = 0; j < ct.size.y(); ++j) {
          for (int i = 0; i < ct.size.x(); ++i) {
            const int l = parts.labels[ct.Index(i, j, k)];
            if (l == 0) continue;
            const Eigen::Vector3d p = ct.PatientPoint(i, j, k);
            ++n[l];
            sum[l] += p;
            lo[l] = lo[l].cwiseMin(p);
            hi[l] = hi[l].cwiseMax(p);
          }
        }
      }
      for (Component& c : stats) {
        if (n[c.label] == 0) continue;
        c.voxels = n[c.label];
        c.volume = n[c.label] * voxel_volume;
        c.centroid_P = sum[c.label] / static_cast<double>(n[c.label]);
        c.min_P = lo[c.label];
        c.max_P = hi[c.label];
      }
    }
    double lump_volume = 0.0;
    for (const Component& c : stats) {
      switch (kind[c.label]) {
        case 1: {
          // A rib is long and slender: a lump (a sacral wing, a transverse process) is not.
          const double length = (c.max_P - c.min_P).norm();
          if (c.volume > o.lump_volume &&
              length * length * length < o.min_rib_elongation * c.volume) {
            lump_volume += c.volume;
            break;
          }
          (c.centroid_P.x() > (axis.any ? axis.x[slices.Of(c.centroid_P.z())] : centre.x())
               ? parts.ribs_left
               : parts.ribs_right)
              .push_back(c);
          break;
        }
        case 2:
          parts.sternum.push_back(c);
          break;
        case 3:
          parts.spine.push_back(c);
          break;
        default:
          break;
      }
    }
    if (lump_volume > 0.0) {
      seg->anatomy.push_back(
          "bone lumps off the midline, not slender like a rib (transverse processes, the sacrum's "
          "wings, a scapula's edge): " +
          Ml(lump_volume));
    }
  }

  void JoinRibs() {
    // 5. Pieces of one rib (cut by a crop face, or broken) joined.
    JoinRibPieces(ct, centre, o, &parts.labels, &parts.ribs_left, &parts.ribs_right, &seg->anatomy);
    // 5b. One stack of ribs: pieces far above or below the stack of most ribs are not ribs.
    {
      struct Span {
        double lo, hi, volume;
        int pieces;
      };
      std::vector<Span> spans;
      for (const auto* ribs : {&parts.ribs_left, &parts.ribs_right}) {
        for (const Component& c : *ribs) spans.push_back({c.min_P.z(), c.max_P.z(), c.volume, 1});
      }
      std::sort(spans.begin(), spans.end(),
                [](const Span& a, const Span& b) { return a.lo < b.lo; });
      Span best{0.0, 0.0, -1.0, 0};
      for (std::size_t a = 0; a < spans.size();) {
        Span stack = spans[a];
        std::size_t b = a + 1;
        for (; b < spans.size() && spans[b].lo <= stack.hi + o.rib_stack_gap; ++b) {
          stack.hi = std::max(stack.hi, spans[b].hi);
          stack.volume += spans[b].volume;
          ++stack.pieces;
        }
        if (std::make_pair(stack.pieces, stack.volume) > std::make_pair(best.pieces, best.volume))
          best = stack;
        a = b;
      }
      double apart = 0.0;
      for (auto* ribs : {&parts.ribs_left, &parts.ribs_right}) {
        ribs->erase(std::remove_if(ribs->begin(), ribs->end(),
                                   [&](const Component& c) {
                                     const bool out = c.max_P.z() < best.lo - 1e-9 ||
                                                      c.min_P.z() > best.hi + 1e-9;
                                     if (out) apart += c.volume;
                                     return out;
                                   }),
                    ribs->end());
      }
      if (apart > 0.0) {
        seg->anatomy.push_back(
            "rib-like bone apart from the stack of ribs (more than " +
            std::to_string(static_cast<int>(std::lround(o.rib_stack_gap * 1e3))) +
            " mm above or below it: a femur, the sacrum, lumbar processes): " + Ml(apart) +
            ", not ribs");
      }
    }
    auto by_height = [](const Component& a, const Component& b) {
      return a.centroid_P.z() > b.centroid_P.z();
    };
    std::sort(parts.ribs_left.begin(), parts.ribs_left.end(), by_height);
    std::sort(parts.ribs_right.begin(), parts.ribs_right.end(), by_height);
  }

  void KeepCollarbonesOut() {
    // 5c. A rib articulates with its vertebra; a collarbone, from the manubrium to the shoulder,
    //     comes nowhere near the spine. Lying over the first rib, it is taken for the highest rib
    //     when the layer along the rays does not show it outside (arms raised turn it up beside
    //     the rib): it then blocks the rib-1 anchor, and the "space" between it and rib 1 is
    //     offered as a port. A piece above the second one that meets the spine (at the first
    //     rib's height or above) whose nearest approach to the spine exceeds the median of the
    //     side's pieces by more than `collarbone_spine_excess` is a collarbone, where the side's
    //     ribs meet the spine at all (their median within `rib_spine_reach`).
    // A collarbone meets the manubrium at its top: none is looked for without a sternum (a scan
    // cut below the collarbones, an abdomen, shows ribs' front ends cut off from their heads).
    if (parts.spine.empty() || parts.sternum.empty() || !(o.collarbone_spine_excess > 0.0)) return;
    double sternum_top = -HUGE_VAL;
    for (const Component& c : parts.sternum) sternum_top = std::max(sternum_top, c.max_P.z());
    int max_label = 0;
    for (const Component& c : parts.spine) max_label = std::max(max_label, c.label);
    for (const auto* ribs : {&parts.ribs_left, &parts.ribs_right})
      for (const Component& c : *ribs) max_label = std::max(max_label, c.label);
    // role: -1 spine, r + 1 for the r-th rib piece of `all`.
    std::vector<int> role(static_cast<std::size_t>(max_label) + 1, 0);
    for (const Component& c : parts.spine) role[c.label] = -1;
    std::vector<const Component*> all;
    for (const auto* ribs : {&parts.ribs_left, &parts.ribs_right}) {
      for (const Component& c : *ribs) {
        all.push_back(&c);
        role[c.label] = static_cast<int>(all.size());
      }
    }
    auto role_at = [&](long v) {
      const int l = parts.labels[v];
      return l > 0 && l <= max_label ? role[l] : 0;
    };
    // The spine's centroid in each slice (slices with a few of its voxels only).
    const int nz = ct.size.z();
    std::vector<Eigen::Vector2d> spine_sum(nz, Eigen::Vector2d::Zero());
    std::vector<long> spine_count(nz, 0);
    for (int k = 0; k < nz; ++k) {
      for (int j = 0; j < ct.size.y(); ++j) {
        for (int i = 0; i < ct.size.x(); ++i) {
          if (role_at(ct.Index(i, j, k)) != -1) continue;
          spine_sum[k] += ct.PatientPoint(i, j, k).head<2>();
          ++spine_count[k];
        }
      }
    }
    const long min_spine_voxels = std::max<long>(
        1, std::lround(2e-7 / voxel_volume));  // 0.2 ml: a slice through a vertebra holds more
    std::vector<double> approach(all.size(), HUGE_VAL);
    for (int k = 0; k < nz; ++k) {
      if (spine_count[k] < min_spine_voxels) continue;
      const Eigen::Vector2d spine = spine_sum[k] / static_cast<double>(spine_count[k]);
      for (int j = 0; j < ct.size.y(); ++j) {
        for (int i = 0; i < ct.size.x(); ++i) {
          const int r = role_at(ct.Index(i, j, k));
          if (r <= 0) continue;
          double& a = approach[static_cast<std::size_t>(r - 1)];
          a = std::min(a, (ct.PatientPoint(i, j, k).head<2>() - spine).norm());
        }
      }
    }
    auto approach_of = [&](const Component& c) { return approach[role[c.label] - 1]; };
    for (int side : {+1, -1}) {
      auto& ribs = side > 0 ? parts.ribs_left : parts.ribs_right;
      std::vector<double> finite;
      for (const Component& c : ribs)
        if (std::isfinite(approach_of(c))) finite.push_back(approach_of(c));
      if (finite.size() < 3) continue;
      const double median = Median(&finite);
      if (median > o.rib_spine_reach) continue;  // these ribs do not reach the spine in the scan
      // The pieces above the second one that meets the spine (highest first), at the first
      // rib's height or above, that do not meet it: collarbones.
      auto meets = [&](const Component& c) {
        return std::isfinite(approach_of(c)) &&
               approach_of(c) <= median + o.collarbone_spine_excess;
      };
      std::size_t second = 0;
      for (int seen = 0; second < ribs.size(); ++second) {
        if (meets(ribs[second]) && ++seen == 2) break;
      }
      std::vector<int> moved;
      double moved_volume = 0.0, farthest = 0.0;
      for (std::size_t r = 0; r < std::min(second, ribs.size()); ++r) {
        // ... rising to the manubrium's top or above it, toward the shoulder.
        if (meets(ribs[r]) || !std::isfinite(approach_of(ribs[r])) ||
            ribs[r].max_P.z() < sternum_top - o.collarbone_sternum_margin)
          continue;
        moved.push_back(ribs[r].label);
        moved_volume += ribs[r].volume;
        farthest = std::max(farthest, approach_of(ribs[r]));
        if (ribs[r].label < static_cast<int>(kind.size())) kind[ribs[r].label] = 4;
      }
      ribs.erase(std::remove_if(ribs.begin(), ribs.end(),
                                [&](const Component& c) {
                                  return std::find(moved.begin(), moved.end(), c.label) !=
                                         moved.end();
                                }),
                 ribs.end());
      if (moved.empty()) continue;
      for (long v = 0; v < static_cast<long>(parts.labels.size()); ++v) {
        const int l = parts.labels[v];
        if (l != 0 && std::find(moved.begin(), moved.end(), l) != moved.end())
          seg->shoulder.inside[v] = 1;
      }
      std::ostringstream s;
      s << moved.size() << " " << (side > 0 ? "left" : "right") << " rib-like piece"
        << (moved.size() == 1 ? "" : "s") << " at the first rib's height or above, up to "
        << std::lround(farthest * 1e3) << " mm from the spine where the side's ribs come within "
        << std::lround(median * 1e3) << " mm (median; a rib meets its vertebra): collarbone, "
        << Ml(moved_volume) << ", kept out of the ribs";
      seg->anatomy.push_back(s.str());
    }
  }

  void NumberRibs() {
    // 6. Numbering, per side: from rib 1 when the top of the rib cage is in view, from rib 12 when
    //    its bottom is (the spine going on below the lowest rib); both must agree.
    const double scan_top = slices.z_top, scan_bottom = slices.z0;
    double spine_bottom = HUGE_VAL;
    for (const Component& c : parts.spine) spine_bottom = std::min(spine_bottom, c.min_P.z());
    double sternum_top = -HUGE_VAL;
    for (const Component& c : parts.sternum) sternum_top = std::max(sternum_top, c.max_P.z());
    for (int side : {+1, -1}) {
      auto& ribs = side > 0 ? parts.ribs_left : parts.ribs_right;
      RibNumbering& n = side > 0 ? seg->numbering_left : seg->numbering_right;
      const std::string name = side > 0 ? "left" : "right";
      if (ribs.empty()) {
        n.basis = "no " + name + " rib found";
        continue;
      }
      const int count = static_cast<int>(ribs.size());
      const Component& top = ribs.front();
      const Component& bottom = ribs.back();
      // In view: no rib of this side reaches the scan's face there.
      double rib_top = -HUGE_VAL, rib_bottom = HUGE_VAL;
      for (const Component& c : ribs) {
        rib_top = std::max(rib_top, c.max_P.z());
        rib_bottom = std::min(rib_bottom, c.min_P.z());
      }
      const bool top_in_view = scan_top - rib_top >= o.top_margin;
      const bool bottom_in_view = rib_bottom - scan_bottom >= o.bottom_spine &&
                                  spine_bottom <= rib_bottom - o.bottom_spine &&
                                  bottom.min_P.z() <= rib_bottom + 1e-9;
      // Rib 1 meets the manubrium: the top rib's front end reaches the sternum's top.
      const bool meets_manubrium = !parts.sternum.empty() && top.min_P.z() <= sternum_top + 0.01 &&
                                   std::abs(top.max_P.z() - sternum_top) < 0.04;
      std::ostringstream why;
      int first = 0;  // number of ribs.front()
      if (top_in_view && bottom_in_view) {
        if (count == 12) {
          first = 1;
          n.confidence = 0.95;
          why << "12 " << name << " ribs between the top of the rib cage and the lumbar spine";
        } else {
          why << count << " " << name
              << " rib pieces between the top of the rib cage and the lumbar spine, not 12 "
              << "(ribs broken into pieces or joined): not numbered";
        }
      } else if (top_in_view && meets_manubrium) {
        first = 1;
        n.confidence = 0.8;
        why << "from the top of the rib cage (the highest " << name
            << " rib is rib 1, meeting the manubrium)";
      } else if (top_in_view) {
        why << "the top of the rib cage is in the scan but the highest " << name
            << " rib does not meet the manubrium (rib 1 not confirmed): not numbered";
      } else {
        // What was seen, not what it would mean: a rib piece near the top face is a cut cage's
        // top, or a collarbone or shoulder blade sorted with the ribs; either way rib 1 cannot
        // be told (issue #42: the import says why it names no space, truthfully).
        why << "the highest " << name << " rib piece reaches within "
            << std::lround(std::max(0.0, scan_top - rib_top) * 1e3)
            << " mm of the scan's top face (under " << std::lround(o.top_margin * 1e3)
            << " mm: the rib cage cut there, or a collarbone or shoulder blade taken for a rib), "
               "so rib 1 cannot be told; ";
        if (bottom_in_view)
          why << "counting up from the lowest " << name
              << " piece is not trusted (transverse processes and the pelvis can pass for ribs, "
                 "and 11 pairs occur): not numbered";
        else
          why << "nor is the bottom of the cage with the lumbar spine below it in the scan: not "
                 "numbered";
      }
      n.basis = why.str();
      n.numbered = first >= 1 && n.confidence >= 0.5 && first + count - 1 <= 12;
      if (n.numbered) {
        for (int r = 0; r < count; ++r) ribs[r].number = first + r;
      } else {
        n.confidence = 0.0;
      }
    }
    parts.numbered = seg->numbering_left.numbered || seg->numbering_right.numbered;
  }

  const Volume& ct;
  Segmentation* seg;
  const AnatomyOptions& o;
  const double min_bone_volume;
  const Slices slices;
  Eigen::Vector2d centre;  // the body's axis (x at the spine's midline when the box is off it)
  const double half_width;
  const double voxel_volume;
  Mask& bone;
  BoneParts& parts;
  SpineAxis axis;
  Mask thick_bone;
  bool plain = false;             // an unenhanced scan in HU
  std::vector<Component> pieces;  // of the bone, the column's apart
  std::vector<int> kind;          // per piece label: 0 none, 1 rib, 2 sternum, 3 spine, 4 shoulder
};

// One sorting of the bone (ClassifyBones: with the vessel core of `o`).
void ClassifyBonesOnce(const Volume& ct, Segmentation* seg, const AnatomyOptions& o,
                       double min_bone_volume) {
  BoneSorting(ct, seg, o, min_bone_volume).Run();
}

}  // namespace

void ClassifyBones(const Volume& ct, Segmentation* seg, const AnatomyOptions& o,
                   double min_bone_volume) {
  const double thin = o.raw_cortex_core_radius;
  if (ct.hounsfield) {
    // The state before sorting, but for the bone (taken again at the enhanced level if needed)
    // and the body (the sorting only reads it: not copied, a byte per voxel).
    Mask bone = std::move(seg->bone);
    Mask body = std::move(seg->body);
    Segmentation as_read = *seg;
    seg->bone = std::move(bone);
    seg->body = std::move(body);
    ClassifyBonesOnce(ct, seg, o, min_bone_volume);
    const double above = seg->bone_threshold;
    if (!seg->contrast || !seg->bones.sternum.empty() || seg->bones.ribs_left.empty() ||
        seg->bones.ribs_right.empty() || o.enhanced_bone_hu <= 0.0 || o.enhanced_bone_hu >= above)
      return;
    // Ribs on both sides: the scan covers the front of the chest, where the sternum lies. Its
    // thin cortex under the blood's brightest: sorted again from the enhanced level.
    body = std::move(seg->body);
    *seg = std::move(as_read);
    seg->body = std::move(body);
    seg->bone_threshold = o.enhanced_bone_hu;
    seg->bone = Above(ct, seg->body, o.enhanced_bone_hu);
    ClassifyBonesOnce(ct, seg, o, min_bone_volume);
    std::ostringstream why;
    why << "no sternum at the bone threshold (" << above << " HU, above the contrast-filled "
        << "blood), though ribs of both sides are: bone taken from " << o.enhanced_bone_hu
        << " HU (a coarse slice's thin cortex), thick blood sorted out by its thickness and "
        << "pieces without a voxel above " << o.enhanced_seed_hu << " HU by their lack of cortex";
    seg->anatomy.insert(seg->anatomy.begin(), why.str());
    return;
  }
  if (thin <= 0.0 || thin >= o.raw_vessel_core_radius) {
    ClassifyBonesOnce(ct, seg, o, min_bone_volume);
    return;
  }
  // A windowed volume: how its ribs read at the bone threshold decides how thick contrast is.
  // Sorted once with the default vessel core; when the ribs found hold a ball of `thin` almost
  // nowhere, only their cortex reaches the threshold (the marrow lies below it), so bone-bright
  // blobs that do hold one, off the spine's column, are no rib-like bone but contrast (an
  // injection's undiluted contrast in the arm's veins, the superior vena cava, the right heart):
  // sorted again with the thinner core.
  Segmentation as_read = *seg;
  ClassifyBonesOnce(ct, seg, o, min_bone_volume);
  std::vector<std::uint8_t> is_rib(
      seg->bones.labels.empty()
          ? 1
          : *std::max_element(seg->bones.labels.begin(), seg->bones.labels.end()) + 1,
      0);
  for (const auto* side : {&seg->bones.ribs_left, &seg->bones.ribs_right}) {
    for (const Component& c : *side) is_rib[c.label] = 1;
  }
  // Measured on cells of at least 1.4 mm (LIDC2's voxels): a share, not a mask to keep.
  const Mask thick = ThickParts(ct, seg->bone, thin, o.raw_cortex_cell);
  long rib_voxels = 0, thick_voxels = 0;
  for (long v = 0; v < static_cast<long>(seg->bones.labels.size()); ++v) {
    const int l = seg->bones.labels[v];
    if (l <= 0 || !is_rib[l]) continue;
    ++rib_voxels;
    thick_voxels += thick.inside[v];
  }
  if (rib_voxels == 0) return;
  const double share = static_cast<double>(thick_voxels) / static_cast<double>(rib_voxels);
  if (share >= o.raw_cortex_rib_share) {
    std::ostringstream why;
    why << "the ribs read solid (" << std::fixed << std::setprecision(1) << 100.0 * share
        << " % of their voxels hold a " << thin * 1e3 << " mm ball): contrast is what holds a "
        << o.raw_vessel_core_radius * 1e3 << " mm one";
    seg->anatomy.insert(seg->anatomy.begin(), why.str());
    return;
  }
  *seg = std::move(as_read);
  AnatomyOptions cortex = o;
  cortex.raw_vessel_core_radius = thin;
  ClassifyBonesOnce(ct, seg, cortex, min_bone_volume);
  std::ostringstream why;
  why << "the ribs read as their cortex only (" << std::fixed << std::setprecision(1)
      << 100.0 * share << " % of their voxels hold a " << thin * 1e3
      << " mm ball): bone-bright blobs that hold one, off the spine, are contrast-filled vessels";
  seg->anatomy.insert(seg->anatomy.begin(), why.str());
}

double KeepBoneBeyondTheLayerOutOfRibs(const Volume& ct, const LayerChart& chart, int side,
                                       const AnatomyOptions& o, Segmentation* seg) {
  std::vector<Component>& ribs = side > 0 ? seg->bones.ribs_left : seg->bones.ribs_right;
  const std::vector<double>& surface = side > 0 ? chart.surface_left : chart.surface_right;
  if (ribs.empty() || seg->bones.labels.empty() || chart.rows <= 0 || chart.cols <= 0 ||
      surface.size() != static_cast<std::size_t>(chart.rows) * chart.cols)
    return 0.0;
  std::map<int, int> rib_of_label;
  for (std::size_t r = 0; r < ribs.size(); ++r) rib_of_label[ribs[r].label] = static_cast<int>(r);
  const int n = static_cast<int>(ribs.size());
  // A voxel against the ribs' surface: -1 not judged (no surface there, or in the band behind
  // the spine, where the layer is the vertebrae's arches under the back's muscles), 0 within the
  // layer, 1 beyond it.
  const double spine_band = 2.0 * o.spine_half_width;
  auto judge = [&](long v) {
    const int i = static_cast<int>(v % ct.size.x());
    const int j = static_cast<int>((v / ct.size.x()) % ct.size.y());
    const int k = static_cast<int>(v / (static_cast<long>(ct.size.x()) * ct.size.y()));
    const Eigen::Vector3d p = ct.PatientPoint(i, j, k);
    const Eigen::Vector2d d = p.head<2>() - seg->axis_P;
    if (d.y() > 0.0 && std::abs(d.x()) < spine_band) return -1;
    const double angle = std::atan2(side * d.x(), d.y());  // 0 at the back, π at the front
    const long row = std::lround((chart.top_z - p.z()) / chart.dz);
    if (angle < 0.0 || row < 0 || row >= chart.rows) return -1;
    const int col = std::min(chart.cols - 1, static_cast<int>(angle / chart.bin));
    const double s = surface[row * chart.cols + col];
    if (std::isnan(s)) return -1;
    return d.norm() > s + chart.outside ? 1 : 0;
  };
  std::vector<long> judged(n, 0), beyond(n, 0);
  for (long v = 0; v < static_cast<long>(seg->bones.labels.size()); ++v) {
    const int label = seg->bones.labels[v];
    if (label <= 0) continue;
    const auto it = rib_of_label.find(label);
    if (it == rib_of_label.end()) continue;
    const int verdict = judge(v);
    if (verdict < 0) continue;
    ++judged[it->second];
    beyond[it->second] += verdict;
  }
  std::set<int> out_labels;
  for (int r = 0; r < n; ++r) {
    if (judged[r] >= o.layer_judged_share * static_cast<double>(ribs[r].voxels) &&
        beyond[r] > o.layer_beyond_share * static_cast<double>(judged[r]))
      out_labels.insert(ribs[r].label);
  }
  if (out_labels.empty()) return 0.0;
  if (seg->shoulder.inside.size() != seg->bones.labels.size()) {
    seg->shoulder.size = ct.size;
    seg->shoulder.inside.assign(seg->bones.labels.size(), 0);
  }
  // A piece outside goes to the girdle, but for what of it lies within the layer and is a rib
  // by itself (at least `min_rib_volume` and `min_rib_length`): a rib merged with its collarbone
  // or shoulder blade keeps its own bone.
  Mask within;
  within.size = ct.size;
  within.inside.assign(seg->bones.labels.size(), 0);
  int next_label = 0;
  for (long v = 0; v < static_cast<long>(seg->bones.labels.size()); ++v) {
    const int label = seg->bones.labels[v];
    next_label = std::max(next_label, std::abs(label));
    if (label <= 0 || out_labels.count(label) == 0) continue;
    within.inside[v] = judge(v) == 0;
    seg->bones.labels[v] = 0;
    seg->shoulder.inside[v] = 1;
  }
  std::vector<int> within_labels;
  const std::vector<Component> parts = ConnectedComponents(ct, within, &within_labels);
  std::vector<int> new_label(parts.size() + 1, 0);
  std::vector<Component> kept;
  for (const Component& c : parts) {
    if (c.volume < o.min_rib_volume || (c.max_P - c.min_P).norm() < o.min_rib_length) continue;
    Component rib = c;
    rib.label = ++next_label;
    new_label[c.label] = rib.label;
    kept.push_back(rib);
  }
  double kept_volume = 0.0;
  for (long v = 0; v < static_cast<long>(within_labels.size()); ++v) {
    const int l = within_labels[v];
    if (l == 0 || new_label[l] == 0) continue;
    seg->bones.labels[v] = new_label[l];
    seg->shoulder.inside[v] = 0;
  }
  double moved = 0.0;
  std::vector<Component> stay;
  for (const Component& c : ribs) {
    if (out_labels.count(c.label) != 0) {
      moved += c.volume;
    } else {
      stay.push_back(c);
    }
  }
  for (const Component& c : kept) {
    kept_volume += c.volume;
    stay.push_back(c);
  }
  std::stable_sort(stay.begin(), stay.end(), [](const Component& a, const Component& b) {
    return a.centroid_P.z() > b.centroid_P.z();
  });
  ribs = std::move(stay);
  std::ostringstream line;
  line << (side > 0 ? "left" : "right") << ": " << out_labels.size()
       << " rib-like piece(s) lying mostly outside the rib cage's layer (over "
       << std::lround(100.0 * o.layer_beyond_share) << " % of them further from the axis than "
       << "the ribs' surface by over " << std::lround(chart.outside * 1e3)
       << " mm: shoulder blade, collarbone, arm): " << Ml(moved - kept_volume)
       << ", kept out of the ribs";
  if (!kept.empty())
    line << " (" << kept.size() << " rib(s) within the layer kept from them: " << Ml(kept_volume)
         << ")";
  seg->anatomy.push_back(line.str());
  return moved - kept_volume;
}

}  // namespace trocar::patient
