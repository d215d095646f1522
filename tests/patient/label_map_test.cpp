#include "patient/label_map.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <set>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "patient/patient_model.hpp"
#include "patient/volume.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

namespace fs = std::filesystem;
using patient::ClassifyLabel;
using patient::LabelKind;

std::string LabelScratch(const std::string& name) {
  const std::string dir = test::ScratchPath("labels_" + name);
  fs::create_directories(dir);
  return dir;
}

// A case of the CT `ct` with the label map `seg` (and `more` lines of patient.yaml), imported.
patient::ImportedPatient ImportLabelled(const std::string& name, const std::string& ct,
                                        const std::string& seg, const std::string& more) {
  const std::string dir = LabelScratch(name);
  WriteFileAtomically(dir + "/patient.yaml", "ct: " + ct + "\nlabels: " + seg + "\n" + more);
  return patient::ImportCase(dir, {false, false});
}
patient::PatientModel ImportLabelledCase(const std::string& name, const std::string& ct,
                                         const std::string& seg, const std::string& more) {
  return *ImportLabelled(name, ct, seg, more).model;
}

std::string ErrorOf(const std::function<void()>& f) { return test::ErrorMessage(f, "(no error)"); }

TEST(LabelMap, NamesOfTotalSegmentatorAndSlicerAreClassified) {
  struct Case {
    const char* name;
    LabelKind kind;
    int side, number;
  };
  for (const Case& c : {Case{"rib_left_5", LabelKind::kRib, +1, 5}, Case{"rib_right_12", LabelKind::kRib, -1, 12},
                        Case{"Rib left 1", LabelKind::kRib, +1, 1}, Case{"rib_7_right", LabelKind::kRib, -1, 7},
                        Case{"rib_left", LabelKind::kOther, 0, 0}, Case{"rib_left_13", LabelKind::kOther, 0, 0},
                        Case{"costal_cartilages", LabelKind::kCartilage, 0, 0},
                        Case{"sternum", LabelKind::kSternum, 0, 0}, Case{"vertebrae_T7", LabelKind::kVertebra, 0, 0},
                        Case{"vertebrae_L1", LabelKind::kVertebra, 0, 0}, Case{"heart", LabelKind::kHeart, 0, 0},
                        Case{"heart_ventricle_left", LabelKind::kHeart, 0, 0},
                        Case{"heart_myocardium", LabelKind::kHeart, 0, 0}, Case{"aorta", LabelKind::kVessel, 0, 0},
                        Case{"pulmonary_artery", LabelKind::kVessel, 0, 0},
                        Case{"superior_vena_cava", LabelKind::kVessel, 0, 0},
                        Case{"brachiocephalic_trunk", LabelKind::kVessel, 0, 0},
                        Case{"subclavian_artery_left", LabelKind::kVessel, +1, 0},
                        Case{"clavicula_left", LabelKind::kShoulder, +1, 0},
                        Case{"scapula_right", LabelKind::kShoulder, -1, 0},
                        Case{"humerus_left", LabelKind::kShoulder, +1, 0}, Case{"liver", LabelKind::kOther, 0, 0},
                        Case{"lung_upper_lobe_left", LabelKind::kOther, 0, 0}}) {
    SCOPED_TRACE(c.name);
    const auto got = ClassifyLabel(c.name);
    EXPECT_EQ(got.kind, c.kind);
    if (c.kind == LabelKind::kRib) {
      EXPECT_EQ(got.side, c.side);
      EXPECT_EQ(got.number, c.number);
    }
  }
}

