#include "patient/anatomy.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <regex>
#include <set>

#include "common/error.hpp"
#include "patient/intercostal.hpp"
#include "patient/label_map.hpp"
#include "patient/markups.hpp"
#include "patient/patient_model.hpp"
#include "patient/sanity.hpp"
#include "patient/segmentation.hpp"
#include "patient/stored_otherwise.hpp"
#include "patient/volume.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

using patient::LabelKind;

// Where each labelled structure's voxels went in trocar's classical segmentation.
struct Confusion {
  // key: label name; value: trocar class → voxels
  std::map<std::string, std::map<std::string, long>> counts;
  std::map<std::string, long> totals;
  std::map<std::string, std::vector<float>> hu;
};

std::string TrocarClassAt(const patient::Segmentation& seg, long v) {
  const int label = seg.bones.labels.empty() ? 0 : seg.bones.labels[v];
  if (label != 0) {
    for (int side : {+1, -1}) {
      const auto& ribs = side > 0 ? seg.bones.ribs_left : seg.bones.ribs_right;
      for (std::size_t r = 0; r < ribs.size(); ++r) {
        if (ribs[r].label == label) {
          const int n = ribs[r].number > 0 ? ribs[r].number : -static_cast<int>(r + 1);
          return std::string(side > 0 ? "ribL" : "ribR") + std::to_string(n);
        }
      }
    }
    for (const auto& c : seg.bones.sternum) {
      if (c.label == label) return "sternum";
    }
    for (const auto& c : seg.bones.spine) {
      if (c.label == label) return "spine";
    }
  }
  if (!seg.vessels.inside.empty() && seg.vessels.inside[v]) return "vessel";
  if (!seg.shoulder.inside.empty() && seg.shoulder.inside[v]) return "shoulder";
  if (seg.bone.inside[v]) return "bone-unsorted";
  return "-";
}

// `labels`: the label map resampled on the CT's grid (patient::ResampleLabels).
Confusion Compare(const patient::Volume& ct, const patient::Segmentation& seg,
                  const patient::LabelMap& map, const std::vector<int>& labels) {
  Confusion c;
  for (long v = 0; v < static_cast<long>(labels.size()); ++v) {
    if (labels[v] == 0) continue;
    const auto it = map.names.find(labels[v]);
    if (it == map.names.end()) continue;
    const auto kind = patient::ClassifyLabel(it->second).kind;
    if (kind == LabelKind::kOther) continue;
    ++c.totals[it->second];
    ++c.counts[it->second][TrocarClassAt(seg, v)];
    c.hu[it->second].push_back(ct.values[v]);
  }
  return c;
}

void Print(const Confusion& c) {
  for (const auto& [name, row] : c.counts) {
    auto h = c.hu.at(name);
    std::sort(h.begin(), h.end());
    auto pc = [&](double f) { return h[static_cast<std::size_t>(f * (h.size() - 1))]; };
    std::printf("%-28s %7ld [%4.0f %4.0f %4.0f %4.0f]:", name.c_str(), c.totals.at(name), pc(0.1),
                pc(0.5), pc(0.9), pc(0.99));
    for (const auto& [cls, n] : row)
      std::printf(" %s=%.0f%%", cls.c_str(), 100.0 * n / c.totals.at(name));
    std::printf("\n");
  }
}

TEST(ShapeAnatomy, ContrastIsNeverBoneAndArmsAreNeverRibsOnLabelledRealCts) {
  struct Case {
    const char* ct;
    const char* labels;
  };
  // Under a sanitizer: the contrast crop and the abdomen (test::Cases); the DICOM series' CT is
  // segmented instrumented in Segmentation.ACtTableUnderTheBackIsLeftOutOfTheBody.
  for (const Case& k : test::Cases<Case>(
           {Case{"ct/totalseg-cta-aorta/ct_cropped.nii.gz",
                 "ct/totalseg-cta-aorta/DERIVED_labels_tsv2ids_on_aorta_crop.nii.gz"},
            Case{"ct/totalseg-dicom-j2k/dicom", "ct/totalseg-dicom-j2k/example_seg_dicom.nii.gz"},
            Case{"ct/totalseg-abdomen/example_ct.nii.gz",
                 "ct/totalseg-abdomen/example_seg_fast_force_split.nii.gz"}},
           {0, 2})) {
    const std::string ct_path = test::SharedDataPath(k.ct);
    TROCAR_REQUIRE_SHARED_FILE(ct_path);
    const patient::Volume ct = patient::LoadVolume(ct_path);
    patient::SegmentationOptions options;
    options.shape_anatomy = true;
    const auto seg = patient::Segment(ct, options);
    const auto map = patient::LoadLabelMap(test::SharedDataPath(k.labels));
    std::printf("== %s\n", k.ct);
    const Confusion c = Compare(ct, seg, map, patient::ResampleLabels(map, ct));
    Print(c);
    // Contrast-filled heart and aorta are vessels, never bone; no arm bone among the ribs.
    for (const auto& [name, row] : c.counts) {
      const auto kind = patient::ClassifyLabel(name).kind;
      long in_bone = 0, in_ribs = 0;
      for (const auto& [cls, n] : row) {
        if (cls.rfind("rib", 0) == 0 || cls == "sternum" || cls == "spine") in_bone += n;
        if (cls.rfind("rib", 0) == 0) in_ribs += n;
      }
      const double total = static_cast<double>(c.totals.at(name));
      if (name == "heart") {
        EXPECT_LT(in_bone / total, 0.01) << k.ct;
      }
      if (name == "aorta") {
        EXPECT_LT(in_bone / total, 0.10) << k.ct;
      }
      if (kind == LabelKind::kShoulder) {
        EXPECT_EQ(in_ribs, 0) << name << " in " << k.ct;
      }
      // The contrast CT's sternum holds no vessel (a narrow stretch of the dissected aorta, behind
      // the front wall, had been "sternum": 5 % of the aorta), and its aorta is not bone at all.
      if (std::string(k.ct).find("cta-aorta") != std::string::npos &&
          (kind == LabelKind::kVessel || kind == LabelKind::kHeart)) {
        EXPECT_EQ(row.count("sternum") ? row.at("sternum") : 0, 0) << name;
        if (name == "aorta") {
          EXPECT_LT(in_bone / total, 0.01);
        }
      }
    }
  }
}

// Each labelled rib of at least `min_voxels` against the trocar rib holding most of it: that rib
// is of the same side, holds no other labelled rib, and holds at least `share` of the labelled
// voxels or has them next to it in their slice (8-neighbours: a voxel's width). `ts`: the label
// map resampled on the CT's grid (patient::ResampleLabels).
void ExpectEachLabelledRibInOneTrocarRib(const patient::Volume& ct,
                                         const patient::Segmentation& seg,
                                         const patient::LabelMap& map, const std::vector<int>& ts,
                                         long min_voxels, double share) {
  std::map<int, std::map<int, long>> overlap;  // TS label -> trocar label -> voxels
  std::map<int, long> totals;
  for (long v = 0; v < static_cast<long>(ts.size()); ++v) {
    if (ts[v] == 0) continue;
    ++totals[ts[v]];
    if (seg.bones.labels[v] != 0) ++overlap[ts[v]][seg.bones.labels[v]];
  }
  std::set<int> best_of_rib;  // a trocar rib holding two labelled ribs (a join) fails
  std::map<int, int> best_of;  // labelled rib -> the trocar rib holding most of it
  for (const auto& [id, name] : map.names) {
    const auto label = patient::ClassifyLabel(name);
    if (label.kind != LabelKind::kRib || totals[id] < min_voxels) continue;
    SCOPED_TRACE(name);
    int best = 0;
    long best_n = 0;
    for (const auto& [l, n] : overlap[id]) {
      bool rib = false;
      for (const auto* ribs : {&seg.bones.ribs_left, &seg.bones.ribs_right}) {
        for (const auto& r : *ribs) rib = rib || r.label == l;
      }
      if (rib && n > best_n) {
        best = l;
        best_n = n;
      }
    }
    ASSERT_NE(best, 0) << "not found among the ribs";
    EXPECT_TRUE(best_of_rib.insert(best).second) << "two labelled ribs in one trocar rib";
    bool left = false;
    for (const auto& r : seg.bones.ribs_left) left = left || r.label == best;
    EXPECT_EQ(left, label.side > 0) << "the labelled rib lies in a trocar rib of the other side";
    best_of[id] = best;
    std::printf("%s: %.1f %% in trocar rib %d\n", name.c_str(), 100.0 * best_n / totals[id], best);
  }
  // One pass over the grid for every labelled rib: its voxels in or next to its trocar rib.
  std::map<int, long> found;
  for (int k = 0; k < ct.size.z(); ++k) {
    for (int j = 0; j < ct.size.y(); ++j) {
      for (int i = 0; i < ct.size.x(); ++i) {
        const auto rib = best_of.find(ts[ct.Index(i, j, k)]);
        if (rib == best_of.end()) continue;
        bool near = false;
        for (int dj = -1; dj <= 1 && !near; ++dj) {
          for (int di = -1; di <= 1 && !near; ++di) {
            const int ii = i + di, jj = j + dj;
            if (ii < 0 || jj < 0 || ii >= ct.size.x() || jj >= ct.size.y()) continue;
            near = seg.bones.labels[ct.Index(ii, jj, k)] == rib->second;
          }
        }
        found[rib->first] += near;
      }
    }
  }
  for (const auto& [id, best] : best_of) {
    SCOPED_TRACE(map.names.at(id));
    std::printf("%s: %.1f %% in or next to trocar rib %d\n", map.names.at(id).c_str(),
                100.0 * found[id] / totals[id], best);
    EXPECT_GE(static_cast<double>(found[id]) / totals[id], share);
  }
}

// A rib is a cortical tube round its marrow; a labelled rib is the whole tube. On the JPEG 2000
// DICOM CT (ribs 6-12 labelled; a 38 mm slab with an arm beside it), most labelled ribs lie
// mostly in one trocar rib (the marrow the cortex encloses taken in), none is spread over two (a
// join of two ribs, or one rib cut in two, would show as a second trocar rib holding a tenth of
// it), none is taken for the shoulder girdle, and the vertebrae are spine.
TEST(ShapeAnatomy, LabelledRibsLieInOneTrocarRibMarrowIncluded) {
  const std::string ct_path = test::SharedDataPath("ct/totalseg-dicom-j2k/dicom");
  TROCAR_REQUIRE_SHARED_FILE(ct_path);
  const patient::Volume ct = patient::LoadVolume(ct_path);
  const auto seg = patient::Segment(ct);
  const auto map =
      patient::LoadLabelMap(test::SharedDataPath("ct/totalseg-dicom-j2k/example_seg_dicom.nii.gz"));
  const std::vector<int> ts = patient::ResampleLabels(map, ct);
  const Confusion c = Compare(ct, seg, map, ts);
  int mostly = 0;
  for (const auto& [name, row] : c.counts) {
    if (patient::ClassifyLabel(name).kind != LabelKind::kRib || c.totals.at(name) < 300) continue;
    std::vector<double> shares;
    for (const auto& [cls, n] : row) {
      if (cls.rfind("rib", 0) == 0) shares.push_back(static_cast<double>(n) / c.totals.at(name));
    }
    std::sort(shares.rbegin(), shares.rend());
    if (!shares.empty() && shares[0] >= 0.85) ++mostly;
    // No rib is taken for the shoulder girdle (the spine's axis found 16 mm off the vertebrae
    // put left ribs 10 and 11 there, 54 % and 63 %).
    EXPECT_EQ(row.count("shoulder") ? row.at("shoulder") : 0, 0) << name;
    if (shares.size() > 1) {
      EXPECT_LT(shares[1], 0.1) << name;
    }
  }
  EXPECT_GE(mostly, 6);
  // Within the reference's own accuracy: TotalSegmentator's fast model labels on 3 mm blocks (its
  // rib runs along a row are 3, 6, 9... voxels of 0.98 mm, never 1 or 2), so its boundary is off
  // by up to a voxel and a half either way. Counting a labelled voxel next to its trocar rib in
  // its slice as found, every labelled rib in view lies in one trocar rib of its own side, and no
  // trocar rib holds two labelled ribs. These slabs cannot be numbered (no end of the rib cage in
  // view, see ClassifyBones), so the number is not compared.
  ExpectEachLabelledRibInOneTrocarRib(ct, seg, map, ts, 300, 0.9);
  // The vertebrae are spine, never rib (with the axis off, a fifth of T11 was a left "rib").
  for (const auto& [name, row] : c.counts) {
    if (name.rfind("vertebrae", 0) != 0) continue;
    long in_ribs = 0;
    for (const auto& [cls, n] : row) in_ribs += cls.rfind("rib", 0) == 0 ? n : 0;
    EXPECT_LT(static_cast<double>(in_ribs) / c.totals.at(name), 0.01) << name;
    EXPECT_GT(static_cast<double>(row.count("spine") ? row.at("spine") : 0) / c.totals.at(name),
              0.5)
        << name;
  }
}

