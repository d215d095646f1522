#include "patient/segmentation.hpp"

#include <gtest/gtest.h>

#include <random>

#include "common/error.hpp"
#include "patient/phantom.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

using patient::Component;

double DistanceToCurve(const Eigen::Vector3d& p, const patient::Curve& curve) {
  double best = HUGE_VAL;
  for (std::size_t s = 0; s + 1 < curve.size(); ++s) {
    const Eigen::Vector3d a = curve[s], ab = curve[s + 1] - curve[s];
    const double t = std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
    best = std::min(best, (a + t * ab - p).norm());
  }
  return best;
}

// A phantom at 2.5 mm and its segmentation.
struct SegmentedPhantom {
  explicit SegmentedPhantom(unsigned seed)
      : ph(patient::GeneratePhantom([seed] {
          patient::PhantomParameters p;
          p.seed = seed;
          p.voxel_size = 0.0025;
          return p;
        }())),
        seg(patient::Segment(ph.ct)) {}
  patient::Phantom ph;
  patient::Segmentation seg;
};

// A plain 26-connected flood fill, voxel by voxel: the reference ConnectedComponents (which
// works on runs along x) must match exactly, labels and statistics.
std::vector<Component> FloodFill(const patient::Volume& grid, const patient::Mask& mask,
                                 std::vector<int>* labels,
                                 const std::vector<std::uint8_t>* region) {
  const Eigen::Vector3i& s = grid.size;
  labels->assign(mask.inside.size(), 0);
  std::vector<Component> found;
  std::vector<Eigen::Vector3d> sums;
  std::vector<Eigen::Vector3i> lo, hi;
  for (long start = 0; start < static_cast<long>(mask.inside.size()); ++start) {
    if (!mask.inside[start] || (*labels)[start] != 0) continue;
    found.emplace_back();
    const int label = static_cast<int>(found.size());
    sums.emplace_back(Eigen::Vector3d::Zero());
    lo.emplace_back(s);
    hi.emplace_back(-1, -1, -1);
    std::vector<long> stack{start};
    (*labels)[start] = label;
    while (!stack.empty()) {
      const long v = stack.back();
      stack.pop_back();
      const Eigen::Vector3i ijk(static_cast<int>(v % s.x()), static_cast<int>(v / s.x() % s.y()),
                                static_cast<int>(v / (static_cast<long>(s.x()) * s.y())));
      ++found.back().voxels;
      sums.back() += ijk.cast<double>();
      lo.back() = lo.back().cwiseMin(ijk);
      hi.back() = hi.back().cwiseMax(ijk);
      for (int dk = -1; dk <= 1; ++dk)
        for (int dj = -1; dj <= 1; ++dj)
          for (int di = -1; di <= 1; ++di) {
            const Eigen::Vector3i n = ijk + Eigen::Vector3i(di, dj, dk);
            if ((n.array() < 0).any() || (n.array() >= s.array()).any()) continue;
            const long w = grid.Index(n.x(), n.y(), n.z());
            if (!mask.inside[w] || (*labels)[w] != 0) continue;
            if (region != nullptr && (*region)[w] != (*region)[v]) continue;
            (*labels)[w] = label;
            stack.push_back(w);
          }
    }
  }
  std::vector<int> order(found.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
  std::stable_sort(order.begin(), order.end(),
                   [&](int a, int b) { return found[a].voxels > found[b].voxels; });
  std::vector<int> rank(found.size() + 1, 0);
  std::vector<Component> sorted;
  for (std::size_t r = 0; r < order.size(); ++r) {
    Component c = found[order[r]];
    rank[order[r] + 1] = static_cast<int>(r) + 1;
    c.label = static_cast<int>(r) + 1;
    const Eigen::Vector3d mean = sums[order[r]] / static_cast<double>(c.voxels);
    c.centroid_P = grid.PatientPoint(mean.x(), mean.y(), mean.z());
    c.min_P = grid.PatientPoint(lo[order[r]].x(), lo[order[r]].y(), lo[order[r]].z());
    c.max_P = grid.PatientPoint(hi[order[r]].x(), hi[order[r]].y(), hi[order[r]].z());
    sorted.push_back(c);
  }
  for (int& l : *labels) l = rank[l];
  return sorted;
}

// Over seeded random grids (sizes 1-23 per axis, densities from scattered specks through
// percolating tangles to nearly full, with and without regions that cut the mask), the run-based
// components equal the flood fill's: the same label at every voxel, the same order (largest
// first, ties by first voxel in raster order), voxel counts, centroids and bounds.
TEST(Segmentation, ConnectedComponentsEqualAPlainFloodFill) {
  std::mt19937 rng(17);
  int compared = 0, many = 0;
  for (int trial = 0; trial < 400; ++trial) {
    SCOPED_TRACE(trial);
    patient::Volume grid;
    std::uniform_int_distribution<int> n(1, 23);
    grid.size = Eigen::Vector3i(n(rng), n(rng), n(rng));
    grid.index_to_P = Eigen::Vector3d(0.001, 0.0015, 0.0025).asDiagonal();
    grid.origin_P = Eigen::Vector3d(-0.01, 0.02, -0.3);
    patient::Mask mask;
    mask.size = grid.size;
    const double density = std::uniform_real_distribution<double>(0.02, 0.95)(rng);
    std::bernoulli_distribution in(density);
    mask.inside.resize(grid.voxel_count());
    for (auto& v : mask.inside) v = in(rng);
    std::vector<std::uint8_t> region(mask.inside.size());
    const bool with_region = trial % 2 == 1;
    const int cut = std::uniform_int_distribution<int>(0, grid.size.x())(rng);
    for (long v = 0; v < grid.voxel_count(); ++v) {
      // Slabs along x (cuts inside runs) and scattered voxels of a third value.
      region[v] = static_cast<std::uint8_t>((v % grid.size.x() < cut) + (rng() % 7 == 0 ? 2 : 0));
    }
    std::vector<int> got, want;
    const auto a = patient::ConnectedComponents(grid, mask, &got, with_region ? &region : nullptr);
    const auto b = FloodFill(grid, mask, &want, with_region ? &region : nullptr);
    ASSERT_EQ(a.size(), b.size());
    ASSERT_EQ(got, want);
    for (std::size_t c = 0; c < a.size(); ++c) {
      EXPECT_EQ(a[c].label, b[c].label);
      EXPECT_EQ(a[c].voxels, b[c].voxels);
      EXPECT_NEAR(a[c].volume, b[c].voxels * 0.001 * 0.0015 * 0.0025, 1e-15);
      EXPECT_EQ(a[c].centroid_P, b[c].centroid_P);
      EXPECT_EQ(a[c].min_P, b[c].min_P);
      EXPECT_EQ(a[c].max_P, b[c].max_P);
    }
    ++compared;
    many += a.size() > 10;
  }
  EXPECT_EQ(compared, 400);
  EXPECT_GT(many, 50);  // the cases hold many components, not one blob each
}

TEST(Segmentation, FindsThePhantomsRibsWhereTheyWereMade) {
  for (unsigned seed : {1u, 2u}) {
    SCOPED_TRACE(seed);
    const SegmentedPhantom case_(seed);
    const patient::Phantom& ph = case_.ph;
    const patient::PhantomParameters& p = ph.parameters;
    const auto& seg = case_.seg;
    ASSERT_EQ(seg.bones.ribs_left.size(), 9u);
    ASSERT_EQ(seg.bones.ribs_right.size(), 9u);
    EXPECT_EQ(seg.bones.sternum.size(), 1u);
    // The spine: its vertebrae (apart at the discs, arches and processes per level), every piece
    // in the posterior midline where the phantom puts it.
    EXPECT_GE(seg.bones.spine.size(), 1u);
    for (const auto& c : seg.bones.spine) {
      EXPECT_LT(std::abs(c.centroid_P.x()), 0.01);
      EXPECT_GT(c.centroid_P.y(), 0.04);
    }
    const double h = p.voxel_size;
    for (int side : {+1, -1}) {
      const auto& found = side > 0 ? seg.bones.ribs_left : seg.bones.ribs_right;
      for (int r = 0; r < 9; ++r) {
        const auto& truth = ph.truth.ribs[(side > 0 ? 0 : 9) + r].centreline;
        // Every segmented voxel of rib r lies on the generated rib: within its radius plus two
        // voxels of the true centreline (the surfaces agree to two voxels).
        double worst = 0.0;
        for (long n = 0; n < static_cast<long>(seg.bones.labels.size()); ++n) {
          if (seg.bones.labels[n] != found[r].label) continue;
          const int i = int(n % ph.ct.size.x()), j = int((n / ph.ct.size.x()) % ph.ct.size.y());
          const int k = int(n / (long(ph.ct.size.x()) * ph.ct.size.y()));
          worst = std::max(worst, DistanceToCurve(ph.ct.PatientPoint(i, j, k), truth));
        }
        EXPECT_LT(worst, p.rib_radius + 2 * h) << "side " << side << " rib " << r;
        // And it is about as big as the generated rib (a tube of that radius and length).
        double length = 0;
        for (std::size_t s = 0; s + 1 < truth.size(); ++s) length += (truth[s + 1] - truth[s]).norm();
        const double tube = M_PI * p.rib_radius * p.rib_radius * length;
        EXPECT_NEAR(found[r].volume / tube, 1.0, 0.25) << "side " << side << " rib " << r;
      }
    }
    // The body holds the lungs (holes filled) and the heart, not the air around.
    auto inside_body = [&](const Eigen::Vector3d& point) {
      const Eigen::Vector3d ijk = ph.ct.IndexOf(point);
      return seg.body.inside[ph.ct.Index(int(std::lround(ijk.x())), int(std::lround(ijk.y())), int(std::lround(ijk.z())))] != 0;
    };
    EXPECT_TRUE(inside_body(ph.truth.heart_centre));
    EXPECT_TRUE(inside_body(Eigen::Vector3d(-0.09, 0.02, ph.truth.heart_centre.z())));  // lung
    EXPECT_FALSE(inside_body(ph.ct.PatientPoint(1, 1, 1)));
  }
}

TEST(Segmentation, Lidc2ChestRibCageSkinAndBone) {
  const std::string path = test::SharedDataPath("ct/lidc2/ct.nhdr");
  TROCAR_REQUIRE_SHARED_FILE(path);
  const patient::Volume ct = patient::LoadVolume(path);
  const auto seg = patient::Segment(ct);
  // Skin: the body spans an adult chest (about 0.3-0.4 m wide, 0.2-0.3 m deep).
  const Eigen::Vector3d extent = seg.body_max_P - seg.body_min_P;
  EXPECT_GT(extent.x(), 0.28);
  EXPECT_LT(extent.x(), 0.40);
  EXPECT_GT(extent.y(), 0.18);
  EXPECT_LT(extent.y(), 0.32);
  // Bone: a rib cage as wide as most of the chest, of adult volume, with ribs on both sides.
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(HUGE_VAL), hi = -lo;
  double bone_volume = 0;
  for (const auto* list : {&seg.bones.ribs_left, &seg.bones.ribs_right, &seg.bones.spine, &seg.bones.sternum}) {
    for (const Component& c : *list) {
      lo = lo.cwiseMin(c.min_P);
      hi = hi.cwiseMax(c.max_P);
      bone_volume += c.volume;
    }
  }
  EXPECT_GT(hi.x() - lo.x(), 0.75 * extent.x());
  EXPECT_GT(bone_volume, 0.1e-3);  // windowed 8-bit data keeps mostly the cortical shell
  EXPECT_LT(bone_volume, 3.0e-3);
  EXPECT_GE(seg.bones.ribs_left.size(), 3u);
  EXPECT_GE(seg.bones.ribs_right.size(), 3u);
}

// The CT with its table (what lies behind the back, outside `body`) moved toward the back until
// it touches it, and `overlap` voxels further.
patient::Volume WithTheTableRaisedToTheBack(const patient::Volume& ct, const patient::Mask& body,
                                            int overlap) {
  // The front-back index axis, and which way along it is posterior.
  int ay = 0;
  for (int a = 1; a < 3; ++a) {
    if (std::abs(ct.index_to_P(1, a)) > std::abs(ct.index_to_P(1, ay))) ay = a;
  }
  const int back = ct.index_to_P(1, ay) > 0 ? +1 : -1;
  // The table: what is above the body threshold behind the back (along each column of the
  // front-back axis, beyond the body's last voxel), outside the body. Its gap to the back: the
  // least over the columns (the table's top is curved).
  std::vector<std::uint8_t> table(ct.values.size(), 0);
  const int a0 = (ay + 1) % 3, a1 = (ay + 2) % 3;
  int gap = std::numeric_limits<int>::max();
  for (int p = 0; p < ct.size[a0]; ++p) {
    for (int q = 0; q < ct.size[a1]; ++q) {
      Eigen::Vector3i n;
      n[a0] = p;
      n[a1] = q;
      auto at = [&](int t) {
        n[ay] = back > 0 ? t : ct.size[ay] - 1 - t;  // t counts from the front
        return ct.Index(n.x(), n.y(), n.z());
      };
      int last_body = -1;
      for (int t = 0; t < ct.size[ay]; ++t)
        if (body.inside[at(t)]) last_body = t;
      if (last_body < 0) continue;
      for (int t = last_body + 1; t < ct.size[ay]; ++t) {
        const long v = at(t);
        if (ct.values[v] <= -400.0f) continue;
        if (!table[v]) gap = std::min(gap, t - last_body - 1);
        for (int u = t; u < ct.size[ay]; ++u)
          if (ct.values[at(u)] > -400.0f) table[at(u)] = 1;
        break;
      }
    }
  }
  // Up by the gap, and `overlap` voxels more.
  const int shift = gap + overlap;
  patient::Volume raised = ct;
  for (long v = 0; v < static_cast<long>(table.size()); ++v)
    if (table[v]) raised.values[v] = -1000.0f;  // air where the table was
  for (int k = 0; k < ct.size.z(); ++k)
    for (int j = 0; j < ct.size.y(); ++j)
      for (int i = 0; i < ct.size.x(); ++i) {
        const long v = ct.Index(i, j, k);
        if (!table[v]) continue;
        Eigen::Vector3i n(i, j, k);
        n[ay] -= back * shift;
        if (n[ay] < 0 || n[ay] >= ct.size[ay]) continue;
        float& to = raised.values[ct.Index(n.x(), n.y(), n.z())];
        to = std::max(to, ct.values[v]);
      }
  return raised;
}

// The real CT's table (its curved carbon shells, apart from the body under a mattress) raised
// until it meets the back, as when the patient lies on the table top: the segmentation leaves it
// out of the body, which is then the body of the CT as scanned. Without the rule the table joins
// the body and stretches it to the table's width.
TEST(Segmentation, ACtTableUnderTheBackIsLeftOutOfTheBody) {
  const std::string path = test::SharedDataPath("ct/totalseg-dicom-j2k/dicom");
  TROCAR_REQUIRE_SHARED_FILE(path);
  const patient::Volume ct = patient::LoadVolume(path);
  const patient::Segmentation apart = patient::Segment(ct);
  EXPECT_EQ(apart.body_table, "");
  // Under a sanitizer: the shell overlapping the skin by a voxel (test::Cases).
  for (int overlap : test::Cases<int>({0, 1}, {1})) {
    SCOPED_TRACE(overlap);
    const patient::Volume raised = WithTheTableRaisedToTheBack(ct, apart.body, overlap);
    patient::SegmentationOptions off;
    off.table_thickness = 0.0;
    const patient::Segmentation joined = patient::Segment(raised, off);
    // Without the rule the table is body: it is wider than the body and lies behind it.
    ASSERT_GT(joined.body_max_P.y() - apart.body_max_P.y(), 0.005);
    const patient::Segmentation seg = patient::Segment(raised);
    EXPECT_NE(seg.body_table, "");
    // The body as scanned: its bounds within 3 mm (four voxels: where the shell overlaps the
    // skin it is taken for skin), its voxels alike but where the table meets the back.
    EXPECT_LT((seg.body_min_P - apart.body_min_P).cwiseAbs().maxCoeff(), 0.003);
    EXPECT_LT((seg.body_max_P - apart.body_max_P).cwiseAbs().maxCoeff(), 0.003);
    long differ = 0, table_voxels = 0;
    for (std::size_t v = 0; v < seg.body.inside.size(); ++v) {
      differ += seg.body.inside[v] != apart.body.inside[v];
      table_voxels += joined.body.inside[v] && !apart.body.inside[v];
    }
    EXPECT_LT(differ, 0.005 * apart.body.count());
    EXPECT_LT(differ, 0.05 * table_voxels);
    // The table's shell reads as bone: none of it stays.
    const long table_bone = joined.bone.count() - apart.bone.count();
    EXPECT_GT(table_bone, 1000);
    EXPECT_LT(std::abs(seg.bone.count() - apart.bone.count()), 0.02 * table_bone);
  }
}

// Nothing of a body without a table is taken for one: over seeded phantoms with thin chest
// walls (no fat, 3-5 mm of muscle over the ribs: thinner than the ball, over the lungs), arms
// against the chest, and short scans (every piece of a short scan runs through all its slices),
// the body is voxel for voxel the body without the rule.
TEST(Segmentation, NothingIsTakenFromABodyWithoutATable) {
  std::mt19937 rng(17);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<patient::PhantomParameters> phantoms;
  for (int seed = 1; seed <= 6; ++seed) {
    patient::PhantomParameters p;
    p.seed = static_cast<unsigned>(seed);
    p.voxel_size = 0.003;
    p.slice_spacing = 0.003 + 0.002 * u(rng);
    p.shoulders = seed % 2 == 0;
    p.fat_thickness = p.shoulders ? 0.004 * u(rng) : 0.0;
    p.wall_thickness = p.shoulders ? 0.02 : 0.003 + 0.002 * u(rng);
    p.ribs_per_side = seed <= 3 ? 4 : 9;
    p.length = seed <= 3 ? 0.2 : 0.34;
    phantoms.push_back(p);
  }
  // Under a sanitizer: a short scan without shoulders and a long one with them (test::Cases).
  for (const patient::PhantomParameters& p : test::Cases(phantoms, {0, 3})) {
    SCOPED_TRACE(p.seed);
    const patient::Volume ct = patient::GeneratePhantom(p).ct;
    patient::SegmentationOptions off;
    off.table_thickness = 0.0;
    const patient::Segmentation with = patient::Segment(ct), without = patient::Segment(ct, off);
    EXPECT_EQ(with.body_table, "");
    EXPECT_TRUE(with.body.inside == without.body.inside);
  }
  // A chest wall 6 mm thin over a lung along the whole scan, which the phantom's walls (at
  // least 11 mm, ribs and pleura) never are: the lung is inside the body's outline, not outside.
  patient::Volume ct;
  ct.size = {120, 90, 40};
  ct.index_to_P = Eigen::Vector3d(0.002, 0.002, 0.003).asDiagonal();
  ct.origin_P = Eigen::Vector3d(-0.12, -0.09, 0.0);
  ct.hounsfield = true;
  ct.values.assign(static_cast<std::size_t>(ct.voxel_count()), -1000.0f);
  for (int k = 0; k < ct.size.z(); ++k) {
    for (int j = 0; j < ct.size.y(); ++j) {
      for (int i = 0; i < ct.size.x(); ++i) {
        const Eigen::Vector3d q = ct.PatientPoint(i, j, k);
        auto in = [&](double cx, double a, double b) {
          return std::pow((q.x() - cx) / a, 2) + std::pow(q.y() / b, 2) <= 1.0;
        };
        float& v = ct.values[ct.Index(i, j, k)];
        if (in(0.0, 0.11, 0.08)) v = 40.0f;
        if (in(0.05, 0.054, 0.06)) v = -850.0f;  // 6 mm of wall left of it
        if (std::abs(q.x()) < 0.01 && std::abs(q.y() - 0.05) < 0.01) v = 700.0f;  // a spine
      }
    }
  }
  patient::SegmentationOptions off;
  off.table_thickness = 0.0;
  off.shape_anatomy = false;
  patient::SegmentationOptions on = off;
  on.table_thickness = patient::SegmentationOptions{}.table_thickness;
  const patient::Segmentation with = patient::Segment(ct, on), without = patient::Segment(ct, off);
  EXPECT_EQ(with.body_table, "");
  EXPECT_TRUE(with.body.inside == without.body.inside);
}

// A windowed volume's body is filled to the convex hull of each slice (fat clipped to the value of
// air breaks the outline): over seeded star-shaped (non-convex) bodies, the filled slice is exactly
// the set of voxels inside or on the hull of the slice's voxels above the threshold, by a direct
// test of every voxel against every hull edge.
TEST(Segmentation, WindowedBodyIsTheConvexHullOfEachSlice) {
  for (unsigned seed = 1; seed <= 8; ++seed) {
    SCOPED_TRACE(seed);
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    patient::Volume ct;
    ct.size =
        Eigen::Vector3i(48 + static_cast<int>(rng() % 20), 40 + static_cast<int>(rng() % 20), 6);
    ct.index_to_P = Eigen::Vector3d(0.002, 0.002, 0.003).asDiagonal();
    ct.hounsfield = false;
    ct.values.assign(ct.voxel_count(), 0.0f);
    // A star: radius varying with the angle, deep notches included.
    std::vector<double> radius(12);
    for (double& r : radius) r = 5.0 + 15.0 * u(rng);
    const double ci = 0.5 * ct.size.x(), cj = 0.5 * ct.size.y();
    for (int k = 0; k < ct.size.z(); ++k) {
      for (int j = 0; j < ct.size.y(); ++j) {
        for (int i = 0; i < ct.size.x(); ++i) {
          const double a = std::atan2(j - cj, i - ci) + M_PI;
          const double f = a / (2 * M_PI) * 12.0;
          const int n = static_cast<int>(f) % 12;
          const double t = f - std::floor(f);
          const double r = (1 - t) * radius[n] + t * radius[(n + 1) % 12];
          if (std::hypot(i - ci, j - cj) <= r) ct.values[ct.Index(i, j, k)] = 100.0f;
        }
      }
    }
    patient::SegmentationOptions o;
    o.raw_body = 40;
    o.raw_bone = 160;
    o.raw_body_closing = 0.0;
    o.convex_fill_below = 1.01;  // always the convex fill (the choice is tested below)
    o.shape_anatomy = false;
    // No bone: Segment stops there with an error, after the body; the body is what is tested.
    for (int i = 0; i < 3; ++i)
      ct.values[ct.Index(static_cast<int>(ci) + i, static_cast<int>(cj), 2)] = 200.0f;
    const patient::Segmentation seg = patient::Segment(ct, o);
    const int k = 3;
    std::vector<Eigen::Vector2d> pts;
    for (int j = 0; j < ct.size.y(); ++j) {
      for (int i = 0; i < ct.size.x(); ++i) {
        if (ct.values[ct.Index(i, j, k)] > 40.0f) pts.emplace_back(i, j);
      }
    }
    // The hull by gift wrapping, independent of the library's monotone chain.
    std::vector<Eigen::Vector2d> hull;
    std::size_t start = 0;
    for (std::size_t n = 1; n < pts.size(); ++n) {
      if (pts[n].x() < pts[start].x() ||
          (pts[n].x() == pts[start].x() && pts[n].y() < pts[start].y()))
        start = n;
    }
    auto cross = [](const Eigen::Vector2d& o2, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
      return (a - o2).x() * (b - o2).y() - (a - o2).y() * (b - o2).x();
    };
    std::size_t p = start;
    do {
      hull.push_back(pts[p]);
      std::size_t q = (p + 1) % pts.size();
      for (std::size_t n = 0; n < pts.size(); ++n) {
        const double c = cross(pts[p], pts[q], pts[n]);
        if (c < 0 || (c == 0 && (pts[n] - pts[p]).norm() > (pts[q] - pts[p]).norm())) q = n;
      }
      p = q;
      ASSERT_LT(hull.size(), pts.size() + 1);
    } while (p != start);
    long differ = 0, filled = 0;
    for (int j = 0; j < ct.size.y(); ++j) {
      for (int i = 0; i < ct.size.x(); ++i) {
        bool inside = true;
        for (std::size_t e = 0; e < hull.size() && inside; ++e) {
          inside = cross(hull[e], hull[(e + 1) % hull.size()], Eigen::Vector2d(i, j)) >= -1e-9;
        }
        const bool got = seg.body.inside[ct.Index(i, j, k)] != 0;
        differ += got != inside;
        filled += got && ct.values[ct.Index(i, j, k)] <= 40.0f;
      }
    }
    EXPECT_EQ(differ, 0);
    EXPECT_GT(filled, 0);  // the notches were filled: a hole fill would not pass
  }
}

// Which fill a windowed body gets: a wheel whose rim is broken (a skin line with a gap, fat at the
// value of air inside it, a core joined by one spoke) leaves its inside open to the outside, and is
// filled to its convex hull; a body whose outline holds (the same wheel with its rim closed, and
// a notch between an "arm" and the "chest") keeps its holes' fill, the notch left out.
TEST(Segmentation, WindowedBodyIsFilledToItsHullOnlyWhereTheOutlineIsBroken) {
  for (const bool broken : {true, false}) {
    SCOPED_TRACE(broken);
    patient::Volume ct;
    ct.size = Eigen::Vector3i(60, 60, 5);
    ct.index_to_P = Eigen::Vector3d(0.003, 0.003, 0.003).asDiagonal();
    ct.hounsfield = false;
    ct.values.assign(ct.voxel_count(), 0.0f);
    long notch = -1;
    for (int k = 0; k < ct.size.z(); ++k) {
      for (int j = 0; j < ct.size.y(); ++j) {
        for (int i = 0; i < ct.size.x(); ++i) {
          const double r = std::hypot(i - 30.0, j - 30.0);
          const double a = std::atan2(j - 30.0, i - 30.0);
          const bool rim = r >= 22 && r <= 24 && !(broken && std::abs(a) < 0.3);
          const bool core = r <= 8;
          const bool spoke = std::abs(j - 30.0) <= 1 && i < 30 && r <= 23;
          // A notch in the rim's outside (between an arm and the chest), open outward.
          const bool arm =
              r > 24 && r <= 28 && std::abs(a - M_PI / 2) < 0.6 && std::abs(a - M_PI / 2) > 0.15;
          if (rim || core || spoke || arm || (!broken && r <= 24 && std::abs(a - M_PI / 2) < 0.6))
            ct.values[ct.Index(i, j, k)] = 100.0f;
          if (k == 2 && i == 30 && j == 55) notch = ct.Index(i, j, k);
        }
      }
    }
    ct.values[ct.Index(30, 30, 2)] = 200.0f;  // a little bone, so that Segment goes on
    patient::SegmentationOptions o;
    o.raw_body = 40;
    o.raw_bone = 160;
    o.raw_body_closing = 0.0;
    o.shape_anatomy = false;
    const patient::Segmentation seg = patient::Segment(ct, o);
    const long between = ct.Index(30 + 15, 30, 2);  // inside the rim, outside the core
    EXPECT_EQ(seg.body.inside[between], 1);         // filled either way
    EXPECT_EQ(seg.body.inside[notch], broken ? 1 : 0) << seg.body_fill;
    EXPECT_NE(seg.body_fill.find(broken ? "convex hull" : "holes filled"), std::string::npos)
        << seg.body_fill;
  }
}

TEST(Segmentation, HeartMaskResampledOntoTheCtHasAnAdultHeartsVolume) {
  const std::string ct_path = test::SharedDataPath("ct/totalseg-pulmonary/ct_cropped.nii.gz");
  const std::string mask_path = test::SharedDataPath("ct/totalseg-pulmonary/heart.nii.gz");
  TROCAR_REQUIRE_SHARED_FILE(mask_path);
  const patient::Volume ct = patient::LoadVolume(ct_path);
  const patient::Mask heart = patient::ResampleMask(patient::LoadVolume(mask_path), ct);
  const double ml = heart.count() * std::abs(ct.index_to_P.determinant()) * 1e6;
  EXPECT_GT(ml, 300.0);
  EXPECT_LT(ml, 1500.0);
  // A mask somewhere else entirely does not overlap.
  patient::Volume far = patient::LoadVolume(mask_path);
  far.origin_P += Eigen::Vector3d(5, 0, 0);
  EXPECT_THROW(patient::ResampleMask(far, ct), Error);
}

TEST(Segmentation, EmptyResultsAreErrorsNotEmptyModels) {
  patient::Volume air;
  air.size = Eigen::Vector3i(8, 8, 8);
  air.values.assign(512, -1000.0f);
  air.hounsfield = true;
  air.source = "air.nrrd";
  try {
    patient::Segment(air);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(std::string(e.what()), "air.nrrd: no voxel above the body threshold -400 HU: empty segmentation");
  }
  patient::Volume soft = air;
  soft.values.assign(512, 40.0f);
  EXPECT_THROW(patient::Segment(soft), Error);  // a body but no bone
}

}  // namespace
}  // namespace trocar