// TotalSegmentator v2, one multi-label NIfTI with its names in the header extension (Caret XML):
// ribs 7-12 on both sides, numbered by their labels; every labelled rib voxel lands in the trocar
// rib of the same side and number; no humerus, vessel or heart voxel among the bones.
TEST(LabelMap, TotalSegmentatorMultiLabelNiftiGivesNumberedRibs) {
  const std::string ct_path = test::SharedDataPath("ct/totalseg-abdomen/example_ct.nii.gz");
  const std::string seg_path = test::SharedDataPath("ct/totalseg-abdomen/example_seg_fast_force_split.nii.gz");
  TROCAR_REQUIRE_SHARED_FILE(seg_path);
  const patient::Volume ct = patient::LoadVolume(ct_path);
  const patient::LabelMap map = patient::LoadLabelMap(seg_path);
  EXPECT_GE(map.names.size(), 50u);
  int rib_value = 0;
  for (const auto& [value, name] : map.names) {
    if (name == "rib_left_9") rib_value = value;
  }
  ASSERT_GT(rib_value, 0) << "rib_left_9 not among the names";
  const patient::LabelledAnatomy a = patient::AnatomyFromLabels(map, ct);
  std::set<int> left, right;
  for (const auto& r : a.bones.ribs_left) left.insert(r.number);
  for (const auto& r : a.bones.ribs_right) right.insert(r.number);
  EXPECT_EQ(left, (std::set<int>{7, 8, 9, 10, 11, 12}));
  EXPECT_EQ(right, (std::set<int>{7, 8, 9, 10, 11, 12}));
  EXPECT_TRUE(a.bones.numbered);
  EXPECT_GT(a.vessels.count(), 1000);  // the aorta
  // Independently of the builder: each labelled rib voxel (on the CT grid) is in the component of
  // that side and number, and nothing else is.
  const std::vector<int> on_ct = patient::ResampleLabels(map, ct);
  std::map<int, const patient::Component*> comp_of;
  for (const auto* side : {&a.bones.ribs_left, &a.bones.ribs_right}) {
    for (const auto& r : *side) comp_of[r.label] = &r;
  }
  long rib_voxels = 0, misplaced = 0, foreign = 0;
  for (std::size_t n = 0; n < on_ct.size(); ++n) {
    const auto it = map.names.find(on_ct[n]);
    const auto cls = it == map.names.end() ? patient::LabelClass{} : ClassifyLabel(it->second);
    const auto c = comp_of.find(a.bones.labels[n]);
    if (cls.kind == LabelKind::kRib) {
      ++rib_voxels;
      const bool right_rib = c != comp_of.end() && c->second->number == cls.number &&
                             ((cls.side > 0) == std::count_if(a.bones.ribs_left.begin(), a.bones.ribs_left.end(),
                                                               [&](const auto& r) { return r.label == c->first; }));
      misplaced += !right_rib;
    } else if (a.bones.labels[n] != 0 &&
               (cls.kind == LabelKind::kShoulder || cls.kind == LabelKind::kVessel || cls.kind == LabelKind::kHeart ||
                cls.kind == LabelKind::kOther)) {
      ++foreign;
    }
  }
  EXPECT_GT(rib_voxels, 1000);  // 3 mm voxels
  EXPECT_EQ(misplaced, 0);
  EXPECT_EQ(foreign, 0);
}