// The abdominal CT (3 mm voxels, no contrast, T11 to the femora, ribs 7-12 labelled, the top face
// cutting the rib cage): each labelled rib of over 3 ml in view lies in one trocar rib of its own
// side, 85 % of it in or next to it (a rib a voxel or two thick; the ribs' stretches whose
// partial-volume cortex stays under the bone threshold are grown into from the bone above it),
// the crop face's pieces of two ribs are not joined into one (the rib pitch comes from steps
// under 5 cm, not from a rib over a femur), and the femora, hips, sacrum and lumbar vertebrae,
// far below the stack of ribs, are not ribs. Ribs 7, 2-3 ml at the top face with a median of
// 150-180 HU, never reach the bone threshold and are not found.
TEST(ShapeAnatomy, AbdominalCtRibsAreTheirOwnAndThePelvisIsNoRib) {
  const std::string ct_path = test::SharedDataPath("ct/totalseg-abdomen/example_ct.nii.gz");
  TROCAR_REQUIRE_SHARED_FILE(ct_path);
  const patient::Volume ct = patient::LoadVolume(ct_path);
  const auto seg = patient::Segment(ct);
  const auto map = patient::LoadLabelMap(
      test::SharedDataPath("ct/totalseg-abdomen/example_seg_fast_force_split.nii.gz"));
  const std::vector<int> ts = patient::ResampleLabels(map, ct);
  ExpectEachLabelledRibInOneTrocarRib(ct, seg, map, ts, 120, 0.85);
  // Counted from the label map itself: femur and hip are classes trocar does not use, which
  // Compare leaves out.
  std::set<int> rib_labels;
  for (const auto* ribs : {&seg.bones.ribs_left, &seg.bones.ribs_right}) {
    for (const auto& r : *ribs) rib_labels.insert(r.label);
  }
  for (const char* name : {"femur_left", "femur_right", "hip_left", "hip_right", "sacrum",
                           "vertebrae_L3", "vertebrae_L4", "vertebrae_L5", "vertebrae_S1"}) {
    int id = 0;
    for (const auto& [value, n] : map.names) id = n == name ? value : id;
    ASSERT_NE(id, 0) << name << " is not in the label map";
    long total = 0, in_ribs = 0;
    for (long v = 0; v < static_cast<long>(ts.size()); ++v) {
      if (ts[v] != id) continue;
      ++total;
      in_ribs += rib_labels.count(seg.bones.labels[v]);
    }
    EXPECT_GT(total, 100) << name;
    EXPECT_EQ(in_ribs, 0) << name;
  }
}

}  // namespace
}  // namespace trocar

#include "patient/phantom.hpp"
namespace trocar {
namespace {
TEST(ShapeAnatomy, PhantomRibsAreFoundAndNotNumberedWithoutAWholeRibCage) {
  patient::PhantomParameters p;
  const auto ph = patient::GeneratePhantom(p);
  patient::SegmentationOptions options;
  options.shape_anatomy = true;
  const auto seg = patient::Segment(ph.ct, options);
  // Nine ribs a side, contrast-filled heart kept out of the bone; nine ribs with the spine going
  // on below them are not a whole rib cage: no numbers (a confident wrong name is worse).
  EXPECT_EQ(seg.bones.ribs_left.size(), 9u);
  EXPECT_EQ(seg.bones.ribs_right.size(), 9u);
  EXPECT_GT(seg.contrast_volume, 0.3e-3);
  EXPECT_FALSE(seg.numbering_left.numbered);
  EXPECT_FALSE(seg.numbering_right.numbered);
  for (auto& s : seg.anatomy) std::printf("%s\n", s.c_str());
  std::printf("L %zu R %zu sternum %zu spine %zu thr %.0f\n", seg.bones.ribs_left.size(),
              seg.bones.ribs_right.size(), seg.bones.sternum.size(), seg.bones.spine.size(),
              seg.bone_threshold);
  for (int side : {1, -1})
    for (auto& c : side > 0 ? seg.bones.ribs_left : seg.bones.ribs_right)
      std::printf("%d n%d %.1fml c(%.0f %.0f %.0f)\n", side, c.number, c.volume * 1e6,
                  c.centroid_P.x() * 1e3, c.centroid_P.y() * 1e3, c.centroid_P.z() * 1e3);
  std::printf("%s\n%s\n", seg.numbering_left.basis.c_str(), seg.numbering_right.basis.c_str());
}

// Issue #42: a scan whose ribs cannot be numbered says what was seen. The default phantom's top
// rib lies 2.5 cm under the scan's top face: the top of the cage is in view (not numbered for
// want of a manubrium). Cropped so that the top face cuts that rib, the reason names the top face
// and how near the highest rib comes to it, and claims nothing about the bottom.
TEST(ShapeAnatomy, ACageCutAtTheTopIsNotNumberedAndTheReasonSaysWhereTheRibsMeetTheTopFace) {
  const auto ph = patient::GeneratePhantom(patient::PhantomParameters{});
  const auto whole = patient::Segment(ph.ct);
  EXPECT_FALSE(whole.numbering_left.numbered);
  EXPECT_EQ(whole.numbering_left.basis.find("top face"), std::string::npos)
      << whole.numbering_left.basis;
  patient::Volume cut = ph.ct;
  ASSERT_GT(cut.index_to_P(2, 2), 0.0) << "the premise: the phantom's slices run up the body";
  double rib_top = -HUGE_VAL;
  for (const auto& rib : ph.truth.ribs)
    for (const auto& q : rib.centreline) rib_top = std::max(rib_top, q.z());
  const double dz = cut.index_to_P(2, 2);
  const double top = cut.origin_P.z() + (cut.size.z() - 1) * dz;
  const int slices = static_cast<int>(std::ceil((top - (rib_top - 0.004)) / dz));
  ASSERT_GT(slices, 0);
  cut.size.z() -= slices;
  cut.values.resize(static_cast<std::size_t>(cut.voxel_count()));
  const auto seg = patient::Segment(cut);
  for (const auto* n : {&seg.numbering_left, &seg.numbering_right}) {
    EXPECT_FALSE(n->numbered) << n->basis;
    std::smatch m;
    ASSERT_TRUE(std::regex_search(
        n->basis, m, std::regex("rib piece reaches within ([0-9]+) mm of the scan's top face")))
        << n->basis;
    EXPECT_LE(std::stoi(m[1].str()), 15) << n->basis;
    EXPECT_EQ(n->basis.find("only the bottom"), std::string::npos) << n->basis;
  }
}

}  // namespace
}  // namespace trocar

namespace trocar {
namespace {

using test::DistanceToPolyline;

// A field of view that cuts the left chest wall cuts each left rib in two (its back and its front
// piece, the middle outside the scan). The pieces are joined into one rib each: nine left ribs,
// each one holding voxels of one generated rib only, and every generated rib in one trocar rib;
// the right side, whole, joins nothing. A join that paired the wrong pieces (a rib's back with the
// next rib's front) or left them apart fails it.
TEST(ShapeAnatomy, RibsCutInTwoByACropFaceAreJoinedIntoTheirOwnRibs) {
  for (unsigned seed : {1u, 2u, 3u, 5u}) {
    SCOPED_TRACE(seed);
    patient::PhantomParameters p;
    p.seed = seed;
    p.voxel_size = 0.003;
    p.rib_drop = 0.03 + 0.01 * (seed % 3);
    const patient::Phantom ph = patient::GeneratePhantom(p);
    patient::Volume ct = ph.ct;
    const int nx =
        static_cast<int>(std::floor((0.11 + 0.005 * seed - ct.origin_P.x()) / ct.spacing().x()));
    ct.size.x() = nx;
    ct.values.resize(static_cast<std::size_t>(ct.voxel_count()));
    for (int k = 0; k < ct.size.z(); ++k) {
      for (int j = 0; j < ct.size.y(); ++j) {
        for (int i = 0; i < nx; ++i) ct.values[ct.Index(i, j, k)] = ph.ct.at(i, j, k);
      }
    }
    const auto seg = patient::Segment(ct);
    bool joined = false;
    for (const auto& s : seg.anatomy)
      joined = joined || s.find("left rib pieces joined") != std::string::npos;
    EXPECT_TRUE(joined);
    for (const auto& s : seg.anatomy)
      EXPECT_EQ(s.find("right rib pieces joined"), std::string::npos) << s;
    ASSERT_EQ(seg.bones.ribs_left.size(), static_cast<std::size_t>(p.ribs_per_side));
    EXPECT_EQ(seg.bones.ribs_right.size(), static_cast<std::size_t>(p.ribs_per_side));
    // Each trocar left rib against the generated ribs: voxels within 2 rib radii of each.
    std::map<int, std::map<int, long>> near;  // trocar rib → generated rib → voxels
    std::map<int, int> rib_of_label;
    for (std::size_t r = 0; r < seg.bones.ribs_left.size(); ++r)
      rib_of_label[seg.bones.ribs_left[r].label] = static_cast<int>(r);
    std::vector<std::pair<int, test::Polyline>> left_truth;  // generated left rib: index, line
    for (const auto& truth : ph.truth.ribs)
      if (truth.side > 0) left_truth.emplace_back(truth.index, test::Polyline(truth.centreline));
    for (int k = 0; k < ct.size.z(); ++k) {
      for (int j = 0; j < ct.size.y(); ++j) {
        for (int i = 0; i < nx; ++i) {
          const auto it = rib_of_label.find(seg.bones.labels[ct.Index(i, j, k)]);
          if (it == rib_of_label.end()) continue;
          const Eigen::Vector3d q = ct.PatientPoint(i, j, k);
          for (const auto& [index, line] : left_truth) {
            if (line.Distance(q, 2 * p.rib_radius) < 2 * p.rib_radius) ++near[it->second][index];
          }
        }
      }
    }
    std::set<int> matched;
    for (int r = 0; r < p.ribs_per_side; ++r) {
      ASSERT_EQ(near[r].size(), 1u)
          << "trocar left rib " << r << " holds voxels of " << near[r].size() << " generated ribs";
      matched.insert(near[r].begin()->first);
      EXPECT_EQ(near[r].begin()->first, r) << "top to bottom";
    }
    EXPECT_EQ(matched.size(), static_cast<std::size_t>(p.ribs_per_side));
  }
}

}  // namespace
}  // namespace trocar

