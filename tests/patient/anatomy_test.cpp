#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <map>

#include "common/error.hpp"
#include "patient/label_map.hpp"
#include "patient/segmentation.hpp"
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

Confusion Compare(const patient::Volume& ct, const patient::Segmentation& seg, const patient::LabelMap& map) {
  const std::vector<int> labels = patient::ResampleLabels(map, ct);
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
    std::printf("%-28s %7ld [%4.0f %4.0f %4.0f %4.0f]:", name.c_str(), c.totals.at(name), pc(0.1), pc(0.5), pc(0.9), pc(0.99));
    for (const auto& [cls, n] : row) std::printf(" %s=%.0f%%", cls.c_str(), 100.0 * n / c.totals.at(name));
    std::printf("\n");
  }
}

TEST(ShapeAnatomy, ContrastIsNeverBoneAndArmsAreNeverRibsOnLabelledRealCts) {
  struct Case {
    const char* ct;
    const char* labels;
  };
  for (const Case& k : {Case{"ct/totalseg-cta-aorta/ct_cropped.nii.gz", "ct/totalseg-cta-aorta/DERIVED_labels_tsv2ids_on_aorta_crop.nii.gz"},
                        Case{"ct/totalseg-dicom-j2k/dicom", "ct/totalseg-dicom-j2k/example_seg_dicom.nii.gz"},
                        Case{"ct/totalseg-abdomen/example_ct.nii.gz", "ct/totalseg-abdomen/example_seg_fast_force_split.nii.gz"}}) {
    const std::string ct_path = test::SharedDataPath(k.ct);
    TROCAR_REQUIRE_SHARED_FILE(ct_path);
    const patient::Volume ct = patient::LoadVolume(ct_path);
    patient::SegmentationOptions options;
    options.shape_anatomy = true;
    const auto seg = patient::Segment(ct, options);
    const auto map = patient::LoadLabelMap(test::SharedDataPath(k.labels));
    std::printf("== %s\n", k.ct);
    const Confusion c = Compare(ct, seg, map);
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
      if (name == "heart") { EXPECT_LT(in_bone / total, 0.01) << k.ct; }
      if (name == "aorta") { EXPECT_LT(in_bone / total, 0.10) << k.ct; }
      if (kind == LabelKind::kShoulder) { EXPECT_EQ(in_ribs, 0) << name << " in " << k.ct; }
    }
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
  std::printf("L %zu R %zu sternum %zu spine %zu thr %.0f\n", seg.bones.ribs_left.size(), seg.bones.ribs_right.size(), seg.bones.sternum.size(), seg.bones.spine.size(), seg.bone_threshold);
  for (int side : {1, -1}) for (auto& c : side > 0 ? seg.bones.ribs_left : seg.bones.ribs_right) std::printf("%d n%d %.1fml c(%.0f %.0f %.0f)\n", side, c.number, c.volume*1e6, c.centroid_P.x()*1e3, c.centroid_P.y()*1e3, c.centroid_P.z()*1e3);
  std::printf("%s\n%s\n", seg.numbering_left.basis.c_str(), seg.numbering_right.basis.c_str());
}
}  // namespace
}  // namespace trocar