// A folder of masks (TotalSegmentator's default output) and a JSON sidecar of names.
TEST(LabelMap, FolderOfMasksAndJsonSidecar) {
  const std::string src = test::SharedDataPath("ct/totalseg-cta-aorta");
  TROCAR_REQUIRE_SHARED_FILE(src + "/aorta.nii.gz");
  const patient::Volume ct = patient::LoadVolume(src + "/ct_cropped.nii.gz");
  const std::string dir = LabelScratch("folder");
  fs::copy_file(src + "/aorta.nii.gz", dir + "/aorta.nii.gz");
  fs::copy_file(src + "/vertebrae_T12.nii.gz", dir + "/vertebrae_T12.nii.gz");
  fs::copy_file(src + "/DERIVED_heart_on_aorta_crop.nii.gz", dir + "/heart.nii.gz");
  WriteFileAtomically(dir + "/README.txt", "not a mask\n");
  const patient::LabelMap folder = patient::LoadLabelMap(dir);
  EXPECT_EQ(folder.names.size(), 3u);
  const auto a = patient::AnatomyFromLabels(folder, ct);
  EXPECT_GT(a.heart.count(), 10000);
  EXPECT_GT(a.vessels.count(), 5000);
  ASSERT_EQ(a.bones.spine.size(), 1u);
  EXPECT_TRUE(a.bones.ribs_left.empty());
  // The same anatomy from the single label map with its JSON sidecar (found beside it).
  const patient::LabelMap single = patient::LoadLabelMap(src + "/DERIVED_labels_tsv2ids_on_aorta_crop.nii.gz");
  EXPECT_EQ(single.names.at(51), "heart");
  const auto b = patient::AnatomyFromLabels(single, ct);
  // The two differ only where heart and aorta overlap (which label wins).
  EXPECT_NEAR(b.heart.count(), a.heart.count(), 0.001 * a.heart.count());
  EXPECT_EQ(b.bones.spine.front().voxels, a.bones.spine.front().voxels);
  // A mask on another grid in the same folder: refused with both geometries.
  fs::copy_file(src + "/DERIVED_heart_on_pulmonary_crop.nii.gz", dir + "/heart_atrium_left.nii.gz");
  const std::string m = ErrorOf([&] { patient::LoadLabelMap(dir); });
  EXPECT_NE(m.find("heart_atrium_left.nii.gz: on a different grid"), std::string::npos) << m;
  EXPECT_NE(m.find("voxels of"), std::string::npos) << m;
}

// A 3D Slicer segmentation: SegmentN_Name / SegmentN_LabelValue / SegmentN_Layer keys.
std::string SlicerSeg(const std::string& dir, const std::string& extra_keys) {
  const std::string path = dir + "/Segmentation.seg.nrrd";
  std::string header =
      "NRRD0004\ntype: unsigned char\ndimension: 3\nspace: left-posterior-superior\nsizes: 4 3 2\n"
      "space directions: (2,0,0) (0,2,0) (0,0,2)\nkinds: domain domain domain\nencoding: raw\n"
      "space origin: (0,0,0)\nSegment0_Name:=Rib left 5\nSegment0_LabelValue:=3\nSegment0_Layer:=0\n"
      "Segment1_Name:=Heart\nSegment1_LabelValue:=7\nSegment1_Layer:=0\n" +
      (extra_keys.empty() ? "" : extra_keys + "\n") + "\n";
  std::string data(24, '\0');
  data[0] = data[1] = 3;
  data[13] = 7;
  WriteFileAtomically(path, header + data);
  return path;
}

TEST(LabelMap, SlicerSegmentationNamesItsSegments) {
  const std::string dir = LabelScratch("slicer");
  const patient::LabelMap map = patient::LoadLabelMap(SlicerSeg(dir, ""));
  EXPECT_EQ(map.names.at(3), "Rib left 5");
  EXPECT_EQ(map.names.at(7), "Heart");
  const auto a = patient::AnatomyFromLabels(map, map.volume);
  ASSERT_EQ(a.bones.ribs_left.size(), 1u);
  EXPECT_EQ(a.bones.ribs_left[0].number, 5);
  EXPECT_EQ(a.bones.ribs_left[0].voxels, 2);
  EXPECT_EQ(a.heart.count(), 1);
  // A second layer is refused, naming the segment.
  const std::string m = ErrorOf([&] {
    patient::LoadLabelMap(SlicerSeg(dir, "Segment2_Name:=Aorta\nSegment2_LabelValue:=1\nSegment2_Layer:=1"));
  });
  EXPECT_NE(m.find("segment 2 ('Aorta') is on layer 1"), std::string::npos) << m;
}