namespace trocar {
namespace {

// A whole rib cage as real ones come: twelve ribs a side reaching the vertebrae at their heads,
// shoulder blades over the upper ribs, collarbones over the first ribs, upper arms beside the
// chest; over seeds, body sizes, rib spacings and voxel sizes. The ribs are numbered 1 to 12 from
// the top of the rib cage with the lumbar spine in view, each trocar rib holding the voxels of
// the generated rib of its number, and no bone of the shoulder girdle among the ribs.
TEST(ShapeAnatomy, AWholePhantomRibCageIsNumberedOneToTwelveOverSeedsAndSizes) {
  struct Size {
    unsigned seed;
    double width, depth, spacing, voxel;
  };
  for (const Size& z :
       test::Cases<Size>({Size{1, 0.34, 0.24, 0.028, 0.003}, Size{2, 0.30, 0.22, 0.025, 0.0025},
                          Size{3, 0.38, 0.26, 0.030, 0.0035}, Size{4, 0.34, 0.24, 0.027, 0.003}},
                         {1})) {
    SCOPED_TRACE(z.seed);
    patient::PhantomParameters p;
    p.seed = z.seed;
    p.body_width = z.width;
    p.body_depth = z.depth;
    p.rib_spacing = z.spacing;
    p.voxel_size = z.voxel;
    p.ribs_per_side = 12;
    p.length = 0.05 + 0.05 + 1.04 * 11 * z.spacing + 0.05;
    p.wall_thickness = 0.02;
    p.ribs_reach_spine = true;
    p.shoulders = true;
    const patient::Phantom ph = patient::GeneratePhantom(p);
    const auto seg = patient::Segment(ph.ct);
    for (int side : {+1, -1}) {
      SCOPED_TRACE(side);
      const auto& ribs = side > 0 ? seg.bones.ribs_left : seg.bones.ribs_right;
      const patient::RibNumbering& numbering = side > 0 ? seg.numbering_left : seg.numbering_right;
      ASSERT_EQ(ribs.size(), 12u);
      EXPECT_TRUE(numbering.numbered) << numbering.basis;
      EXPECT_GE(numbering.confidence, 0.9);
      std::map<int, int> number_of_label;
      for (const auto& c : ribs) number_of_label[c.label] = c.number;
      std::vector<std::pair<int, test::Polyline>> side_truth;  // generated rib: index, line
      for (const auto& truth : ph.truth.ribs)
        if (truth.side == side)
          side_truth.emplace_back(truth.index, test::Polyline(truth.centreline));
      // Each voxel of a trocar rib near a generated rib: the same number.
      long right = 0, wrong = 0;
      for (int k = 0; k < ph.ct.size.z(); ++k) {
        for (int j = 0; j < ph.ct.size.y(); ++j) {
          for (int i = 0; i < ph.ct.size.x(); ++i) {
            const long v = ph.ct.Index(i, j, k);
            const auto it = number_of_label.find(seg.bones.labels[v]);
            if (it == number_of_label.end()) continue;
            EXPECT_FALSE(seg.shoulder.inside[v]);
            const Eigen::Vector3d q = ph.ct.PatientPoint(i, j, k);
            for (const auto& [index, line] : side_truth) {
              if (line.Distance(q, 1.5 * p.rib_radius) > 1.5 * p.rib_radius) continue;
              (index + 1 == it->second ? right : wrong) += 1;
            }
          }
        }
      }
      EXPECT_GT(right, 0);
      EXPECT_EQ(wrong, 0);
    }
  }
}

// The port candidates of a whole phantom rib cage (12 ribs a side) are its intercostal spaces
// named from numbered ribs: ICS-L1 … ICS-L11 and ICS-R…, each within `tolerance` of the generated
// space of its name (carried into the CT's frame by `to_ct`), at least nine a side.
void ExpectSpacesNamedAlongTheGeneratedOnes(
    const patient::PatientModel& m, const patient::Phantom& ph, double tolerance,
    const std::function<Eigen::Vector3d(const Eigen::Vector3d&)>& to_ct,
    const std::string& basis = "numbered (confidence 0.95") {
  std::map<char, int> named;
  for (const auto& c : m.port_candidates) {
    SCOPED_TRACE(c.name);
    ASSERT_EQ(c.name.rfind("ICS-", 0), 0u);
    const int side = c.name[4] == 'L' ? +1 : -1;
    const int number = std::stoi(c.name.substr(5));
    ASSERT_GE(number, 1);
    ASSERT_LE(number, 11);
    EXPECT_NE(c.source.find(basis), std::string::npos) << c.source;
    ++named[c.name[4]];
    // The generated space below rib `number` on that side (left first, 11 a side).
    patient::Curve truth;
    for (const auto& q : ph.truth.intercostal_spaces[(side > 0 ? 0 : 11) + number - 1])
      truth.push_back(to_ct(q));
    for (const auto& q : c.skin) EXPECT_LT(DistanceToPolyline(q, truth), tolerance);
  }
  EXPECT_GE(named['L'], 9);
  EXPECT_GE(named['R'], 9);
}

// The same whole rib cages imported as cases without annotated ports: the intercostal spaces
// found are named from the ribs' numbers (ICS-L1 … ICS-L11, ICS-R…), each one lying along the
// generated space of its name, and say what the names rest on. The upper arms lie against the
// chest: a point on the arm's skin would lie 8 cm or more off the space's curve. The third
// patient is obese (6 cm of fat, 8-9 cm from the ribs to the skin): with a fixed 8 cm bound on
// the chest wall it had no port candidate at all.
TEST(ShapeAnatomy, SpacesOfAWholePhantomRibCageAreNamedByTheirRibs) {
  struct Size {
    unsigned seed;
    double width, spacing, voxel, depth = 0.24, fat = 0.012;
  };
  // Under a sanitizer: the obese one (test::Cases; the small cage's numbering runs instrumented in
  // AWholePhantomRibCageIsNumberedOneToTwelveOverSeedsAndSizes).
  for (const Size& z : test::Cases<Size>({Size{6, 0.34, 0.028, 0.003}, Size{7, 0.31, 0.026, 0.0035},
                                          Size{8, 0.44, 0.028, 0.0035, 0.32, 0.06}},
                                         {2})) {
    SCOPED_TRACE(z.seed);
    const std::string dir = testing::TempDir() + "/trocar-whole-cage-" + std::to_string(z.seed);
    std::filesystem::remove_all(dir);
    std::filesystem::create_directories(dir);
    const double length = 0.15 + 1.04 * 11 * z.spacing;
    std::ofstream(dir + "/patient.yaml")
        << "name: whole\nct: ct.nrrd\nunits: hounsfield\nintercostal: {left: true, right: true}\n"
        << "surfaces: {skin: 3000, ribs: 4000, heart: 2000}\n"
        << "phantom: {seed: " << z.seed << ", body_width: " << z.width
        << ", body_depth: " << z.depth << ", fat_thickness: " << z.fat << ", length: " << length
        << ", ribs_per_side: 12, rib_spacing: " << z.spacing << ", voxel_size: " << z.voxel
        << ", wall_thickness: 0.02, ribs_reach_spine: true, shoulders: true}\n";
    const patient::PatientModel m = patient::ImportPatient(dir, {false, false, true});
    patient::PhantomParameters p;
    p.seed = z.seed;
    p.body_width = z.width;
    p.body_depth = z.depth;
    p.fat_thickness = z.fat;
    p.length = length;
    p.ribs_per_side = 12;
    p.rib_spacing = z.spacing;
    p.voxel_size = z.voxel;
    p.wall_thickness = 0.02;
    p.ribs_reach_spine = p.shoulders = true;
    const patient::Phantom ph = patient::GeneratePhantom(p);
    ExpectSpacesNamedAlongTheGeneratedOnes(m, ph, 3 * z.voxel,
                                           [](const Eigen::Vector3d& q) { return q; });
  }
}

// The whole phantom rib cage with shoulder blades, collarbones and arms that the rolled and the
// oblique tests turn, generated once.
const patient::Phantom& WholeCageWithShoulders() {
  static const patient::Phantom phantom = [] {
    patient::PhantomParameters p;
    p.seed = 9;
    p.ribs_per_side = 12;
    p.rib_spacing = 0.028;
    p.length = 0.15 + 1.04 * 11 * p.rib_spacing;
    p.voxel_size = 0.003;
    p.field_of_view = 0.6;
    p.wall_thickness = 0.02;
    p.ribs_reach_spine = p.shoulders = true;
    return patient::GeneratePhantom(p);
  }();
  return phantom;
}

// A turn about the patient's z axis through a grid's centre line (the slices' middle).
struct TurnAboutZ {
  Eigen::Vector3d centre;
  Eigen::Matrix3d R;
  TurnAboutZ(const patient::Volume& grid, double degrees)
      : centre(grid.PatientPoint(grid.size.x() / 2, grid.size.y() / 2, 0)),
        R(Eigen::AngleAxisd(degrees * M_PI / 180.0, Eigen::Vector3d::UnitZ())) {}
  Eigen::Vector3d operator()(const Eigen::Vector3d& q) const { return Apply(R, q); }
  Eigen::Vector3d Back(const Eigen::Vector3d& q) const { return Apply(R.transpose(), q); }

 private:
  Eigen::Vector3d Apply(const Eigen::Matrix3d& M, const Eigen::Vector3d& q) const {
    Eigen::Vector3d r = q;
    r.head<2>() = centre.head<2>() + (M * (q - centre)).head<2>();
    return r;
  }
};

// The value of a volume's voxel nearest a patient point q, or `outside` beyond its grid (the
// grid's inverse found once: these resample whole volumes).
class NearestValue {
 public:
  explicit NearestValue(const patient::Volume& v) : v_(v), P_to_index_(v.index_to_P.inverse()) {}
  float operator()(const Eigen::Vector3d& q, float outside) const {
    const Eigen::Vector3d f = P_to_index_ * (q - v_.origin_P);
    const Eigen::Vector3i n(std::lround(f.x()), std::lround(f.y()), std::lround(f.z()));
    if ((n.array() < 0).any() || (n.array() >= v_.size.array()).any()) return outside;
    return v_.values[v_.Index(n.x(), n.y(), n.z())];
  }

