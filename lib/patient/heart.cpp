// The heart from a contrast CT, and the distance transform it stands on.
#include <optional>
#include <algorithm>
#include <cmath>
#include <limits>

#include "common/error.hpp"
#include "patient/segmentation.hpp"

namespace trocar::patient {
namespace {

// 1-D squared distance transform of f (0 at sites, +inf elsewhere) with sample spacing h,
// Felzenszwalb & Huttenlocher (2012). d[q] = min_p (f[p] + h²(q - p)²).
void Transform1D(const float* f, int n, double h, float* d, std::vector<int>& v,
                 std::vector<double>& z) {
  const double h2 = h * h;
  const double inf = std::numeric_limits<double>::infinity();
  int k = -1;
  for (int q = 0; q < n; ++q) {
    if (!std::isfinite(f[q])) continue;
    if (k < 0) {
      k = 0;
      v[0] = q;
      z[0] = -inf;
      z[1] = inf;
      continue;
    }
    double s;
    while (true) {
      const int p = v[k];
      s = ((f[q] + h2 * q * q) - (f[p] + h2 * p * p)) / (2.0 * h2 * (q - p));
      if (s <= z[k] && k > 0) {
        --k;
      } else {
        break;
      }
    }
    if (s <= z[k]) {  // k == 0 and the new parabola dominates everywhere
      v[0] = q;
      z[0] = -inf;
      z[1] = inf;
      continue;
    }
    ++k;
    v[k] = q;
    z[k] = s;
    z[k + 1] = inf;
  }
  if (k < 0) {
    std::fill(d, d + n, std::numeric_limits<float>::infinity());
    return;
  }
  int j = 0;
  for (int q = 0; q < n; ++q) {
    while (z[j + 1] < q) ++j;
    const int p = v[j];
    d[q] = static_cast<float>(h2 * (q - p) * (q - p) + f[p]);
  }
}

}  // namespace

std::vector<float> SquaredDistanceToMask(const Volume& grid, const Mask& mask) {
  TROCAR_THROW_UNLESS(mask.size == grid.size, "distance transform: mask size "
                                                  << mask.size.transpose() << " is not the grid's "
                                                  << grid.size.transpose());
  const Eigen::Vector3d h = grid.spacing();
  std::vector<float> d(mask.inside.size());
  for (std::size_t n = 0; n < d.size(); ++n) {
    d[n] = mask.inside[n] ? 0.f : std::numeric_limits<float>::infinity();
  }
  const int nmax = grid.size.maxCoeff();
  const Eigen::Vector3i& s = grid.size;
  const long stride[3] = {1, s.x(), static_cast<long>(s.x()) * s.y()};
  {
    // Along x the input is binary: the squared distance to the nearest inside voxel of the line,
    // from one sweep each way (what the lower envelope gives for parabolas of height 0 or ∞).
    const double h2 = h.x() * h.x();
    const long lines = static_cast<long>(s.y()) * s.z();
#pragma omp parallel
    {
      std::vector<int> nearest(s.x());
#pragma omp for schedule(static)
      for (long line = 0; line < lines; ++line) {
        float* row = &d[line * s.x()];
        int last = -1;
        for (int q = 0; q < s.x(); ++q) {
          if (row[q] == 0.f) last = q;
          nearest[q] = last;
        }
        last = -1;
        for (int q = s.x() - 1; q >= 0; --q) {
          if (row[q] == 0.f) last = q;
          int p = nearest[q];
          if (last >= 0 && (p < 0 || last - q < q - p)) p = last;
          if (p >= 0) row[q] = static_cast<float>(h2 * (q - p) * (q - p));
        }
      }
    }
  }
  for (int axis = 1; axis < 3; ++axis) {
    const int a = 0, b = axis == 2 ? 1 : 2;
    // Lines along the axis are independent: split them over threads (exact, so the result does
    // not depend on the thread count).
    // Lines across x (y and z) are gathered kTile at a time from contiguous runs of x, which
    // keeps the strided reads in cache.
    constexpr int kTile = 16;
    const int tile = kTile;
#pragma omp parallel
    {
      std::vector<float> lines(static_cast<std::size_t>(kTile) * nmax), out(nmax);
      std::vector<int> v(nmax);
      std::vector<double> z(nmax + 1);
#pragma omp for schedule(static)
      for (int ib = 0; ib < s[b]; ++ib) {
        for (int ia0 = 0; ia0 < s[a]; ia0 += tile) {
          const int width = std::min(tile, s[a] - ia0);
          const long base = ia0 * stride[a] + ib * stride[b];
          for (int q = 0; q < s[axis]; ++q) {
            const float* from = &d[base + q * stride[axis]];
            for (int t = 0; t < width; ++t) lines[t * static_cast<std::size_t>(nmax) + q] = from[t * stride[a]];
          }
          for (int t = 0; t < width; ++t) {
            float* line = &lines[t * static_cast<std::size_t>(nmax)];
            Transform1D(line, s[axis], h[axis], out.data(), v, z);
            std::copy(out.begin(), out.begin() + s[axis], line);
          }
          for (int q = 0; q < s[axis]; ++q) {
            float* to = &d[base + q * stride[axis]];
            for (int t = 0; t < width; ++t) to[t * stride[a]] = lines[t * static_cast<std::size_t>(nmax) + q];
          }
        }
      }
    }
  }
  return d;
}

namespace {
template <typename T>
void ReleaseMemory(std::vector<T>* v) {
  std::vector<T>().swap(*v);
}
}  // namespace

Mask SegmentHeartFromContrast(const Volume& ct, const Segmentation& seg, const HeartOptions& o) {
  std::optional<Mask> heart = TrySegmentHeartFromContrast(ct, seg, o);
  const double blood = ct.hounsfield ? o.blood_hu : o.raw_blood;
  TROCAR_THROW_UNLESS(heart.has_value(),
                      ct.source << ": heart: no contrast-filled blood pool "
                                << (ct.hounsfield ? "above " : "above raw ") << blood
                                << " and thicker than " << 2 * o.opening_radius * 1e3
                                << " mm in the chest: no contrast detected. Give the heart as a mask "
                                   "file (patient.yaml heart.mask) or a label map (labels:), leave "
                                   "heart.contrast unset for an approximation from the mediastinum, "
                                   "or build without a heart (heart: {contrast: false}; plans will "
                                   "not avoid it)");
  return std::move(*heart);
}

std::optional<Mask> TrySegmentHeartFromContrast(const Volume& ct, const Segmentation& seg,
                                                const HeartOptions& o) {
  const double blood = ct.hounsfield ? o.blood_hu : o.raw_blood;
  const double soft = ct.hounsfield ? o.soft_hu : o.raw_soft;
  const double bone = seg.bone_threshold;
  // Strong contrast (pulmonary CT angiography) can be brighter than the bone threshold, and the
  // bone segmentation then holds blood too (in a heart-centred crop even sorted as "spine"):
  // exclude only the ribs. The spine stays out by where it lies (the back of the chest).
  std::vector<std::uint8_t> skeletal(seg.bones.labels.empty() ? 0 : 1 + *std::max_element(
                                         seg.bones.labels.begin(), seg.bones.labels.end()), 0);
  for (const auto* list : {&seg.bones.ribs_left, &seg.bones.ribs_right}) {
    for (const Component& c : *list) skeletal[c.label] = 1;
  }
  auto is_skeleton = [&](std::size_t n) {
    return !seg.bones.labels.empty() && seg.bones.labels[n] > 0 && skeletal[seg.bones.labels[n]];
  };
  const double blood_max = ct.hounsfield ? o.blood_max_hu : bone;
  Mask pool;
  pool.size = ct.size;
  pool.inside.assign(ct.values.size(), 0);
  for (std::size_t n = 0; n < ct.values.size(); ++n) {
    pool.inside[n] = seg.body.inside[n] && ct.values[n] > blood && ct.values[n] <= blood_max &&
                     !is_skeleton(n);
  }
  // Opening: the blood voxels deeper than the radius inside the pool...
  Mask not_pool = pool;
  for (auto& x : not_pool.inside) x = !x;
  std::vector<float> depth2 = SquaredDistanceToMask(ct, not_pool);
  const float r2 = static_cast<float>(o.opening_radius * o.opening_radius);
  Mask core;
  core.size = ct.size;
  core.inside.assign(ct.values.size(), 0);
  for (std::size_t n = 0; n < depth2.size(); ++n) core.inside[n] = depth2[n] > r2;
  ReleaseMemory(&depth2);  // a 512×512×300 CT: each of these whole-volume arrays is 300 MB
  ReleaseMemory(&not_pool.inside);
  std::vector<int> labels;
  const auto blobs = ConnectedComponents(ct, core, &labels);
  // ...whose largest blob in the chest (between the body's sides, in front of its back third)
  // is the chambers.
  const Eigen::Vector3d centre = 0.5 * (seg.body_min_P + seg.body_max_P);
  const Eigen::Vector3d extent = seg.body_max_P - seg.body_min_P;
  const Component* first = nullptr;
  for (const auto& blob : blobs) {
    const Eigen::Vector3d c = blob.centroid_P;
    if (std::abs(c.x() - centre.x()) < 0.3 * extent.x() &&
        c.y() < seg.body_min_P.y() + 0.7 * extent.y()) {
      first = &blob;
      break;  // largest first
    }
  }
  if (first == nullptr) return std::nullopt;  // no contrast-filled blood pool
  // The other chambers: blobs of some size around the first (septa and valves separate them).
  std::vector<std::uint8_t> keep(blobs.size() + 1, 0);
  for (const auto& blob : blobs) {
    // Vessels are long and thin; chambers are round: skip elongated blobs (the aorta's).
    const Eigen::Vector3d size = blob.max_P - blob.min_P;
    const bool tube = size.maxCoeff() > o.max_chamber_elongation * size.minCoeff();
    keep[blob.label] = blob.label == first->label ||
                       (!tube && blob.volume >= o.min_chamber_fraction * first->volume &&
                        (blob.centroid_P - first->centroid_P).norm() <= o.chamber_reach);
  }
  Mask chambers;
  chambers.size = ct.size;
  chambers.inside.assign(ct.values.size(), 0);
  for (std::size_t n = 0; n < labels.size(); ++n) chambers.inside[n] = labels[n] > 0 && keep[labels[n]];
  ReleaseMemory(&labels);
  ReleaseMemory(&core.inside);
  // Grow back within the pool (the closing half of the opening), then the wall into soft tissue.
  std::vector<float> from_core2 = SquaredDistanceToMask(ct, chambers);
  Mask heart_blood = chambers;
  for (std::size_t n = 0; n < from_core2.size(); ++n) {
    heart_blood.inside[n] = pool.inside[n] && from_core2[n] <= r2 * 1.0001f;
  }
  ReleaseMemory(&from_core2);
  ReleaseMemory(&chambers.inside);
  const std::vector<float> from_blood2 = SquaredDistanceToMask(ct, heart_blood);
  const float w2 = static_cast<float>(o.wall_thickness * o.wall_thickness);
  Mask heart = heart_blood;
  for (std::size_t n = 0; n < from_blood2.size(); ++n) {
    heart.inside[n] = heart_blood.inside[n] ||
                      (from_blood2[n] <= w2 && seg.body.inside[n] && !is_skeleton(n) &&
                       ct.values[n] > soft && ct.values[n] <= blood_max);
  }
  return heart;
}

Mask ApproximateHeartFromMediastinum(const Volume& ct, const Segmentation& seg,
                                     const HeartOptions& o) {
  const double soft = ct.hounsfield ? o.soft_hu : o.raw_soft;
  const double lung_below = ct.hounsfield ? -400.0 : 0.5 * soft;
  const long n_voxels = static_cast<long>(ct.values.size());
  const int nx = ct.size.x(), ny = ct.size.y(), nz = ct.size.z();
  // Lungs: air inside the body.
  Mask lung;
  lung.size = ct.size;
  lung.inside.assign(ct.values.size(), 0);
  for (long n = 0; n < n_voxels; ++n) lung.inside[n] = seg.body.inside[n] && ct.values[n] < lung_below;
  std::vector<int> lung_labels;
  const auto lung_parts = ConnectedComponents(ct, lung, &lung_labels);
  std::vector<std::uint8_t> big(lung_parts.size() + 2, 0);
  Eigen::Vector3d lung_centroid = Eigen::Vector3d::Zero();
  double lung_volume = 0.0;
  for (const auto& part : lung_parts) {
    if (part.volume < 0.1e-3) continue;  // a lung holds litres; 100 ml keeps both halves of a cut one
    big[part.label] = 1;
    lung_centroid += part.volume * part.centroid_P;
    lung_volume += part.volume;
  }
  TROCAR_THROW_UNLESS(lung_volume > 0.0, ct.source << ": heart: no contrast and no lungs found "
                                                      "(air inside the body) to place the "
                                                      "mediastinum by: give the heart as a mask "
                                                      "or a label map");
  lung_centroid /= lung_volume;
  for (long n = 0; n < n_voxels; ++n) lung.inside[n] = lung_labels[n] > 0 && big[lung_labels[n]];
  ReleaseMemory(&lung_labels);
  // The mediastinum: soft tissue with lung on both sides along its row (x), in front of the
  // lungs' centre (the heart lies forward; behind are the spine and the aorta's descent).
  Mask region;
  region.size = ct.size;
  region.inside.assign(ct.values.size(), 0);
  for (int k = 0; k < nz; ++k) {
    for (int j = 0; j < ny; ++j) {
      int first_lung = -1, last_lung = -1;
      for (int i = 0; i < nx; ++i) {
        if (lung.inside[ct.Index(i, j, k)]) {
          if (first_lung < 0) first_lung = i;
          last_lung = i;
        }
      }
      if (first_lung < 0) continue;
      for (int i = first_lung + 1; i < last_lung; ++i) {
        const long n = ct.Index(i, j, k);
        if (lung.inside[n] || !seg.body.inside[n] || seg.bone.inside[n]) continue;
        if (ct.values[n] <= soft) continue;  // fat, air
        if (ct.PatientPoint(i, j, k).y() > lung_centroid.y()) continue;  // behind: spine, aorta
        region.inside[n] = 1;
      }
    }
  }
  ReleaseMemory(&lung.inside);
  // The heart: the thickest part of it (opened by a 15 mm ball), the largest blob, grown back.
  const float r2 = 0.015f * 0.015f;
  Mask outside = region;
  for (auto& x : outside.inside) x = !x;
  std::vector<float> depth2 = SquaredDistanceToMask(ct, outside);
  ReleaseMemory(&outside.inside);
  Mask core;
  core.size = ct.size;
  core.inside.assign(ct.values.size(), 0);
  for (long n = 0; n < n_voxels; ++n) core.inside[n] = depth2[n] > r2;
  ReleaseMemory(&depth2);
  std::vector<int> labels;
  const auto blobs = ConnectedComponents(ct, core, &labels);
  TROCAR_THROW_UNLESS(!blobs.empty(), ct.source << ": heart: no contrast, and no soft tissue 3 cm "
                                                   "thick between the lungs to approximate it by: "
                                                   "give the heart as a mask or a label map");
  Mask heart;
  heart.size = ct.size;
  heart.inside.assign(ct.values.size(), 0);
  for (long n = 0; n < n_voxels; ++n) heart.inside[n] = labels[n] == blobs.front().label;
  ReleaseMemory(&labels);
  const std::vector<float> from_core2 = SquaredDistanceToMask(ct, heart);
  for (long n = 0; n < n_voxels; ++n) {
    heart.inside[n] = region.inside[n] && from_core2[n] <= r2 * 1.0001f;
  }
  return heart;
}

}  // namespace trocar::patient