TEST(LabelMap, BadLabelMapsAreClearErrors) {
  const std::string dir = LabelScratch("bad");
  const std::string seg = SlicerSeg(dir, "");
  // Names that trocar does not use: listed.
  std::string text = ReadTextFile(seg);
  text.replace(text.find("Rib left 5"), 10, "liver     ");
  text.replace(text.find("Heart"), 5, "spleen");
  WriteFileAtomically(seg, text);
  const patient::LabelMap map = patient::LoadLabelMap(seg);
  const std::string m = ErrorOf([&] { patient::AnatomyFromLabels(map, map.volume); });
  EXPECT_NE(m.find("none of its 2 label names"), std::string::npos) << m;
  EXPECT_NE(m.find("7 spleen"), std::string::npos) << m;
  // A value with no name (a sidecar that does not match the map).
  WriteFileAtomically(dir + "/map.json", "{\"3\": \"rib_left_5\"}");
  fs::copy_file(seg, dir + "/map.nrrd");
  const std::string u = ErrorOf([&] { patient::LoadLabelMap(dir + "/map.nrrd", dir + "/map.json"); });
  EXPECT_NE(u.find("1 label value(s) have no name (7)"), std::string::npos) << u;
  // A map that labels no voxel: refused, not ignored (the anatomy would come from the CT alone).
  std::string zero = ReadTextFile(SlicerSeg(dir, ""));
  std::fill(zero.end() - 24, zero.end(), '\0');
  WriteFileAtomically(dir + "/empty.seg.nrrd", zero);
  const std::string z = ErrorOf([&] { patient::LoadLabelMap(dir + "/empty.seg.nrrd"); });
  EXPECT_NE(z.find("empty.seg.nrrd: the label map labels no voxel"), std::string::npos) << z;
  // The same for a folder of masks whose masks are all empty.
  const std::string masks = LabelScratch("empty_masks");
  WriteFileAtomically(masks + "/heart.nrrd", zero);
  const std::string f = ErrorOf([&] { patient::LoadLabelMap(masks); });
  EXPECT_NE(f.find("empty_masks: the label map labels no voxel"), std::string::npos) << f;
  // A segment index or a label-table key too large for any label: named, not "stoi".
  std::string huge = ReadTextFile(seg);
  const std::size_t at = huge.find("Segment0_");
  ASSERT_NE(at, std::string::npos);
  huge.insert(at, "Segment99999999999999999999_Name:=x\n");
  WriteFileAtomically(dir + "/huge.seg.nrrd", huge);
  const std::string h = ErrorOf([&] { patient::LoadLabelMap(dir + "/huge.seg.nrrd"); });
  EXPECT_NE(h.find("huge.seg.nrrd: segment index"), std::string::npos) << h;
  EXPECT_EQ(h.find("stoi"), std::string::npos) << h;
  // A map that does not overlap the CT: both geometries named.
  patient::Volume far = map.volume;
  far.origin_P += Eigen::Vector3d(1, 0, 0);
  far.source = "far.nrrd";
  const std::string o = ErrorOf([&] { patient::ResampleLabels(map, far); });
  EXPECT_NE(o.find("does not overlap the CT far.nrrd"), std::string::npos) << o;
}

// `labels:` in patient.yaml: the model's ribs, heart and vessels come from the label map and the
// intercostal spaces are named by the ribs' numbers.
TEST(LabelMap, PatientCaseWithALabelMapNamesSpacesByRibNumbers) {
  const std::string ct = test::SharedDataPath("ct/totalseg-abdomen/example_ct.nii.gz");
  const std::string seg = test::SharedDataPath("ct/totalseg-abdomen/example_seg_fast_force_split.nii.gz");
  TROCAR_REQUIRE_SHARED_FILE(seg);
  const patient::PatientModel m = ImportLabelledCase(
      "case", ct, seg, "heart: {contrast: false}\nintercostal: {left: true, right: true}\n");
  ASSERT_NE(m.Find("ribs"), nullptr);
  ASSERT_NE(m.Find("vessels"), nullptr);
  ASSERT_FALSE(m.port_candidates.empty());
  for (const auto& c : m.port_candidates) {
    EXPECT_EQ(c.source, "intercostal:labels");
    EXPECT_TRUE(c.name == "ICS-L7" || c.name == "ICS-L8" || c.name == "ICS-L9" || c.name == "ICS-L10" ||
                c.name == "ICS-L11" || c.name == "ICS-R7" || c.name == "ICS-R8" || c.name == "ICS-R9" ||
                c.name == "ICS-R10" || c.name == "ICS-R11")
        << c.name;
  }
}