 private:
  const patient::Volume& v_;
  Eigen::Matrix3d P_to_index_;
};

// A patient lying rolled about the long axis in the scanner (a wedge under one side): the
// sorting reads left-right and front-back along the scan's axes, and rolled 8-15 degrees the
// whole phantom rib cage lost ribs and the numbers of one side or both (9-12 ribs a side); at 25
// degrees a strip of the arm's cortex, broken off by the resampling, stayed a "rib" until the
// girdle rule was repeated to a fixed point (13 pieces a side, not numbered). The
// import measures the roll from the body's cross-section and sorts in a frame turned upright; the
// model comes back in the CT's frame, so each named space lies along the rolled phantom's space
// of that name, and a heart mask and a target given in the CT's frame come back where they were
// given (left unturned, the mask's heart lay 4.7 mm off; the target 25 points off). Rolled on a
// wedge on a flat CT table, the table (turned in the upright frame) is left out of the body. A
// label map given on the CT's grid names the spaces by its ribs, and the ribs' surface lies on
// them.
TEST(ShapeAnatomy, APatientRolledInTheScannerIsSortedUprightAndModelledWhereHeLies) {
  const patient::Phantom& ph = WholeCageWithShoulders();
  const patient::PhantomParameters& p = ph.parameters;
  // Under a sanitizer: the label map's roll (test::Cases); the table rule runs instrumented in
  // Segmentation.ACtTableUnderTheBackIsLeftOutOfTheBody and the patient on the table's import.
  for (const double degrees : test::Cases<double>({-8.0, 12.0, -15.0, 25.0}, {2})) {
    SCOPED_TRACE(degrees);
    // At -8 degrees the patient lies rolled on a flat CT table (on a wedge): the table is not
    // turned, and the lower side of the back touches its carbon top.
    const bool table = degrees == -8.0;
    patient::Phantom on_table;
    if (table) {
      patient::PhantomParameters q = p;
      q.table_gap = 0.0;
      on_table = patient::GeneratePhantom(q);
      ASSERT_EQ(on_table.ct.values.size(), ph.ct.values.size());
    }
    // The phantom turned about the grid's centre line, nearest voxel, on the same grid.
    const TurnAboutZ roll(ph.ct, degrees);
    patient::Volume rolled = ph.ct;
    const NearestValue phantom_at(ph.ct);
    double back = -HUGE_VAL;  // the patient's back (LPS +y), without the table
    long touching = 0;
    for (int k = 0; k < rolled.size.z(); ++k) {
      for (int j = 0; j < rolled.size.y(); ++j) {
        for (int i = 0; i < rolled.size.x(); ++i) {
          const long here = rolled.Index(i, j, k);
          float& value = rolled.values[here];
          value = phantom_at(roll.Back(rolled.PatientPoint(i, j, k)), -1000.0f);
          if (value > -500.0f) back = std::max(back, rolled.PatientPoint(i, j, k).y());
          if (table && on_table.ct.values[here] != ph.ct.values[here]) {
            // The table, where the turned patient is not; where he is, he presses on it.
            if (value > -500.0f)
              ++touching;
            else
              value = on_table.ct.values[here];
          }
        }
      }
    }
    if (table) {
      ASSERT_GT(touching, 100) << "the table does not touch the patient";
    }
    const std::string dir =
        testing::TempDir() + "/trocar-rolled-" + std::to_string(std::lround(degrees));
    std::filesystem::remove_all(dir);
    std::filesystem::create_directories(dir);
    patient::WriteNrrd(rolled, dir + "/ct.nrrd");
    // At 12 degrees the inputs given in the CT's frame too: a heart mask (the phantom's heart,
    // rolled, on the CT's grid) and the LAD annotated with its normals. They come back where
    // they were given: turned into the upright frame with the CT, and back with the model.
    const bool inputs = degrees == 12.0;
    patient::Curve lad;
    std::vector<Eigen::Vector3d> lad_normals;
    long heart_voxels = 0;
    if (inputs) {
      patient::Volume heart = rolled;
      heart.hounsfield = false;
      for (int k = 0; k < heart.size.z(); ++k) {
        for (int j = 0; j < heart.size.y(); ++j) {
          for (int i = 0; i < heart.size.x(); ++i) {
            const Eigen::Vector3d q = roll.Back(heart.PatientPoint(i, j, k));
            const bool in = ph.truth.HeartCoordinates(q).squaredNorm() <= 1.0;
            heart.values[heart.Index(i, j, k)] = in ? 1.0f : 0.0f;
            heart_voxels += in;
          }
        }
      }
      patient::WriteNrrd(heart, dir + "/heart.nrrd");
      patient::Markup m;
      m.name = "LAD";
      m.type = "Curve";
      for (const auto& q : ph.truth.lad) m.points.push_back(roll(q));
      for (const auto& n : ph.truth.lad_normals) m.normals.push_back(roll.R * n);
      lad = m.points;
      lad_normals = m.normals;
      patient::WriteMarkups({m}, dir + "/lad.mrk.json");
    }
    // At -15 degrees a label map on the CT's grid (TotalSegmentator's names in a sidecar): the
    // phantom's bone within 8 mm of a rib's centre line labelled with that rib, and its heart.
    // Its geometry goes upright with the CT, and the spaces are named by its ribs.
    const bool labels = degrees == -15.0;
    if (labels) {
      patient::Volume map = rolled;
      map.hounsfield = false;
      std::fill(map.values.begin(), map.values.end(), 0.0f);
      std::ostringstream names;
      names << "{\"25\": \"heart\"";
      for (std::size_t r = 0; r < ph.truth.ribs.size(); ++r) {
        const auto& rib = ph.truth.ribs[r];
        names << ", \"" << r + 1 << "\": \"rib_" << (rib.side > 0 ? "left_" : "right_")
              << rib.index + 1 << "\"";
      }
      names << "}";
      std::ofstream(dir + "/labels.json") << names.str();
      std::vector<test::Polyline> rib_lines;
      for (const auto& rib : ph.truth.ribs) rib_lines.emplace_back(rib.centreline);
      for (int k = 0; k < map.size.z(); ++k) {
        for (int j = 0; j < map.size.y(); ++j) {
          for (int i = 0; i < map.size.x(); ++i) {
            const Eigen::Vector3d q = roll.Back(map.PatientPoint(i, j, k));
            float& label = map.values[map.Index(i, j, k)];
            if (ph.truth.HeartCoordinates(q).squaredNorm() <= 1.0)
              label = 25.0f;
            if (rolled.values[rolled.Index(i, j, k)] < 200.0f) continue;
            double best = 0.008;
            for (std::size_t r = 0; r < rib_lines.size(); ++r) {
              const double d = rib_lines[r].Distance(q, best);
              if (d < best) {
                best = d;
                label = static_cast<float>(r + 1);
              }
            }
          }
        }
      }
      patient::WriteNrrd(map, dir + "/labels.nrrd");
    }
    std::ofstream(dir + "/patient.yaml")
        << "name: rolled\nct: ct.nrrd\nunits: hounsfield\nintercostal: {left: true, right: true}\n"
        << "surfaces: {skin: 3000, ribs: 4000, heart: 2000}\n"
        << (inputs ? "heart: {mask: heart.nrrd}\ntargets:\n"
                     "  - {name: LAD, markups: lad.mrk.json, surface: heart, normals: file}\n"
                   : "")
        << (labels ? "labels: {file: labels.nrrd, names: labels.json}\n" : "");
    const patient::ImportedPatient imported = patient::ImportCase(dir, {false, false, true});
    const patient::PatientModel& m = *imported.model;
    if (inputs) {
      ASSERT_EQ(m.targets.size(), 1u);
      ASSERT_EQ(m.targets[0].points.size(), lad.size());
      ASSERT_EQ(m.targets[0].normals.size(), lad.size());
      for (std::size_t i = 0; i < lad.size(); ++i) {
        EXPECT_LT((m.targets[0].points[i] - lad[i]).norm(), 1e-9);
        EXPECT_LT((m.targets[0].normals[i] - lad_normals[i]).norm(), 1e-9);
      }
      const patient::Structure* heart = m.Find("heart");
      ASSERT_NE(heart, nullptr);
      EXPECT_NEAR(heart->volume, heart_voxels * std::abs(rolled.index_to_P.determinant()),
                  0.05 * heart->volume);
      Eigen::Vector3d mean = Eigen::Vector3d::Zero();
      for (const auto& v : heart->mesh.vertices) mean += v;
      mean /= static_cast<double>(heart->mesh.vertices.size());
      EXPECT_LT((mean - roll(ph.truth.heart_centre)).head<2>().norm(), p.voxel_size)
          << "the heart's surface centred at " << mean.transpose() << ", the mask's at "
          << roll(ph.truth.heart_centre).transpose();
    }
    bool said = false, table_said = false;
    for (const auto& line : imported.report.checks) {
      said = said || line.find("rolled") != std::string::npos;
      table_said = table_said || line.find("(a CT table") != std::string::npos;
    }
    EXPECT_TRUE(said);
    EXPECT_EQ(table_said, table);
    // The body is the patient's: its box ends at his back, not at the table behind it.
    EXPECT_NEAR(m.body_max_P.y(), back, 1.5 * p.voxel_size);
    ExpectSpacesNamedAlongTheGeneratedOnes(
        m, ph, 3 * p.voxel_size, roll, labels ? "intercostal:labels" : "numbered (confidence 0.95");
    if (labels) {
      // The ribs' surface lies on the labelled ribs where the CT has them: its vertices within a
      // rib's radius and a voxel or two of the rolled centre lines.
      const patient::Structure* ribs = m.Find("ribs");
      ASSERT_NE(ribs, nullptr);
      std::vector<test::Polyline> rolled_lines;
      for (const auto& rib : ph.truth.ribs) {
        patient::Curve rolled_line;
        for (const auto& q : rib.centreline) rolled_line.push_back(roll(q));
        rolled_lines.emplace_back(rolled_line);
      }
      std::vector<double> off;
      for (std::size_t v = 0; v < ribs->mesh.vertices.size(); v += 7) {
        double best = HUGE_VAL;
        for (const auto& line : rolled_lines)
          best = std::min(best, line.Distance(ribs->mesh.vertices[v], best));
        off.push_back(best);
      }
      std::sort(off.begin(), off.end());
      // Measured 5.0 mm median, 7.2 mm at the 95th percentile; with the label map left in the
      // CT's frame, unturned, 13.6 and 20.1 mm.
      EXPECT_LT(off[off.size() * 95 / 100], 0.010);
    }
    // The skin where the CT has it: its vertices' box is the body's, in the CT's frame.
    const patient::Structure* skin = m.Find("skin");
    ASSERT_NE(skin, nullptr);
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(HUGE_VAL), hi = -lo;
    for (const auto& v : skin->mesh.vertices) {
      lo = lo.cwiseMin(v);
      hi = hi.cwiseMax(v);
    }
    EXPECT_LT((lo - m.body_min_P).head<2>().cwiseAbs().maxCoeff(), 2 * p.voxel_size);
    EXPECT_LT((hi - m.body_max_P).head<2>().cwiseAbs().maxCoeff(), 2 * p.voxel_size);
  }
}

// A CT whose grid is turned from the patient's axes: an oblique header (a reconstruction along
// the body's axes, a file written after a registration) or a gantry tilt (slices sheared along
// the table). The patient lies straight in the patient frame while the grid's rows run across
// him, and the sorting reads the rows: on a grid turned 12 degrees the left side kept 2 of its 12
// ribs. The import resamples such a grid along the patient's axes (along the upright frame when
// the patient is rolled as well), finds the scan's cut faces on its own grid (they lie slanted
// across the turned one) and keeps port candidates off them.
TEST(ShapeAnatomy, AnObliqueGridIsResampledAlongThePatientsAxes) {
  const patient::Phantom& ph = WholeCageWithShoulders();
  const patient::PhantomParameters& p = ph.parameters;
  struct Case {
    double grid, roll, tilt;  // degrees: the grid turned about z, the patient rolled, the tilt
    int crop;                 // voxels cut off each side of the grid's first axis
  };
  // Under a sanitizer: the turned grid of a rolled patient alone (test::Cases: the roll's sorting
  // and the grid's resampling instrumented together; the rolled patient's own test runs in Release
  // only, scripts/test; the crop faces run instrumented in CutFaces); the cropped grid and the
  // tilt run in Release (CI's time budget, #45).
  for (const Case& t :
       test::Cases<Case>({Case{20, 0, 0, 25}, Case{-12, 15, 0, 0}, Case{0, 0, 15, 0}}, {1})) {
    SCOPED_TRACE(::testing::Message() << "grid " << t.grid << ", roll " << t.roll << ", tilt "
                                      << t.tilt << ", crop " << t.crop);
    const TurnAboutZ grid(ph.ct, t.grid), roll(ph.ct, t.roll);
    // The scan's grid: the phantom's turned about its centre line, its first axis cropped, its
    // column axis tilted about x (slices stacked along z); each voxel the phantom's nearest to
    // where the (rolled) patient has that point.
    patient::Volume ct = ph.ct;
    ct.index_to_P = grid.R * ph.ct.index_to_P;
    ct.origin_P = grid(ph.ct.origin_P) + ct.index_to_P.col(0) * t.crop;
    ct.size.x() -= 2 * t.crop;
    if (t.tilt != 0.0) {
      const double a = t.tilt * M_PI / 180.0, dy = ct.index_to_P.col(1).norm();
      const Eigen::Vector3d mid =
          ct.PatientPoint(ct.size.x() / 2, ct.size.y() / 2, ct.size.z() / 2);
      ct.index_to_P.col(1) = dy * Eigen::Vector3d(0.0, std::cos(a), std::sin(a));
      ct.origin_P += mid - ct.PatientPoint(ct.size.x() / 2, ct.size.y() / 2, ct.size.z() / 2);
    }
    ct.values.assign(static_cast<std::size_t>(ct.size.x()) * ct.size.y() * ct.size.z(), 0.0f);
    const NearestValue phantom_at(ph.ct);
    for (int k = 0; k < ct.size.z(); ++k) {
      for (int j = 0; j < ct.size.y(); ++j) {
        for (int i = 0; i < ct.size.x(); ++i) {
          ct.values[ct.Index(i, j, k)] = phantom_at(roll.Back(ct.PatientPoint(i, j, k)), -1000.0f);
        }
      }
    }
    const std::string dir = testing::TempDir() + "/trocar-oblique";
    std::filesystem::remove_all(dir);
    std::filesystem::create_directories(dir);
    patient::WriteNrrd(ct, dir + "/ct.nrrd");
    std::ofstream(dir + "/patient.yaml")
        << "name: oblique\nct: ct.nrrd\nunits: hounsfield\nintercostal: {left: true, right: true}\n"
        << "surfaces: {skin: 3000, ribs: 4000, heart: 2000}\n";
    const patient::ImportedPatient imported = patient::ImportCase(dir, {false, false, true});
    const patient::PatientModel& m = *imported.model;
    const double turned = std::max({std::abs(t.grid), std::abs(t.tilt)});
    std::ostringstream said;
    said << "CT: its grid is turned " << std::fixed << std::setprecision(1) << turned
         << " degrees from the patient's axes";
    int turned_lines = 0, rolled_lines = 0;
    for (const auto& line : imported.report.checks) {
      turned_lines += line.rfind(said.str(), 0) == 0;
      rolled_lines += line.find("lies rolled") != std::string::npos;
    }
    EXPECT_EQ(turned_lines, 1) << ::testing::PrintToString(imported.report.checks);
    EXPECT_EQ(rolled_lines, t.roll != 0.0 ? 1 : 0);
    ExpectSpacesNamedAlongTheGeneratedOnes(m, ph, 3 * p.voxel_size, roll);
    // The cut faces are the scan's: top and bottom (slanted across the resampled grid when
    // tilted), and both sides when cropped; no port candidate within the margin of them.
    std::vector<std::string> faces = {"superior", "inferior"};
    if (t.crop > 0) faces = {"right", "left", "superior", "inferior"};
    EXPECT_EQ(m.cut_faces, faces);
    const Eigen::Matrix3d to_ct_index = ct.index_to_P.inverse();
    int near_side = 0;
    for (const auto& c : m.port_candidates) {
      for (const auto& q : c.skin) {
        const Eigen::Vector3d f = to_ct_index * (q - ct.origin_P);
        const double h = ct.index_to_P.col(0).norm();
        const double side = std::min(f.x() + 0.5, ct.size.x() - 0.5 - f.x()) * h;
        const double dz = ct.index_to_P.col(2).norm();
        const double end = std::min(f.z() + 0.5, ct.size.z() - 0.5 - f.z()) * dz;
        near_side += (t.crop > 0 && side < patient::PatientModel::kCutFaceMargin) ||
                     end < patient::PatientModel::kCutFaceMargin;
      }
    }
    EXPECT_EQ(near_side, 0);
  }
}

// A crafted header, its slices a micrometre apart and tilted 45 degrees, would ask the resampling
// along the patient's axes for a million slices (4 x 10^9 voxels): refused by the voxel limit,
// naming the volume, before anything is allocated.
TEST(ShapeAnatomy, AGridShearedBeyondAnyTiltIsRefusedNamingIt) {
  patient::Volume v;
  v.source = "sheared.nrrd";
  v.size = Eigen::Vector3i(4, 1000, 4);
  v.index_to_P.col(0) = Eigen::Vector3d(0.001, 0.0, 0.0);
  v.index_to_P.col(1) = Eigen::Vector3d(0.0, 0.001, 0.001);
  v.index_to_P.col(2) = Eigen::Vector3d(0.0, 0.0, 1e-6);
  v.values.assign(4 * 1000 * 4, 0.0f);
  EXPECT_NEAR(patient::GridObliquity(v), M_PI / 4, 1e-9);  // the import would resample it
  try {
    patient::ResampleTurned(v, Eigen::Isometry3d::Identity(), -1000.0f);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("sheared.nrrd"), std::string::npos) << what;
    EXPECT_NE(what.find("resampled along the patient's axes"), std::string::npos) << what;
  }
}

}  // namespace
}  // namespace trocar

