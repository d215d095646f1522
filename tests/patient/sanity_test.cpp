#include "patient/sanity.hpp"

#include <filesystem>
#include <fstream>
#include <optional>

#include <gtest/gtest.h>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "patient/markups.hpp"
#include "patient/patient_model.hpp"
#include "patient/phantom.hpp"
#include "patient/segmentation.hpp"
#include "patient/volume.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

namespace fs = std::filesystem;

// A phantom case whose CT header is mirrored along the patient axes in `flip` (+1 kept, -1
// flipped): the voxels stay, the header says the anatomy lies the other way.
std::string FlippedCase(const std::string& name, unsigned seed, const Eigen::Vector3d& flip,
                        const std::string& extra_yaml = "") {
  const std::string dir = testing::TempDir() + "/trocar-flip-" + name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  patient::PhantomParameters p;
  p.seed = seed;
  p.voxel_size = 0.004;
  patient::Volume ct = patient::GeneratePhantom(p).ct;
  const Eigen::Matrix3d M = flip.asDiagonal();
  ct.index_to_P = M * ct.index_to_P;
  ct.origin_P = M * ct.origin_P;
  patient::WriteNrrd(ct, JoinPath(dir, "ct.nrrd"));
  std::ofstream(JoinPath(dir, "patient.yaml"))
      << "name: " << name << "\nct: ct.nrrd\nunits: hounsfield\nintercostal: {left: true}\n"
      << "surfaces: {skin: 3000, ribs: 4000, heart: 2000}\n" << extra_yaml;
  return dir;
}