// lidc-idri-0001, a whole-thorax CT with all 24 ribs, imported with its TotalSegmentator label
// map (issue #42: "the same scan with its labels: the ribs, spaces and sternum from the labels"):
// each numbered space lies between the labelled ribs of its number, checked against the label
// map read here, not the import's ribs. For each point of ICS-L<n> or ICS-R<n> (on the skin over
// the space), the nearest voxel of that side's labelled rib n lies no lower than it (toward the
// head) and the nearest of rib n+1 no higher, within a slice's thickness, for at least 90 % of
// the space's points. A space named one number off fails: the test checks that its own
// criterion, with every space named one number higher, fails nearly every space.
TEST(LabelMap, AWholeThoraxsSpacesLieBetweenTheLabelledRibsOfTheirNumber) {
  const std::string ct = test::SharedDataPath("ct/lidc-idri-0001/ct.nii.gz");
  const std::string seg = test::SharedDataPath("ct/lidc-idri-0001/totalseg_labels.nii.gz");
  TROCAR_REQUIRE_SHARED_FILE(seg);
  const patient::ImportedPatient imported =
      ImportLabelled("lidc_idri_0001", ct, seg, "intercostal: {left: true, right: true}\n");
  const patient::PatientModel& m = *imported.model;
  ASSERT_NE(m.Find("sternum"), nullptr);
  // The map lies on its own CT: its overlap is measured and said, and nothing is warned (the
  // shifted maps of the next test are refused by the same check).
  bool said = false;
  for (const auto& line : imported.report.checks)
    said = said || line.find("label map: ") != std::string::npos;
  EXPECT_TRUE(said) << "the overlap is said";
  for (const auto& w : imported.report.warnings)
    EXPECT_EQ(w.find("label map"), std::string::npos) << w;
  const patient::LabelMap map = patient::LoadLabelMap(seg);
  // The labelled ribs' voxels in P, by "left 5", "right 12".
  std::map<int, std::string> rib_of_label;
  for (const auto& [label, name] : map.names) {
    for (const char* side : {"left", "right"}) {
      const std::string prefix = std::string("rib_") + side + "_";
      if (name.rfind(prefix, 0) == 0)
        rib_of_label[label] = std::string(side) + " " + name.substr(prefix.size());
    }
  }
  ASSERT_EQ(rib_of_label.size(), 24u);
  std::map<std::string, std::vector<Eigen::Vector3d>> ribs;
  const patient::Volume& v = map.volume;
  for (int k = 0; k < v.size.z(); ++k) {
    for (int j = 0; j < v.size.y(); ++j) {
      for (int i = 0; i < v.size.x(); ++i) {
        const auto it = rib_of_label.find(static_cast<int>(v.values[v.Index(i, j, k)]));
        if (it != rib_of_label.end()) ribs[it->second].push_back(v.PatientPoint(i, j, k));
      }
    }
  }
  auto nearest = [](const std::vector<Eigen::Vector3d>& voxels, const Eigen::Vector3d& p) {
    Eigen::Vector3d best = voxels.front();
    for (const Eigen::Vector3d& q : voxels)
      if ((q - p).squaredNorm() < (best - p).squaredNorm()) best = q;
    return best;
  };
  const double slice = v.spacing().z();
  std::set<std::string> named;
  int spaces = 0, one_off_fails = 0;
  for (const patient::PortCandidate& c : m.port_candidates) {
    ASSERT_EQ(c.source, "intercostal:labels") << c.name;
    ASSERT_TRUE(c.name.rfind("ICS-L", 0) == 0 || c.name.rfind("ICS-R", 0) == 0) << c.name;
    named.insert(c.name);
    const std::string side = c.name[4] == 'L' ? "left" : "right";
    const int n = std::stoi(c.name.substr(5));
    // The share of the space's points between ribs `above` and `above` + 1 of its side, within
    // a slice's thickness (the nearest voxel of a sloping rib may lie in the point's own slice or
    // the next, beside it).
    auto share_between = [&](int above) {
      const auto& upper = ribs[side + " " + std::to_string(above)];
      const auto& lower = ribs[side + " " + std::to_string(above + 1)];
      if (upper.empty() || lower.empty()) return 0.0;
      int between = 0;
      for (const Eigen::Vector3d& p : c.skin) {
        if (nearest(upper, p).z() >= p.z() - slice && nearest(lower, p).z() <= p.z() + slice)
          ++between;
      }
      return between / static_cast<double>(c.skin.size());
    };
    const double share = share_between(n);
    EXPECT_GE(share, 0.9) << c.name << ": " << 100 * share << " % of its points between ribs " << n
                          << " and " << n + 1 << " of the " << side;
    // The check tells a space from its neighbours: named one number higher, it fails.
    if (n <= 10) one_off_fails += share_between(n + 1) < 0.5 ? 1 : 0;
    ++spaces;
  }
  EXPECT_GE(one_off_fails, spaces - 1) << "of " << spaces << " spaces";
  // The spaces a surgeon asks for by number, on both sides.
  for (int n = 1; n <= 9; ++n) {
    EXPECT_EQ(named.count("ICS-L" + std::to_string(n)), 1u) << n;
    EXPECT_EQ(named.count("ICS-R" + std::to_string(n)), 1u) << n;
  }
}

}  // namespace
}  // namespace trocar