#include "patient/intercostal.hpp"

namespace trocar {
namespace {

TEST(IntercostalSpaces, FoundFromThePhantomsRibsLieBetweenTheRightRibs) {
  for (unsigned seed : {1u, 3u}) {
    SCOPED_TRACE(seed);
    const SegmentedPhantom case_(seed);
    const patient::Phantom& ph = case_.ph;
    const patient::PhantomParameters& p = ph.parameters;
    const auto& seg = case_.seg;
    patient::IntercostalOptions options;
    options.right = true;
    const auto spaces = patient::FindIntercostalSpaces(ph.ct, seg, options);
    ASSERT_EQ(spaces.size(), 16u);  // 8 a side
    for (const auto& space : spaces) {
      ASSERT_GE(space.skin.size(), 10u);
      const int truth_index = (space.side > 0 ? 0 : 8) + space.upper_rib;
      const auto& truth_curve = ph.truth.intercostal_spaces[truth_index];
      const auto& upper = ph.truth.ribs[(space.side > 0 ? 0 : 9) + space.upper_rib].centreline;
      const auto& lower = ph.truth.ribs[(space.side > 0 ? 0 : 9) + space.upper_rib + 1].centreline;
      for (std::size_t s = 0; s < space.skin.size(); ++s) {
        // On the skin, within three voxels of the generated intercostal mid-curve (rib edges and
        // the skin are found on the voxel grid, and the sloping ribs are sampled by polar angle
        // here but generated by ellipse angle)...
        EXPECT_LT(DistanceToCurve(space.skin[s], truth_curve), 3 * p.voxel_size) << "space " << truth_index;
        // ...and between the right ribs: below the upper rib, above the lower one, by at least
        // a rib radius, at the same angle.
        const Eigen::Vector3d& d = space.depth[s];
        double z_upper = 0, z_lower = 0, best_u = HUGE_VAL, best_l = HUGE_VAL;
        for (const auto& q : upper) {
          const double e = (q.head<2>() - d.head<2>()).norm();
          if (e < best_u) { best_u = e; z_upper = q.z(); }
        }
        for (const auto& q : lower) {
          const double e = (q.head<2>() - d.head<2>()).norm();
          if (e < best_l) { best_l = e; z_lower = q.z(); }
        }
        EXPECT_LT(d.z(), z_upper - p.rib_radius);
        EXPECT_GT(d.z(), z_lower + p.rib_radius);
      }
    }
  }
}

TEST(IntercostalSpaces, TooFewRibsIsAnError) {
  patient::PhantomParameters p;
  p.voxel_size = 0.004;
  const patient::Phantom ph = patient::GeneratePhantom(p);
  auto seg = patient::Segment(ph.ct);
  seg.bones.ribs_left.resize(1);
  EXPECT_THROW(patient::FindIntercostalSpaces(ph.ct, seg), Error);
}

}  // namespace
}  // namespace trocar