namespace trocar {
namespace {

// Which growth regime a scan gets is measured: the phantom with its blood at muscle's 45 HU is
// unenhanced (bone grows along itself above 130 HU); with its blood at a venous phase's 145 HU,
// below the contrast-pool finder's 150 HU, it is enhanced all the same (2.8 % of the body's
// voxels between 130 HU and the bone threshold, away from bone; the plain one 0 %). Either way both
// sides' nine ribs are found, none grown into the blood.
TEST(ShapeAnatomy, EnhancementIsMeasuredNotTakenFromTheContrastPool) {
  patient::PhantomParameters p;
  p.voxel_size = 0.003;
  const patient::Phantom ph = patient::GeneratePhantom(p);
  for (const float blood : {45.0f, 145.0f}) {
    SCOPED_TRACE(blood);
    patient::Volume ct = ph.ct;
    long changed = 0;
    for (float& v : ct.values) {
      if (v == patient::PhantomHu::kBlood || v == patient::PhantomHu::kArtery) {
        v = blood;
        ++changed;
      }
    }
    ASSERT_GT(changed, 1000);
    const auto seg = patient::Segment(ct);
    EXPECT_FALSE(seg.contrast);
    std::string regime;
    for (const auto& s : seg.anatomy) {
      if (s.find("away from bone") != std::string::npos) regime = s;
    }
    EXPECT_NE(regime.find(blood < 100 ? ": unenhanced" : ": enhanced"), std::string::npos)
        << regime;
    std::printf("%s\n", regime.c_str());
    EXPECT_EQ(seg.bones.ribs_left.size(), 9u);
    EXPECT_EQ(seg.bones.ribs_right.size(), 9u);
    long blood_in_bone = 0;
    for (long v = 0; v < static_cast<long>(ct.values.size()); ++v) {
      blood_in_bone += ct.values[v] == blood && seg.bones.labels[v] != 0;
    }
    EXPECT_EQ(blood_in_bone, 0);
  }
}

}  // namespace
}  // namespace trocar

namespace trocar {
namespace {

// The rib cage is one stack: a slender bone far below the ribs (a femur in an abdominal scan) is
// no rib. The phantom with a 10 cm bone rod standing 7 cm below its lowest rib keeps its nine
// ribs a side and the rod in none of them; with the stack rule off the rod is taken for a rib.
TEST(ShapeAnatomy, ASlenderBoneFarBelowTheStackOfRibsIsNoRib) {
  patient::PhantomParameters p;
  p.voxel_size = 0.003;
  p.length = 0.50;
  patient::Phantom ph = patient::GeneratePhantom(p);
  patient::Volume& ct = ph.ct;
  double rib_bottom = HUGE_VAL;
  for (const auto& rib : ph.truth.ribs) {
    for (const auto& q : rib.centreline) rib_bottom = std::min(rib_bottom, q.z());
  }
  const double rod_top = rib_bottom - 0.07, rod_bottom = rod_top - 0.10;
  ASSERT_GT(rod_bottom, ct.PatientPoint(0, 0, 0).z() + 0.01);
  std::vector<long> rod;
  for (int k = 0; k < ct.size.z(); ++k) {
    for (int j = 0; j < ct.size.y(); ++j) {
      for (int i = 0; i < ct.size.x(); ++i) {
        const Eigen::Vector3d q = ct.PatientPoint(i, j, k);
        if (q.z() < rod_bottom || q.z() > rod_top || std::hypot(q.x() - 0.09, q.y()) > 0.009)
          continue;
        ct.values[ct.Index(i, j, k)] = patient::PhantomHu::kBone;
        rod.push_back(ct.Index(i, j, k));
      }
    }
  }
  ASSERT_GT(rod.size(), 500u);
  for (const bool stack_rule : {true, false}) {
    SCOPED_TRACE(stack_rule);
    patient::SegmentationOptions options;
    if (!stack_rule) {
      options.anatomy.rib_stack_gap = 10.0;
      // The rod runs along the body's axis, which the shape rule (a rib runs around the chest)
      // refuses too: off, so that this shows what the stack rule does.
      options.anatomy.max_rib_axial_ratio = HUGE_VAL;
    }
    const auto seg = patient::Segment(ct, options);
    std::set<int> rib_labels;
    for (const auto* ribs : {&seg.bones.ribs_left, &seg.bones.ribs_right}) {
      for (const auto& c : *ribs) rib_labels.insert(c.label);
    }
    long rod_in_ribs = 0;
    for (const long v : rod) rod_in_ribs += rib_labels.count(seg.bones.labels[v]);
    if (stack_rule) {
      EXPECT_EQ(seg.bones.ribs_left.size(), 9u);
      EXPECT_EQ(seg.bones.ribs_right.size(), 9u);
      EXPECT_EQ(rod_in_ribs, 0);
    } else {
      EXPECT_GT(rod_in_ribs, static_cast<long>(rod.size() / 2));
    }
  }
}

}  // namespace
}  // namespace trocar

namespace trocar {
namespace {

// The rib cage's layer on windowed phantoms (HU mapped to 8 bits as a 400-wide window at 40 HU,
// the units raw): over seeds and sizes, each space found lies on one generated space of its side
// (median distance under one and a half voxels), no generated space is found twice, and at least
// nine of the left side's eleven are found.
TEST(ShapeAnatomy, SpacesInTheLayerOfWindowedPhantomsLieOnTheGeneratedSpaces) {
  struct Size {
    unsigned seed;
    double width, spacing, voxel;
  };
  // Under a sanitizer: the first size (test::Cases).
  for (const Size& z : test::Cases<Size>({Size{6, 0.34, 0.028, 0.003}, Size{7, 0.31, 0.026, 0.0035},
                                          Size{11, 0.36, 0.03, 0.0025}},
                                         {0})) {
    SCOPED_TRACE(z.seed);
    patient::PhantomParameters p;
    p.seed = z.seed;
    p.body_width = z.width;
    p.length = 0.15 + 1.04 * 11 * z.spacing;
    p.ribs_per_side = 12;
    p.rib_spacing = z.spacing;
    p.voxel_size = z.voxel;
    p.wall_thickness = 0.02;
    p.ribs_reach_spine = p.shoulders = true;
    patient::Phantom ph = patient::GeneratePhantom(p);
    for (float& v : ph.ct.values) v = std::clamp((v + 160.0f) / 400.0f * 255.0f, 0.0f, 255.0f);
    ph.ct.hounsfield = false;
    patient::SegmentationOptions so;
    so.raw_body = 20;  // fat (-100 HU) reads 38
    so.raw_bone = 200;
    const patient::Segmentation seg = patient::Segment(ph.ct, so);
    patient::IntercostalOptions io;
    io.right = true;
    patient::LayerChart chart;
    const auto spaces = patient::FindIntercostalSpacesInLayer(ph.ct, seg, io, &chart);
    EXPECT_GT(chart.floor, so.raw_body);
    EXPECT_LT(chart.floor, so.raw_bone);
    std::set<int> found;
    int left = 0;
    for (const auto& s : spaces) {
      EXPECT_EQ(s.upper_rib, -1);
      int best = -1;
      double best_d = HUGE_VAL;
      for (int n = 0; n < static_cast<int>(ph.truth.intercostal_spaces.size()); ++n) {
        if (ph.truth.intercostal_side[n] != s.side) continue;
        std::vector<double> d;
        for (const auto& q : s.skin)
          d.push_back(DistanceToPolyline(q, ph.truth.intercostal_spaces[n]));
        std::sort(d.begin(), d.end());
        if (d[d.size() / 2] < best_d) {
          best_d = d[d.size() / 2];
          best = n;
        }
      }
      EXPECT_LT(best_d, 1.5 * z.voxel)
          << "space of side " << s.side << " at z " << s.skin.front().z();
      EXPECT_TRUE(found.insert(best).second) << "generated space " << best << " found twice";
      left += s.side > 0;
    }
    EXPECT_GE(left, 9);
  }
}

}  // namespace
}  // namespace trocar