namespace trocar {
namespace {

// Issue #42, bad input: a label map whose ribs do not lie on the CT's (its header's origin off by
// 12 or 30 mm toward the head, or 20 mm to the side: a rib's height, a rib's spacing) is refused
// naming the file and the overlap measured, where it is and moved to fit (the map unshifted
// imports and says its overlap: the spaces' test above, one import fewer). The import measures the
// share of the labelled rib voxels that are bone-bright on the CT, there and with the labels moved
// 5-30 mm.
TEST(LabelMap, AWholeThoraxsMapShiftedAgainstItsCtIsRefusedWithTheOverlapMeasured) {
  const std::string ct = test::SharedDataPath("ct/lidc-idri-0001/ct.nii.gz");
  const std::string seg = test::SharedDataPath("ct/lidc-idri-0001/totalseg_labels.nii.gz");
  TROCAR_REQUIRE_SHARED_FILE(seg);
  const patient::LabelMap map = patient::LoadLabelMap(seg);
  const std::string dir = LabelScratch("shifted_maps");
  nlohmann::json names = nlohmann::json::object();
  for (const auto& [value, name] : map.names) names[std::to_string(value)] = name;
  WriteFileAtomically(dir + "/names.json", names.dump());
  struct Shift {
    const char* name;
    Eigen::Vector3d d_P;
  };
  for (const Shift& s : {Shift{"head12", {0, 0, 0.012}}, Shift{"head30", {0, 0, 0.030}},
                         Shift{"left20", {0.020, 0, 0}}}) {
    SCOPED_TRACE(s.name);
    patient::Volume v = map.volume;
    v.origin_P += s.d_P;
    const std::string file = dir + "/" + s.name + ".nrrd";
    patient::WriteNrrd(v, file);
    const std::string case_dir = LabelScratch(std::string("shifted_") + s.name);
    WriteFileAtomically(case_dir + "/patient.yaml", "ct: " + ct + "\nlabels: {file: " + file +
                                                        ", names: " + dir +
                                                        "/names.json}\n"
                                                        "intercostal: {left: true, right: true}\n");
    const std::string e = ErrorOf([&] { patient::ImportCase(case_dir, {false, false}); });
    EXPECT_NE(e.find(std::string(s.name) + ".nrrd: its ribs do not lie on this CT's ribs: "),
              std::string::npos)
        << e;
    EXPECT_NE(e.find("% moved "), std::string::npos) << e;
  }
}

}  // namespace
}  // namespace trocar