std::string ImportError(const std::string& dir) {
  try {
    patient::ImportPatient(dir, {false, false});
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// Every flip of the header's axes, alone or together (the case: x and y), is reported
// naming the axis the anatomy contradicts; the header as written imports with all three agreed.
TEST(Orientation, FlippedOrMirroredHeadersAreReportedOverSeeds) {
  // Under a sanitizer: the first seed's phantom, every flip (test::Cases).
  for (unsigned seed : test::Cases<unsigned>({1u, 4u}, {0})) {
    SCOPED_TRACE(seed);
    const patient::ImportedPatient ok_imported = patient::ImportCase(FlippedCase("none", seed, {1, 1, 1}), {false, false});
    const patient::ImportReport& ok_report = ok_imported.report;
    int agreed = 0;
    for (const auto& line : ok_report.checks) agreed += line.find("as the header says") != std::string::npos;
    EXPECT_GE(agreed, 3);
    for (const auto& w : ok_report.warnings) EXPECT_EQ(w.find("orientation"), std::string::npos) << w;

    struct Flip {
      const char* name;
      Eigen::Vector3d axes;
      std::vector<const char*> expected;
    };
    const std::vector<Flip> flips = {
        {"x", {-1, 1, 1}, {"mirrored"}},
        {"y", {1, -1, 1}, {"front-back flipped"}},
        {"z", {1, 1, -1}, {"head-foot flipped"}},
        {"xy", {-1, -1, 1}, {"mirrored", "front-back flipped"}},
    };
    for (const Flip& f : flips) {
      SCOPED_TRACE(f.name);
      const std::string dir = FlippedCase(f.name, seed, f.axes);
      const std::string error = ImportError(dir);
      ASSERT_FALSE(error.empty()) << "a header flipped along " << f.name << " imported silently";
      EXPECT_NE(error.find("disagrees with the header"), std::string::npos) << error;
      for (const char* e : f.expected) EXPECT_NE(error.find(e), std::string::npos) << e << "\n" << error;
      EXPECT_NE(error.find("orientation: {check: false}"), std::string::npos) << error;
    }
  }
  // Asked not to check (a mirrored patient): imported, with a warning.
  const patient::ImportedPatient mirrored_imported = patient::ImportCase(
      FlippedCase("x-unchecked", 1, {-1, 1, 1}, "orientation: {check: false}\n"), {false, false});
  const patient::ImportReport& mirrored_report = mirrored_imported.report;
  bool warned = false;
  for (const auto& w : mirrored_report.warnings) warned = warned || w.find("orientation") != std::string::npos;
  EXPECT_TRUE(warned);
}

// A "heart" behind the lungs while the spine lies at the back (contrast in a kidney taken for the
// chambers) does not judge the header: no "mirrored" from it, left-right left to other cues. The
// same ball in front of the lungs, right of the midline, is still a mirrored header: the rule
// drops only the heart the spine contradicts.
TEST(Orientation, AHeartTheSpineContradictsDoesNotJudgeTheHeader) {
  for (unsigned seed : {1u, 2u, 3u}) {
    SCOPED_TRACE(seed);
    patient::PhantomParameters p;
    p.seed = seed;
    p.voxel_size = 0.004;
    const patient::Volume ct = patient::GeneratePhantom(p).ct;
    const patient::Segmentation seg = patient::Segment(ct);
    const Eigen::Vector3d centre = 0.5 * (seg.body_min_P + seg.body_max_P);
    // The lungs' centre: air inside the body, as the check measures it.
    Eigen::Vector3d lung_c = Eigen::Vector3d::Zero();
    long lung_n = 0;
    for (int k = 0; k < ct.size.z(); ++k) {
      for (int j = 0; j < ct.size.y(); ++j) {
        for (int i = 0; i < ct.size.x(); ++i) {
          const long n = ct.Index(i, j, k);
          if (!seg.body.inside[n] || ct.values[n] > seg.body_threshold) continue;
          lung_c += ct.PatientPoint(i, j, k);
          ++lung_n;
        }
      }
    }
    ASSERT_GT(lung_n, 1000);
    lung_c /= static_cast<double>(lung_n);
    // A 3 cm ball 7 cm right of the midline, 4 cm behind (LPS +y) or in front of the lungs' centre.
    auto ball = [&](double dy) {
      patient::Mask m;
      m.size = ct.size;
      m.inside.assign(ct.values.size(), 0);
      const Eigen::Vector3d c(centre.x() - 0.07, lung_c.y() + dy, lung_c.z());
      for (int k = 0; k < ct.size.z(); ++k) {
        for (int j = 0; j < ct.size.y(); ++j) {
          for (int i = 0; i < ct.size.x(); ++i)
            m.inside[ct.Index(i, j, k)] = (ct.PatientPoint(i, j, k) - c).norm() < 0.03;
        }
      }
      return m;
    };
    const patient::Mask behind = ball(+0.04), in_front = ball(-0.04);
    const patient::OrientationCheck kidney = patient::CheckOrientation(ct, seg, &behind);
    EXPECT_EQ(kidney.anterior_posterior, +1);  // the spine decides, as the header says
    EXPECT_TRUE(kidney.heart_misplaced);
    EXPECT_NE(kidney.left_right, -1);  // undecided, or the ribs' sides
    EXPECT_FALSE(kidney.flipped());
    bool said = false;
    for (const auto& f : kidney.findings) {
      said = said || f.find("not a heart where a heart lies") != std::string::npos;
      EXPECT_EQ(f.find("heart: centre"), std::string::npos) << f;  // no left-right from it
    }
    EXPECT_TRUE(said);
    const patient::OrientationCheck mirrored = patient::CheckOrientation(ct, seg, &in_front);
    EXPECT_FALSE(mirrored.heart_misplaced);
    EXPECT_EQ(mirrored.left_right, -1);
    EXPECT_TRUE(mirrored.flipped());
  }
}

// The abdominal CT, imported as a user would without hand settings: its only "blood pool" is
// contrast in the right kidney (66 ml, 8 cm right of the midline, below the lung bases), which
// had made the import fail with "a mirrored header". The header is right; the import goes through
// and warns that its heart is probably none.
TEST(Orientation, AnAbdominalScanWhoseContrastIsTakenForTheHeartImportsWithAWarning) {
  const std::string ct_path = test::SharedDataPath("ct/totalseg-abdomen/example_ct.nii.gz");
  TROCAR_REQUIRE_SHARED_FILE(ct_path);
  const std::string dir = testing::TempDir() + "/trocar-abdomen-heart";
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::ofstream(JoinPath(dir, "patient.yaml"))
      << "ct: " << ct_path << "\nintercostal: {left: true, right: true}\n"
      << "surfaces: {skin: 3000, ribs: 4000, heart: 2000, spine: 2000}\n";
  const patient::ImportedPatient imported = patient::ImportCase(dir, {false, false});
  bool warned = false;
  for (const auto& w : imported.report.warnings) {
    warned =
        warned || w.rfind("heart: the heart from a contrast-filled blood pool lies behind", 0) == 0;
    EXPECT_EQ(w.find("orientation"), std::string::npos) << w;
  }
  EXPECT_TRUE(warned);
  for (const auto& c : imported.report.checks) {
    EXPECT_EQ(c.find("mirrored"), std::string::npos) << c;
    EXPECT_EQ(c.find("flipped"), std::string::npos) << c;
  }
  // The same pool given as heart.mask: the user's mask is checked, not called "no heart".
  patient::Volume ct = patient::LoadVolume(ct_path);
  const std::optional<patient::Mask> pool =
      patient::TrySegmentHeartFromContrast(ct, patient::Segment(ct), {});
  ASSERT_TRUE(pool.has_value());
  for (std::size_t n = 0; n < ct.values.size(); ++n) ct.values[n] = pool->inside[n] ? 1.0f : 0.0f;
  patient::WriteNrrd(ct, JoinPath(dir, "pool.nrrd"));
  std::ofstream(JoinPath(dir, "patient.yaml"))
      << "ct: " << ct_path << "\nheart: {mask: pool.nrrd}\nintercostal: {left: true, right: true}\n"
      << "surfaces: {skin: 3000, ribs: 4000, heart: 2000, spine: 2000}\n";
  const patient::ImportedPatient given = patient::ImportCase(dir, {false, false});
  bool checked = false;
  for (const auto& w : given.report.warnings) {
    if (w.rfind("heart: the heart from heart.mask", 0) != 0) continue;
    checked = w.find("check that it belongs to this CT") != std::string::npos;
    EXPECT_EQ(w.find("probably no heart"), std::string::npos) << w;
  }
  EXPECT_TRUE(checked);
}

// A cardiac field of view: the contrast CT cropped around the heart, cut on every side. The box's
// centre lies near the heart (7 mm from its centre), so against it the heart decided nothing and a
// mirrored header went unreported. Against the body's axis (at the spine when the box is pulled
// aside) the heart lies left as it should, and the mirrored header is reported.
TEST(Orientation, TotalSegmentatorCtaCropMirroredIsReportedAgainstTheSpinesMidline) {
  const std::string ct_path = test::SharedDataPath("ct/totalseg-cta-aorta/ct_cropped.nii.gz");
  TROCAR_REQUIRE_SHARED_FILE(ct_path);
  patient::Volume ct = patient::LoadVolume(ct_path);
  for (const double flip : {+1.0, -1.0}) {
    SCOPED_TRACE(flip);
    if (flip < 0) {
      const Eigen::Matrix3d M = Eigen::Vector3d(-1, 1, 1).asDiagonal();
      ct.index_to_P = M * ct.index_to_P;
      ct.origin_P = M * ct.origin_P;
    }
    const patient::Segmentation seg = patient::Segment(ct);
    const std::optional<patient::Mask> heart = patient::TrySegmentHeartFromContrast(ct, seg, {});
    ASSERT_TRUE(heart.has_value());
    const patient::OrientationCheck o = patient::CheckOrientation(ct, seg, &*heart);
    std::string findings;
    for (const auto& f : o.findings) findings += f + "\n";
    EXPECT_EQ(o.left_right, flip > 0 ? +1 : -1) << findings;
    EXPECT_EQ(o.flipped(), flip < 0) << findings;
    EXPECT_FALSE(o.heart_misplaced) << findings;
  }
}

// A scan whose field of view cuts the body's left side: the crop face is named, and no port
// candidate lies within the margin of it (the intercostal spaces found reach the side of the
// chest, so some of their points were there).
TEST(CutFaces, CropFacesAreNamedAndCarryNoPortCandidates) {
  for (unsigned seed : {1u, 2u, 3u}) {
    SCOPED_TRACE(seed);
    const std::string dir = testing::TempDir() + "/trocar-cut-" + std::to_string(seed);
    fs::remove_all(dir);
    fs::create_directories(dir);
    patient::PhantomParameters p;
    p.seed = seed;
    p.voxel_size = 0.004;
    const patient::Volume full = patient::GeneratePhantom(p).ct;
    // Keep x (left, LPS +x) up to 0.13 m: the left chest wall beyond it is cut off.
    patient::Volume ct = full;
    const double crop_x = 0.13;
    const int nx = static_cast<int>(std::floor((crop_x - full.origin_P.x()) / full.spacing().x()));
    ct.size.x() = nx;
    ct.values.resize(static_cast<std::size_t>(ct.voxel_count()));
    for (int k = 0; k < ct.size.z(); ++k) {
      for (int j = 0; j < ct.size.y(); ++j) {
        for (int i = 0; i < nx; ++i) ct.values[ct.Index(i, j, k)] = full.at(i, j, k);
      }
    }
    patient::WriteNrrd(ct, JoinPath(dir, "ct.nrrd"));
    std::ofstream(JoinPath(dir, "patient.yaml"))
        << "name: cut\nct: ct.nrrd\nunits: hounsfield\nintercostal: {left: true}\n"
        << "surfaces: {skin: 3000, ribs: 4000, heart: 2000}\n";
    const patient::ImportedPatient m_imported = patient::ImportCase(dir, {false, false});
    const patient::PatientModel& m = *m_imported.model;
    const patient::ImportReport& m_report = m_imported.report;
    EXPECT_NE(std::find(m.cut_faces.begin(), m.cut_faces.end(), "left"), m.cut_faces.end());
    bool warned = false;
    for (const auto& w : m_report.warnings) warned = warned || w.find("left face") != std::string::npos;
    EXPECT_TRUE(warned);
    ASSERT_FALSE(m.port_candidates.empty());
    const double face_x = ct.PatientPoint(nx - 0.5, 0, 0).x();
    for (const auto& c : m.port_candidates) {
      for (const auto& q : c.skin) {
        EXPECT_LE(q.x(), face_x - patient::PatientModel::kCutFaceMargin + 1e-9) << c.name;
      }
    }
  }
}

// The real contrast CT cropped close around the heart: the body is cut on every side; none of the
// spaces found there survives as a port candidate, and the import says so.
TEST(CutFaces, TotalSegmentatorCtaCropCarriesNoPortCandidatesOnItsCropFaces) {
  const std::string ct = test::SharedDataPath("ct/totalseg-cta-aorta/ct_cropped.nii.gz");
  const std::string heart = test::SharedDataPath("ct/totalseg-cta-aorta/DERIVED_heart_on_aorta_crop.nii.gz");
  TROCAR_REQUIRE_SHARED_FILE(ct);
  const std::string dir = testing::TempDir() + "/trocar-cta-crop";
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::ofstream(JoinPath(dir, "patient.yaml"))
      << "ct: " << ct << "\nheart: {mask: " << heart << "}\nintercostal: {left: true}\n";
  const patient::ImportedPatient m_imported = patient::ImportCase(dir, {false, false});
  const patient::PatientModel& m = *m_imported.model;
  const patient::ImportReport& m_report = m_imported.report;
  for (const char* face : {"left", "right", "anterior", "posterior"}) {
    EXPECT_NE(std::find(m.cut_faces.begin(), m.cut_faces.end(), face), m.cut_faces.end()) << face;
  }
  const patient::Volume volume = patient::LoadVolume(ct);
  const auto faces = patient::FindCutFaces(volume, patient::Segment(volume).body);
  for (const auto& c : m.port_candidates) {
    for (const auto& q : c.skin) {
      for (const auto& f : faces) {
        EXPECT_GE(patient::DistanceToCutFace(volume, f, q), patient::PatientModel::kCutFaceMargin) << c.name;
      }
    }
  }
  bool said = false;
  for (const auto& w : m_report.warnings) said = said || w.find("cut faces") != std::string::npos;
  EXPECT_TRUE(said);
}

TEST(CutFaces, FaceNamesFollowTheHeadersAxes) {
  patient::Volume v;
  v.size = Eigen::Vector3i(10, 12, 8);
  v.index_to_P = Eigen::Vector3d(-0.002, 0.002, 0.003).asDiagonal();  // RAS-like x: index runs right
  v.values.assign(static_cast<std::size_t>(v.voxel_count()), 0.f);
  patient::Mask body;
  body.size = v.size;
  body.inside.assign(v.values.size(), 0);
  for (int k = 0; k < 8; ++k) {
    for (int j = 3; j < 9; ++j) body.inside[v.Index(9, j, k)] = 1;  // touches i = 9 and k = 0, 7
  }
  std::vector<std::string> names;
  for (const auto& f : patient::FindCutFaces(v, body)) names.push_back(f.name);
  // i = 9 lies at the most negative x: the right; k runs superior. Named in the patient's order.
  EXPECT_EQ(names, (std::vector<std::string>{"right", "superior", "inferior"}));
}

// Target points beyond the scanned box are an error naming the target and the file.
TEST(Targets, PointsOutsideTheScanAreAnError) {
  const std::string dir = testing::TempDir() + "/trocar-target-outside";
  fs::remove_all(dir);
  patient::PhantomParameters p;
  p.voxel_size = 0.004;
  patient::WritePhantomCase(patient::GeneratePhantom(p), dir);
  auto lad = patient::LoadMarkups(JoinPath(dir, "markups/LAD.mrk.json"));
  lad[0].points.back().z() += 0.5;  // half a metre above the scan
  lad[0].normals.clear();
  patient::WriteMarkups(lad, JoinPath(dir, "markups/LAD.mrk.json"));
  const std::string error = ImportError(dir);
  EXPECT_NE(error.find("target 'LAD': 1 of 25 points lie outside the CT"), std::string::npos) << error;
  EXPECT_NE(error.find("LAD.mrk.json"), std::string::npos) << error;
}

}  // namespace
}  // namespace trocar