namespace trocar {
namespace {

// A windowed volume whose ribs hold together at the bone threshold keeps its numbered spaces: the
// whole windowed phantom rib cage (ribs at 255) is numbered from its ribs on both sides, and its
// spaces are named from those numbers and lie on the generated ones; the layer's unnumbered
// spaces are for sides whose ribs are not numbered.
TEST(ShapeAnatomy, AWindowedVolumeWithNumberedRibsKeepsItsNamedSpaces) {
  patient::PhantomParameters p;
  p.seed = 6;
  p.body_width = 0.34;
  p.rib_spacing = 0.028;
  p.voxel_size = 0.003;
  p.length = 0.15 + 1.04 * 11 * p.rib_spacing;
  p.ribs_per_side = 12;
  p.wall_thickness = 0.02;
  // Arms beside the chest: the outline held (fat reads above the body threshold), so the body is
  // not filled to its convex hull, which would bridge an arm and the chest and put the spaces'
  // skin points on that bridge.
  p.ribs_reach_spine = p.shoulders = true;
  patient::Phantom ph = patient::GeneratePhantom(p);
  // A 1000-wide window at 300 HU: contrast blood (280 HU) reads 122, bone (750 HU) 242.
  for (float& v : ph.ct.values) v = std::clamp((v + 200.0f) / 1000.0f * 255.0f, 0.0f, 255.0f);
  const std::string dir = testing::TempDir() + "/trocar-windowed-cage";
  std::filesystem::remove_all(dir);
  patient::WritePhantomCase(ph, dir);
  std::ofstream(dir + "/patient.yaml")
      << "name: windowed\nct: ct.nrrd\nunits: raw\nthresholds: {body: 15, bone: 166}\n"
      << "heart: {contrast: false}\nintercostal: {left: true, right: true}\n"
      << "surfaces: {skin: 3000, ribs: 4000}\n";
  const patient::PatientModel m = patient::ImportPatient(dir, {false, false, true});
  std::map<char, int> named;
  for (const auto& c : m.port_candidates) {
    SCOPED_TRACE(c.name);
    ASSERT_EQ(c.name.rfind("ICS-", 0), 0u) << c.source;
    const int side = c.name[4] == 'L' ? +1 : -1;
    const int number = std::stoi(c.name.substr(5));
    ++named[c.name[4]];
    const auto& truth = ph.truth.intercostal_spaces[(side > 0 ? 0 : 11) + number - 1];
    for (const auto& q : c.skin) EXPECT_LT(DistanceToPolyline(q, truth), 3 * p.voxel_size);
  }
  EXPECT_GE(named['L'], 9);
  EXPECT_GE(named['R'], 9);
}

// LIDC2 (8-bit window): the undiluted contrast of the injection (the right arm's veins, the
// superior vena cava, the right heart) reads brighter than the bone threshold, thinner than the
// 7 mm vessel core in places, and was its "sternum": the vein with the right collarbone it
// touches (33 ml, reaching 16 cm right of the midline) and the right ventricle's contrast
// (30 ml). Its ribs read as their cortex only (1.3 % of their voxels hold a 3.5 mm ball), so the
// import sorts again with a 3.5 mm core: the centres of three of those vessels, read off the
// slices (voxel indices), carry no bone label, no sternum piece lies more than 3 cm off the
// midline, and the ribs and the spine keep their volume. Without that second sorting
// (raw_cortex_core_radius 0), the old result.
TEST(ShapeAnatomy, Lidc2InjectedContrastIsVesselsNotSternum) {
  const std::string path = test::SharedDataPath("ct/lidc2/ct.nhdr");
  TROCAR_REQUIRE_SHARED_FILE(path);
  patient::Volume ct = patient::LoadVolume(path);
  ct.hounsfield = false;  // units: raw, as the case file says
  struct Found {
    double sternum_ml = 0.0, widest = 0.0, ribs_ml = 0.0, spine_ml = 0.0, vessels_ml = 0.0;
    int centres_in_bone = 0, centres_in_vessels = 0;
    bool cortex_only = false;  // the import says why it sorted again
  };
  auto sort_bones = [&](const patient::SegmentationOptions& options) {
    const patient::Segmentation seg = patient::Segment(ct, options);
    for (const std::string& a : seg.anatomy) std::printf("  %s\n", a.c_str());
    const double voxel_ml = std::abs(ct.index_to_P.determinant()) * 1e6;
    Found f;
    f.cortex_only = !seg.anatomy.empty() &&
                    seg.anatomy.front().rfind("the ribs read as their cortex only", 0) == 0;
    std::set<int> sternum;
    for (const auto& c : seg.bones.sternum) sternum.insert(c.label);
    for (int k = 0; k < ct.size.z(); ++k) {
      for (int j = 0; j < ct.size.y(); ++j) {
        for (int i = 0; i < ct.size.x(); ++i) {
          const long v = ct.Index(i, j, k);
          f.vessels_ml += seg.vessels.inside[v] * voxel_ml;
          if (sternum.count(seg.bones.labels[v]) == 0) continue;
          f.sternum_ml += voxel_ml;
          f.widest = std::max(f.widest, std::abs(ct.PatientPoint(i, j, k).x() - seg.axis_P.x()));
        }
      }
    }
    for (const auto* side : {&seg.bones.ribs_left, &seg.bones.ribs_right}) {
      for (const auto& c : *side) f.ribs_ml += c.volume * 1e6;
    }
    for (const auto& c : seg.bones.spine) f.spine_ml += c.volume * 1e6;
    // Superior vena cava, right ventricle, right arm's vein: the centre of each lumen (a solid
    // disc of 255 at least 7 voxels across).
    for (const auto& [i, j, k] :
         {std::array<int, 3>{104, 148, 24}, std::array<int, 3>{149, 159, 70},
          std::array<int, 3>{7, 135, 8}}) {
      const long v = ct.Index(i, j, k);
      f.centres_in_bone += seg.bones.labels[v] != 0;
      f.centres_in_vessels += seg.vessels.inside[v] != 0;
    }
    std::printf(
        "sternum %.1f ml, widest %.0f mm off the midline; ribs %.1f ml, spine %.1f ml; "
        "vessels %.1f ml; lumen centres in bone %d, in vessels %d\n",
        f.sternum_ml, f.widest * 1e3, f.ribs_ml, f.spine_ml, f.vessels_ml, f.centres_in_bone,
        f.centres_in_vessels);
    return f;
  };
  patient::SegmentationOptions once;
  once.anatomy.raw_cortex_core_radius = 0.0;
  const Found before = sort_bones(once);
  EXPECT_GT(before.sternum_ml, 50.0);  // the defect, with the 7 mm core alone
  EXPECT_EQ(before.centres_in_bone, 3);
  EXPECT_FALSE(before.cortex_only);
  const Found now = sort_bones(patient::SegmentationOptions{});
  EXPECT_TRUE(now.cortex_only);
  EXPECT_EQ(now.centres_in_bone, 0);
  EXPECT_EQ(now.centres_in_vessels, 3);
  EXPECT_LT(now.widest, 0.03);
  EXPECT_GT(now.vessels_ml, 50.0);
  EXPECT_GE(now.ribs_ml, before.ribs_ml);  // no rib lost to the vessels
  EXPECT_NEAR(now.spine_ml, before.spine_ml, 0.5);
}

// The same rule over phantoms in the same 8-bit window (bone 242, blood 122, the injection's
// contrast 255): a vein 12 mm across (a 7 mm ball does not fit in it, a 3.5 mm one does) crossing
// the midline 4.5 cm behind the front skin above the heart, as the brachiocephalic vein behind
// the manubrium. With the bones hollowed to a cortex one voxel thick (as a real window reads
// them: the marrow below the threshold), the ribs hold no 3.5 mm ball, the import sorts again,
// and the vein is vessels, not sternum, while the ribs and the sternum stay bone. Sorted once
// (raw_cortex_core_radius 0), the vein is bone: the test can fail. With solid bones, the ribs
// hold the ball and the 7 mm core stays (a wide window's ribs are no contrast).
// Under a sanitizer the first case runs: on seed 8 (2.5 mm voxels) the clang build's single sort
// calls the vein vessels where the gcc build calls it bone (docs/decisions.md, stop 59).
TEST(ShapeAnatomy, WindowedContrastThinnerThanTheCoreIsFoundWhenBonesReadAsCortex) {
  for (const auto& cs :
       test::Cases<std::pair<unsigned, double>>({{3u, 0.002}, {8u, 0.0025}}, {0})) {
    const unsigned seed = cs.first;  // plain names: lambdas below capture them (C++17)
    const double voxel = cs.second;
    SCOPED_TRACE(seed);
    patient::PhantomParameters p;
    p.seed = seed;
    p.voxel_size = voxel;
    p.wall_thickness = 0.02;
    p.ribs_reach_spine = p.shoulders = true;
    const patient::Phantom ph = patient::GeneratePhantom(p);
    const patient::Volume& hu = ph.ct;
    // The vein: 4.5 cm above the heart's top (the left brachiocephalic vein crosses behind the
    // manubrium before it joins the superior vena cava, which runs a few cm down to the heart),
    // 4.5 cm behind the front skin at the rib cage's midline, from 4 cm right of it to 3 cm left.
    const Eigen::Vector3d c = ph.truth.heart_centre;
    const double z = c.z() + ph.truth.HeartReach(Eigen::Vector3d::UnitZ()) + 0.045;
    double mid_x = 0.0;
    int points = 0;
    for (const auto& rib : ph.truth.ribs) {
      for (const auto& q : rib.centreline) {
        mid_x += q.x();
        ++points;
      }
    }
    mid_x /= points;
    double front = HUGE_VAL;
    const Eigen::Matrix3d to_index = hu.index_to_P.inverse();
    for (double y = -0.3; y <= 0.3; y += 0.001) {
      const Eigen::Vector3d ijk = to_index * (Eigen::Vector3d(mid_x, y, z) - hu.origin_P);
      const Eigen::Vector3i at(std::lround(ijk.x()), std::lround(ijk.y()), std::lround(ijk.z()));
      if ((at.array() < 0).any() || (at.array() >= hu.size.array()).any()) continue;
      if (hu.values[hu.Index(at.x(), at.y(), at.z())] > -400) front = std::min(front, y);
    }
    ASSERT_TRUE(std::isfinite(front));
    const Eigen::Vector3d a(mid_x - 0.04, front + 0.045, z), b(mid_x + 0.03, front + 0.045, z);
    auto in_vein = [&](const Eigen::Vector3d& q) {
      const double t = std::clamp((q - a).dot(b - a) / (b - a).squaredNorm(), 0.0, 1.0);
      return (q - (a + t * (b - a))).norm() <= 0.006;
    };
    auto windowed = [&](bool hollow) {
      patient::Volume ct = hu;
      const Eigen::Vector3i n = ct.size;
      for (int k = 1; k + 1 < n.z(); ++k) {
        for (int j = 1; j + 1 < n.y(); ++j) {
          for (int i = 1; i + 1 < n.x(); ++i) {
            const long v = ct.Index(i, j, k);
            if (!hollow || hu.values[v] != patient::PhantomHu::kBone) continue;
            // A voxel whose six face neighbours are bone is marrow: a cortex one voxel thick.
            bool interior = true;
            for (const auto& [di, dj, dk] :
                 {std::array<int, 3>{1, 0, 0}, std::array<int, 3>{-1, 0, 0},
                  std::array<int, 3>{0, 1, 0}, std::array<int, 3>{0, -1, 0},
                  std::array<int, 3>{0, 0, 1}, std::array<int, 3>{0, 0, -1}})
              interior = interior &&
                         hu.values[ct.Index(i + di, j + dj, k + dk)] == patient::PhantomHu::kBone;
            if (interior) ct.values[v] = patient::PhantomHu::kMarrow;
          }
        }
      }
      for (int k = 0; k < n.z(); ++k) {
        for (int j = 0; j < n.y(); ++j) {
          for (int i = 0; i < n.x(); ++i) {
            if (in_vein(ct.PatientPoint(i, j, k))) ct.values[ct.Index(i, j, k)] = 1200.0f;
          }
        }
      }
      for (float& v : ct.values) v = std::clamp((v + 200.0f) / 1000.0f * 255.0f, 0.0f, 255.0f);
      ct.hounsfield = false;
      return ct;
    };
    // The ribs' middle stretches (off the spine, the sternum and the shoulders), and which voxel
    // lies on one: geometry of the grid all three sortings share, found once per voxel asked.
    std::vector<test::Polyline> rib_middles;
    for (const auto& rib : ph.truth.ribs) {
      rib_middles.emplace_back(
          std::vector<Eigen::Vector3d>(rib.centreline.begin() + rib.centreline.size() / 4,
                                       rib.centreline.end() - rib.centreline.size() / 4));
    }
    std::vector<signed char> on_rib_memo(hu.values.size(), -1);
    auto on_a_rib = [&](long v, const Eigen::Vector3d& q) {
      signed char& known = on_rib_memo[static_cast<std::size_t>(v)];
      if (known < 0) {
        known = 0;
        const double within = p.rib_radius + 0.5 * p.voxel_size;
        for (const auto& mid : rib_middles) {
          if (mid.Distance(q, within) <= within) {
            known = 1;
            break;
          }
        }
      }
      return known == 1;
    };
    struct Sorted {
      bool cortex_only = false, read_solid = false;
      double vein_in_bone = 0, vein_in_vessels = 0, rib_bone_in_ribs = 0,
             sternum_bone_in_sternum = 0;
    };
    auto sort_bones = [&](const patient::Volume& ct, double thin) {
      patient::SegmentationOptions o;
      o.raw_body = 15;
      o.raw_bone = 166;
      o.anatomy.raw_cortex_core_radius = thin;
      const patient::Segmentation seg = patient::Segment(ct, o);
      Sorted r;
      for (const std::string& line : seg.anatomy) {
        r.cortex_only =
            r.cortex_only || line.find("read as their cortex only") != std::string::npos;
        r.read_solid = r.read_solid || line.find("the ribs read solid") != std::string::npos;
      }
      std::set<int> ribs, sternum, spine;
      for (const auto* side : {&seg.bones.ribs_left, &seg.bones.ribs_right})
        for (const auto& piece : *side) ribs.insert(piece.label);
      for (const auto& piece : seg.bones.sternum) sternum.insert(piece.label);
      for (const auto& piece : seg.bones.spine) spine.insert(piece.label);
      long vein = 0, rib_bone = 0, sternum_bone = 0;
      for (int k = 0; k < ct.size.z(); ++k) {
        for (int j = 0; j < ct.size.y(); ++j) {
          for (int i = 0; i < ct.size.x(); ++i) {
            const long v = ct.Index(i, j, k);
            const Eigen::Vector3d q = ct.PatientPoint(i, j, k);
            const int l = seg.bones.labels[v];
            const bool labelled = ribs.count(l) + sternum.count(l) + spine.count(l) > 0;
            if (in_vein(q)) {
              ++vein;
              r.vein_in_bone += labelled;
              r.vein_in_vessels += seg.vessels.inside[v] != 0;
              continue;
            }
            if (ct.values[v] < o.raw_bone) continue;
            // Bone of the ribs' middle stretch (off the spine, the sternum and the shoulders).
            if (on_a_rib(v, q)) {
              ++rib_bone;
              r.rib_bone_in_ribs += ribs.count(l) > 0;
            }
            if (std::abs(q.x() - mid_x) < 0.01 && q.y() < c.y()) {  // in front of the heart
              ++sternum_bone;
              r.sternum_bone_in_sternum += sternum.count(l) > 0;
            }
          }
        }
      }
      r.vein_in_bone /= std::max(1L, vein);
      r.vein_in_vessels /= std::max(1L, vein);
      r.rib_bone_in_ribs /= std::max(1L, rib_bone);
      r.sternum_bone_in_sternum /= std::max(1L, sternum_bone);
      std::printf(
          "seed %u thin %.4f: cortex only %d, vein %.2f bone %.2f vessels; rib bone %.2f "
          "in ribs; sternum bone %.2f in the sternum\n",
          seed, thin, r.cortex_only, r.vein_in_bone, r.vein_in_vessels, r.rib_bone_in_ribs,
          r.sternum_bone_in_sternum);
      return r;
    };
    const patient::Volume cortex = windowed(true);
    const Sorted now = sort_bones(cortex, 0.0035);
    EXPECT_TRUE(now.cortex_only);
    EXPECT_LT(now.vein_in_bone, 0.02);
    EXPECT_GT(now.vein_in_vessels, 0.9);
    EXPECT_GT(now.rib_bone_in_ribs, 0.9);
    EXPECT_GT(now.sternum_bone_in_sternum, 0.9);
    const Sorted once = sort_bones(cortex, 0.0);
    EXPECT_FALSE(once.cortex_only);
    EXPECT_GT(once.vein_in_bone, 0.5);
    const Sorted solid = sort_bones(windowed(false), 0.0035);
    EXPECT_FALSE(solid.cortex_only);
    EXPECT_TRUE(solid.read_solid);
    EXPECT_GT(solid.rib_bone_in_ribs, 0.9);
  }
}
}  // namespace
}  // namespace trocar

namespace trocar {
namespace {

// The shoulder girdle of a windowed volume whose ribs read as fragments is kept out of its ribs
// by the rib cage's layer (KeepBoneBeyondTheLayerOutOfRibs): phantoms with shoulder blades,
// collarbones and arms, each bone hollowed to a cortex one voxel thick and windowed to 8 bits
// (the ribs read as their cortex, as LIDC2's do), cut at the top through the first ribs so that
// neither side is numbered (the layer judges them); over seeds, voxel sizes (2-3 mm), chest
// walls 20-24 mm thick (the ribs under the shoulder blades then lie deeper than the layer's
// 45 mm) and body widths 30-34 cm. Before, the girdle's bone (voxels further than three rib
// radii from every generated rib) is among the ribs; after, at most 5 % of it is (what stays is
// an arm's bone below the rib cage, where the layer has no ribs to judge it by), and 95 % of the
// ribs' own bone (their middle stretch) stays. The ribs read as fragments: along each, 5 cm
// stretches at bone brightness and 3 cm ones below the bone threshold, above the layer's floor (as
// a rib's partial-volume cortex reads in LIDC2's window); the girdle's bone reads bright.
TEST(ShapeAnatomy, AShoulderGirdleOutsideTheLayerIsKeptOutOfFragmentaryRibs) {
  for (const auto& cs : test::Cases<std::pair<unsigned, double>>(
           {{2u, 0.002}, {5u, 0.0025}, {7u, 0.003}, {9u, 0.0025}}, {2})) {
    const unsigned seed = cs.first;  // plain names: lambdas below capture them (C++17)
    const double voxel = cs.second;
    SCOPED_TRACE(seed);
    patient::PhantomParameters p;
    p.seed = seed;
    p.voxel_size = voxel;
    p.wall_thickness = 0.02 + 0.002 * (seed % 3);
    p.body_width = 0.30 + 0.01 * (seed % 5);
    p.ribs_reach_spine = p.shoulders = true;
    const patient::Phantom ph = patient::GeneratePhantom(p);
    const patient::Volume& hu = ph.ct;
    // Cut 1 cm under the first ribs' highest point.
    double top = -HUGE_VAL;
    for (const auto& rib : ph.truth.ribs) {
      if (rib.index == 0)
        for (const auto& q : rib.centreline) top = std::max(top, q.z());
    }
    const int axial = patient::AxialAxis(hu);
    ASSERT_EQ(axial, 2);
    std::vector<int> keep;
    for (int k = 0; k < hu.size.z(); ++k) {
      if (hu.PatientPoint(0, 0, k).z() <= top - 0.01) keep.push_back(k);
    }
    ASSERT_FALSE(keep.empty());
    patient::Volume ct = hu;
    ct.size.z() = static_cast<int>(keep.size());
    ct.origin_P = hu.PatientPoint(0, 0, keep.front());
    ct.values.assign(static_cast<std::size_t>(ct.voxel_count()), 0.0f);
    const long plane = static_cast<long>(hu.size.x()) * hu.size.y();
    for (std::size_t t = 0; t < keep.size(); ++t) {
      for (long v = 0; v < plane; ++v) {
        // Hollowed: a bone voxel whose six face neighbours are bone is marrow.
        const int k = keep[t];
        const long at = v + k * plane;
        float value = hu.values[at];
        const int i = static_cast<int>(v % hu.size.x()), j = static_cast<int>(v / hu.size.x());
        if (value == patient::PhantomHu::kBone && i > 0 && j > 0 && k > 0 && i + 1 < hu.size.x() &&
            j + 1 < hu.size.y() && k + 1 < hu.size.z()) {
          bool interior = true;
          for (const long step : {1L, static_cast<long>(hu.size.x()), plane})
            interior = interior && hu.values[at + step] == patient::PhantomHu::kBone &&
                       hu.values[at - step] == patient::PhantomHu::kBone;
          if (interior) value = patient::PhantomHu::kMarrow;
        }
        float raw = std::clamp((value + 200.0f) / 1000.0f * 255.0f, 0.0f, 255.0f);
        if (hu.values[at] == patient::PhantomHu::kBone) {
          // On a rib (within two radii of its centreline, off the spine's end): dim between
          // stretches.
          const Eigen::Vector3d q = hu.PatientPoint(i, j, k);
          for (const auto& rib : ph.truth.ribs) {
            double arc = 0.0, best = HUGE_VAL, best_arc = 0.0;
            for (std::size_t n = 0; n + 1 < rib.centreline.size(); ++n) {
              const Eigen::Vector3d a = rib.centreline[n], ab = rib.centreline[n + 1] - a;
              const double u = std::clamp((q - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
              const double d = (a + u * ab - q).norm();
              if (d < best) {
                best = d;
                best_arc = arc + u * ab.norm();
              }
              arc += ab.norm();
            }
            if (best < 2 * p.rib_radius && best_arc > 0.04 && std::fmod(best_arc, 0.08) >= 0.05)
              raw = 140.0f;
          }
        }
        ct.values[v + static_cast<long>(t) * plane] = raw;
      }
    }
    ct.hounsfield = false;
    patient::SegmentationOptions so;
    so.raw_body = 15;
    so.raw_bone = 166;
    // The layer's own effect: the collarbones' distance from the spine can take them out before it
    // (KeepCollarbonesOut), so that rule is off here.
    so.anatomy.collarbone_spine_excess = 0.0;
    patient::Segmentation seg = patient::Segment(ct, so);
    ASSERT_FALSE(seg.numbering_left.numbered) << seg.numbering_left.basis;
    ASSERT_FALSE(seg.numbering_right.numbered) << seg.numbering_right.basis;
    // Rib voxels: off every generated rib (girdle) or on a rib's middle stretch (rib).
    std::vector<test::Polyline> rib_lines, rib_middles;  // whole, and their middle stretches
    for (const auto& rib : ph.truth.ribs) {
      rib_lines.emplace_back(rib.centreline);
      rib_middles.emplace_back(
          std::vector<Eigen::Vector3d>(rib.centreline.begin() + rib.centreline.size() / 4,
                                       rib.centreline.end() - rib.centreline.size() / 4));
    }
    auto count = [&](const patient::Segmentation& s) {
      std::set<int> ribs;
      for (const auto* side : {&s.bones.ribs_left, &s.bones.ribs_right})
        for (const auto& piece : *side) ribs.insert(piece.label);
      std::pair<long, long> girdle_rib{0, 0};
      for (long v = 0; v < ct.voxel_count(); ++v) {
        if (s.bones.labels[v] <= 0 || ribs.count(s.bones.labels[v]) == 0) continue;
        const Eigen::Vector3d q = ct.PatientPoint(
            static_cast<double>(v % ct.size.x()),
            static_cast<double>(v / ct.size.x() % ct.size.y()), static_cast<double>(v / plane));
        double nearest = HUGE_VAL, middle = HUGE_VAL;
        for (std::size_t r = 0; r < rib_lines.size(); ++r) {
          nearest = std::min(nearest, rib_lines[r].Distance(q, nearest));
          middle = std::min(middle, rib_middles[r].Distance(q, middle));
        }
        girdle_rib.first += nearest > 3 * p.rib_radius;
        girdle_rib.second += middle < 2 * p.rib_radius;
      }
      return girdle_rib;
    };
    const auto before = count(seg);
    EXPECT_GT(before.first, 200) << "the girdle was not among the ribs: the test proves nothing";
    patient::IntercostalOptions io;
    io.right = true;
    double moved = 0.0;
    for (int side : {+1, -1}) {
      io.left = side > 0;
      io.right = side < 0;
      patient::LayerChart chart;
      patient::FindIntercostalSpacesInLayer(ct, seg, io, &chart);
      moved += patient::KeepBoneBeyondTheLayerOutOfRibs(ct, chart, side, so.anatomy, &seg);
    }
    const auto after = count(seg);
    std::printf(
        "seed %u: girdle among ribs %ld -> %ld voxels, rib middles %ld -> %ld, moved %.1f ml\n",
        seed, before.first, after.first, before.second, after.second, moved * 1e6);
    EXPECT_LE(after.first, 0.05 * before.first);
    EXPECT_GE(after.second, 0.95 * before.second);
    // What moved is the shoulder's now.
    long shoulder = 0;
    for (std::uint8_t in : seg.shoulder.inside) shoulder += in;
    EXPECT_GE(shoulder * std::abs(ct.index_to_P.determinant()), moved - 1e-12);
  }
}

}  // namespace
}  // namespace trocar
namespace trocar {
namespace {

// What the sorting made of each voxel: 0 nothing, 1 spine, 2 sternum, 3 vessel, 4 girdle, and
// ribs 100 + number (left) or 200 + number (right), number 0 when not numbered.
std::vector<int> ClassOfEachVoxel(const patient::Segmentation& seg) {
  std::map<int, int> of_label;
  for (const auto& c : seg.bones.spine) of_label[c.label] = 1;
  for (const auto& c : seg.bones.sternum) of_label[c.label] = 2;
  for (const auto& c : seg.bones.ribs_left) of_label[c.label] = 100 + std::max(0, c.number);
  for (const auto& c : seg.bones.ribs_right) of_label[c.label] = 200 + std::max(0, c.number);
  std::vector<int> out(seg.bones.labels.size(), 0);
  for (std::size_t v = 0; v < out.size(); ++v) {
    const auto it = of_label.find(seg.bones.labels[v]);
    if (it != of_label.end()) out[v] = it->second;
    if (seg.vessels.inside[v]) out[v] = 3;
    if (seg.shoulder.inside[v]) out[v] = 4;
  }
  return out;
}

// A CT stored sagittally or coronally, or with reversed axes, is the same CT: the bone sorting
// and the spaces found between the ribs do not depend on the order of the file's index axes
// (a slice's voxel area and in-plane spacing once came from the first two index axes, which in a
// sagittal stack are across the slices: LIDC2 stored with its slices across the first axis lost
// 6 ml of spine to a rib). Over phantoms whose ribs touch the vertebrae, with shoulder girdles
// and contrast, in Hounsfield units: every voxel gets the same class, rib numbers included, and
// the same spaces come out.
TEST(ShapeAnatomy, TheSortingDoesNotDependOnTheOrderTheFileStoresItsAxesIn) {
  struct Case {
    unsigned seed;
    std::array<int, 3> order;
    std::array<bool, 3> flip;
  };
  for (const Case& c : test::Cases<Case>(
           {Case{4, {2, 0, 1}, {false, false, false}}, Case{8, {1, 2, 0}, {true, false, true}},
            Case{9, {0, 2, 1}, {false, true, false}}},
           {1})) {
    SCOPED_TRACE(c.seed);
    patient::PhantomParameters p;
    p.seed = c.seed;
    p.voxel_size = 0.002;
    p.slice_spacing = 0.004;  // thicker slices than pixels, as in clinical CTs
    p.ribs_per_side = 12;
    p.length = 0.15 + 1.04 * 11 * p.rib_spacing;
    p.wall_thickness = 0.02;
    p.ribs_reach_spine = p.shoulders = true;
    const patient::Phantom ph = patient::GeneratePhantom(p);
    const patient::Volume& ct = ph.ct;
    const test::Stored stored = test::StoreOtherwise(ct, c.order, c.flip);
    ASSERT_NE(patient::AxialAxis(stored.ct), 2);
    const patient::Segmentation a = patient::Segment(ct);
    const patient::Segmentation b = patient::Segment(stored.ct);
    const std::vector<int> class_a = ClassOfEachVoxel(a), class_b = ClassOfEachVoxel(b);
    long bone = 0, differ = 0;
    std::map<int, long> classes;
    for (int k = 0; k < ct.size.z(); ++k) {
      for (int j = 0; j < ct.size.y(); ++j) {
        for (int i = 0; i < ct.size.x(); ++i) {
          const int x = class_a[ct.Index(i, j, k)], y = class_b[stored.Index(ct, i, j, k)];
          bone += x != 0;
          differ += x != y;
          ++classes[x];
        }
      }
    }
    EXPECT_GT(classes[1], 0);
    EXPECT_GT(classes[4], 0);
    EXPECT_GT(classes[112], 0);  // ribs numbered 1 to 12, the last left one among them
    EXPECT_EQ(differ, 0) << differ << " of " << bone << " voxels sorted otherwise";
    EXPECT_EQ(a.numbering_left.basis, b.numbering_left.basis);
    patient::IntercostalOptions io;
    io.right = true;
    // The heart's contrast pool, the orientation's findings and the cut faces alike.
    const std::optional<patient::Mask> heart_a = patient::TrySegmentHeartFromContrast(ct, a);
    const std::optional<patient::Mask> heart_b = patient::TrySegmentHeartFromContrast(stored.ct, b);
    ASSERT_TRUE(heart_a.has_value() && heart_b.has_value());
    long heart = 0, heart_differ = 0;
    for (int k = 0; k < ct.size.z(); ++k) {
      for (int j = 0; j < ct.size.y(); ++j) {
        for (int i = 0; i < ct.size.x(); ++i) {
          const bool x = heart_a->inside[ct.Index(i, j, k)];
          heart += x;
          heart_differ += x != (heart_b->inside[stored.Index(ct, i, j, k)] != 0);
        }
      }
    }
    EXPECT_GT(heart, 0);
    EXPECT_EQ(heart_differ, 0);
    EXPECT_EQ(patient::CheckOrientation(ct, a, &*heart_a).findings,
              patient::CheckOrientation(stored.ct, b, &*heart_b).findings);
    std::vector<std::string> faces_a, faces_b;
    for (const auto& f : patient::FindCutFaces(ct, a.body)) faces_a.push_back(f.name);
    for (const auto& f : patient::FindCutFaces(stored.ct, b.body)) faces_b.push_back(f.name);
    EXPECT_EQ(faces_a, faces_b);
    const auto spaces_a = patient::FindIntercostalSpaces(ct, a, io);
    const auto spaces_b = patient::FindIntercostalSpaces(stored.ct, b, io);
    ASSERT_EQ(spaces_a.size(), spaces_b.size());
    for (std::size_t n = 0; n < spaces_a.size(); ++n) {
      ASSERT_EQ(spaces_a[n].skin.size(), spaces_b[n].skin.size());
      for (std::size_t q = 0; q < spaces_a[n].skin.size(); ++q)
        EXPECT_LT((spaces_a[n].skin[q] - spaces_b[n].skin[q]).norm(), 1e-3);
    }
  }
}

// The same on a real CT (the abdominal CT, in HU, stored as a coronal stack with two axes
// reversed): every voxel gets the same class. Region growing once took ties between two labels
// reaching a voxel in the same step in the file's order: a millilitre of rib marrow and spine
// went to one or the other.
TEST(ShapeAnatomy, ARealCtSortsAlikeWhicheverOrderItsAxesAreStoredIn) {
  const std::string path = test::SharedDataPath("ct/totalseg-abdomen/example_ct.nii.gz");
  TROCAR_REQUIRE_SHARED_FILE(path);
  const patient::Volume ct = patient::LoadVolume(path);
  const test::Stored stored = test::StoreOtherwise(ct, {1, 2, 0}, {true, false, true});
  ASSERT_NE(patient::AxialAxis(stored.ct), 2);
  const patient::Segmentation a = patient::Segment(ct);
  const patient::Segmentation b = patient::Segment(stored.ct);
  const std::vector<int> class_a = ClassOfEachVoxel(a), class_b = ClassOfEachVoxel(b);
  long bone = 0, differ = 0, ribs = 0;
  for (int k = 0; k < ct.size.z(); ++k) {
    for (int j = 0; j < ct.size.y(); ++j) {
      for (int i = 0; i < ct.size.x(); ++i) {
        const int x = class_a[ct.Index(i, j, k)], y = class_b[stored.Index(ct, i, j, k)];
        bone += x != 0;
        ribs += x >= 100;
        differ += x != y;
      }
    }
  }
  EXPECT_GT(ribs, 1000);
  EXPECT_EQ(differ, 0) << differ << " of " << bone << " voxels sorted otherwise";
  EXPECT_EQ(a.anatomy, b.anatomy);
}

}  // namespace
}  // namespace trocar

namespace trocar {
namespace {

// Issue #42 item 2: lidc-idri-0001 (contrast, 2.5 mm slices) imported without its labels. Its
// labelled sternum reads 146 HU at the median and 383 at the 90th percentile, its ribs 2-4 under
// 415 at the 90th, so at a bone threshold above the blood (450 HU) the sternum was missing and
// those ribs with it. Sorted again at the enhanced level (300 HU, thick blood sorted out by its
// thickness, a bone piece holding a cortex voxel above 450), as the anatomy says, with the
// sternum's marrow filled between its cortex's pieces: the trocar sternum holds at least 80 % of
// the labelled sternum's voxels, at least 85 % of its own voxels are the labelled sternum (the
// rest its rim), and none is the heart, the aorta or another vessel. The ribs' numbers are not
// compared (not numbered: left ribs 2-3 are mostly under 300 HU, issue #42 item 1).
TEST(ShapeAnatomy, TheSternumOfAWholeThoraxContrastCtIsFoundWithoutLabelsAndHoldsNoVessel) {
  // Two sortings of a 512x512x133 scan: Release only (scripts/test's asan_skips: WholeThorax);
  // the same code runs instrumented on the phantoms
  // (ThinContrastFilledVesselsAreNoRibsAtTheEnhancedThreshold).
  const std::string ct_path = test::SharedDataPath("ct/lidc-idri-0001/ct.nii.gz");
  TROCAR_REQUIRE_SHARED_FILE(ct_path);
  const patient::Volume ct = patient::LoadVolume(ct_path);
  const patient::Segmentation seg = patient::Segment(ct);
  ASSERT_TRUE(seg.contrast);
  EXPECT_EQ(seg.bone_threshold, 300.0);
  ASSERT_FALSE(seg.anatomy.empty());
  EXPECT_NE(seg.anatomy.front().find("no sternum at the bone threshold (450 HU"), std::string::npos)
      << seg.anatomy.front();
  ASSERT_FALSE(seg.bones.sternum.empty()) << "no sternum found";
  const auto map =
      patient::LoadLabelMap(test::SharedDataPath("ct/lidc-idri-0001/totalseg_labels.nii.gz"));
  const std::vector<int> ts = patient::ResampleLabels(map, ct);
  const Confusion c = Compare(ct, seg, map, ts);
  ASSERT_TRUE(c.totals.count("sternum"));
  const auto& row = c.counts.at("sternum");
  const double found = row.count("sternum") ? row.at("sternum") : 0;
  EXPECT_GE(found / c.totals.at("sternum"), 0.8);
  for (const auto& [name, counts] : c.counts) {
    const auto kind = patient::ClassifyLabel(name).kind;
    if (kind == LabelKind::kHeart || kind == LabelKind::kVessel) {
      EXPECT_EQ(counts.count("sternum") ? counts.at("sternum") : 0, 0) << name;
    }
  }
  // The trocar sternum's own voxels: the labelled sternum, or unlabelled (its rim).
  long own = 0, labelled_sternum = 0, other = 0;
  for (long v = 0; v < static_cast<long>(ts.size()); ++v) {
    if (TrocarClassAt(seg, v) != "sternum") continue;
    ++own;
    const auto it = map.names.find(ts[v]);
    if (it != map.names.end() && it->second == "sternum") {
      ++labelled_sternum;
    } else if (ts[v] != 0) {
      ++other;
    }
  }
  ASSERT_GT(own, 0);
  EXPECT_GE(static_cast<double>(labelled_sternum) / own, 0.85);
  EXPECT_LT(static_cast<double>(other) / own, 0.02);
  // Item 1: the left collarbone (arms raised: the layer along the rays does not show it outside
  // the ribs) is no rib: 79 % of it was the highest left "rib" before KeepCollarbonesOut, and
  // the left rib 1 was the second piece; now the collarbone is the shoulder's, rib 1 the highest.
  // (The right collarbone is one piece with the right ribs 1 and 2 at 300 HU: not separated.)
  ASSERT_TRUE(c.totals.count("clavicula_left") && c.totals.count("rib_left_1"));
  auto share = [&](const std::string& label, const std::string& prefix) {
    double n = 0;
    for (const auto& [cls, count] : c.counts.at(label))
      if (cls.compare(0, prefix.size(), prefix) == 0) n += count;
    return n / c.totals.at(label);
  };
  EXPECT_LT(share("clavicula_left", "ribL"), 0.05);
  EXPECT_GT(share("clavicula_left", "shoulder"), 0.7);
  const auto& rib1 = c.counts.at("rib_left_1");
  EXPECT_GT(static_cast<double>(rib1.count("ribL-1") ? rib1.at("ribL-1") : 0) /
                static_cast<double>(c.totals.at("rib_left_1")),
            0.8);
}

// What keeps thin contrast-filled vessels out of the ribs at the enhanced level (a bone threshold
// of 300 HU), on the default phantom (its LAD and LIMA drawn at 380 HU, 1.5-1.6 mm in radius;
// invisible at the default 450 HU, where its sternum is found). With both rules, nine ribs a side
// and no rib, sternum or spine voxel on the vessels' centre lines, on 1 mm and 2.5 mm voxels.
// On 2.5 mm voxels with the cortex-seed rule off, the LAD (no voxel above 450 HU) becomes a
// tenth left rib. On 1 mm voxels with the seed rule off the LIMA, a tube along the body's axis, is
// still kept out by its shape; with the shape rule off too, it becomes a tenth left rib.
TEST(ShapeAnatomy, ThinContrastFilledVesselsAreNoRibsAtTheEnhancedThreshold) {
  auto said = [](const patient::Segmentation& seg, const std::string& what) {
    for (const auto& line : seg.anatomy) {
      if (line.find(what) != std::string::npos) return true;
    }
    return false;
  };
  patient::SegmentationOptions enhanced;
  enhanced.bone_hu = 300.0;
  patient::SegmentationOptions no_seed = enhanced;
  no_seed.anatomy.enhanced_seed_hu = 0.0;
  patient::SegmentationOptions neither = no_seed;
  neither.anatomy.max_rib_axial_ratio = HUGE_VAL;
  // Instrumented, the 2.5 mm grid alone (the 1 mm one's four sortings take 25 s there).
  for (const double voxel : test::Cases<double>({0.0, 0.0025}, {1})) {
    SCOPED_TRACE(voxel);
    patient::PhantomParameters p;
    if (voxel > 0.0) p.voxel_size = voxel;
    const patient::Phantom ph = patient::GeneratePhantom(p);
    auto bone_on = [&](const patient::Segmentation& seg, const patient::Curve& curve) {
      int hits = 0;
      for (const Eigen::Vector3d& p_P : curve) {
        const Eigen::Vector3d ijk = ph.ct.IndexOf(p_P);
        const long v = ph.ct.Index(static_cast<int>(std::lround(ijk.x())),
                                   static_cast<int>(std::lround(ijk.y())),
                                   static_cast<int>(std::lround(ijk.z())));
        const std::string cls = TrocarClassAt(seg, v);
        hits += cls.rfind("rib", 0) == 0 || cls == "sternum" || cls == "spine";
      }
      return hits;
    };
    {
      const patient::Segmentation seg = patient::Segment(ph.ct);
      EXPECT_EQ(seg.bone_threshold, 450.0) << "the sternum is found above the blood";
      EXPECT_FALSE(said(seg, "no sternum at the bone threshold"));
    }
    {
      const patient::Segmentation seg = patient::Segment(ph.ct, enhanced);
      ASSERT_TRUE(seg.contrast);
      EXPECT_EQ(seg.bone_threshold, 300.0);
      EXPECT_EQ(seg.bones.ribs_left.size(), 9u);
      EXPECT_EQ(seg.bones.ribs_right.size(), 9u);
      EXPECT_EQ(bone_on(seg, ph.truth.lad), 0);
      EXPECT_EQ(bone_on(seg, ph.truth.lima), 0);
      EXPECT_TRUE(said(seg, "no bone's cortex"));
    }
    if (voxel > 0.0) {
      const patient::Segmentation seg = patient::Segment(ph.ct, no_seed);
      EXPECT_EQ(seg.bones.ribs_left.size(), 10u);
      EXPECT_GT(bone_on(seg, ph.truth.lad), 0);
    } else {
      {
        const patient::Segmentation seg = patient::Segment(ph.ct, no_seed);
        EXPECT_EQ(seg.bones.ribs_left.size(), 9u);
        EXPECT_EQ(bone_on(seg, ph.truth.lima), 0);
        EXPECT_TRUE(said(seg, "along the body's axis"));
      }
      const patient::Segmentation seg = patient::Segment(ph.ct, neither);
      EXPECT_EQ(seg.bones.ribs_left.size(), 10u);
      EXPECT_GT(bone_on(seg, ph.truth.lima), 0);
    }
  }
}

}  // namespace
}  // namespace trocar
