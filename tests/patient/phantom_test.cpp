#include "patient/phantom.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <nlohmann/json.hpp>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "patient/case_file.hpp"
#include "patient/patient_model.hpp"
#include "patient/volume.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

using patient::Phantom;
using patient::PhantomHu;

// A coarse phantom keeps the tests fast; the default is 2 mm.
patient::PhantomParameters Coarse(unsigned seed) {
  patient::PhantomParameters p;
  p.seed = seed;
  p.voxel_size = 0.003;
  return p;
}

float ValueAt(const patient::Volume& v, const Eigen::Vector3d& p_P) {
  const Eigen::Vector3d ijk = v.IndexOf(p_P);
  return v.at(int(std::lround(ijk.x())), int(std::lround(ijk.y())), int(std::lround(ijk.z())));
}

TEST(Phantom, SameSeedSameVolumeOtherSeedOtherVolume) {
  const Phantom a = patient::GeneratePhantom(Coarse(1));
  const Phantom b = patient::GeneratePhantom(Coarse(1));
  const Phantom c = patient::GeneratePhantom(Coarse(2));
  EXPECT_EQ(a.ct.values, b.ct.values);
  EXPECT_NE(a.ct.values, c.ct.values);
  EXPECT_TRUE(a.ct.hounsfield);
}

TEST(Phantom, AnatomyIsWhereTheTruthSaysItIs) {
  for (unsigned seed : {1u, 2u, 3u}) {
    const Phantom ph = patient::GeneratePhantom(Coarse(seed));
    const auto& t = ph.truth;
    ASSERT_EQ(t.ribs.size(), 18u);
    for (const auto& rib : t.ribs) {
      for (std::size_t s = 5; s + 5 < rib.centreline.size(); s += 5) {
        EXPECT_EQ(ValueAt(ph.ct, rib.centreline[s]), PhantomHu::kBone)
            << "seed " << seed << " rib " << rib.side << "/" << rib.index;
      }
    }
    // The middle of each intercostal space, at the depth of the ribs, is soft tissue, not bone.
    ASSERT_EQ(t.intercostal_spaces.size(), 16u);
    for (std::size_t s = 0; s < t.intercostal_spaces.size(); ++s) {
      const Eigen::Vector3d skin = t.intercostal_spaces[s][15];
      const auto& upper = t.ribs[(t.intercostal_side[s] > 0 ? 0 : 9) + s % 8].centreline;
      // Bring the skin point in to the ribs' ellipse at the same angle and height.
      const double scale = std::hypot(upper[40].x(), upper[40].y()) / std::hypot(skin.x(), skin.y());
      const Eigen::Vector3d inside(skin.x() * scale, skin.y() * scale, skin.z());
      EXPECT_NE(ValueAt(ph.ct, inside), PhantomHu::kBone) << "space " << s;
      EXPECT_EQ(ValueAt(ph.ct, skin + Eigen::Vector3d(0, 0, 0) * 0), ValueAt(ph.ct, skin));
    }
    EXPECT_EQ(ValueAt(ph.ct, t.heart_centre), PhantomHu::kBlood);
    for (std::size_t s = 2; s + 2 < t.lad.size(); ++s) EXPECT_EQ(ValueAt(ph.ct, t.lad[s]), PhantomHu::kArtery);
    for (std::size_t s = 1; s + 1 < t.lima.size(); ++s) EXPECT_EQ(ValueAt(ph.ct, t.lima[s]), PhantomHu::kArtery);
    // Lung beside the heart, air outside the body.
    EXPECT_EQ(ValueAt(ph.ct, Eigen::Vector3d(-0.09, 0.02, t.heart_centre.z())), PhantomHu::kLung);
    EXPECT_EQ(ValueAt(ph.ct, ph.ct.PatientPoint(0, 0, 0)), PhantomHu::kAir);
    // LAD normals point away from the heart and forward (anterior is −y).
    for (std::size_t s = 0; s < t.lad.size(); ++s) {
      EXPECT_GT(t.lad_normals[s].dot(t.lad[s] - t.heart_centre), 0.0);
      EXPECT_LT(t.lad_normals[s].y(), 0.0);
    }
  }
}

TEST(Phantom, WrittenWithLpsOrRasHeadersImportsToTheSameGeometry) {
  const Phantom ph = patient::GeneratePhantom(Coarse(4));
  const std::string lps = ::testing::TempDir() + "/trocar_phantom_lps";
  const std::string ras = ::testing::TempDir() + "/trocar_phantom_ras";
  patient::WritePhantomCase(ph, lps, patient::CtFormat::kNrrdLps);
  patient::WritePhantomCase(ph, ras, patient::CtFormat::kNrrdRas);
  const patient::Volume a = patient::LoadVolume(lps + "/ct.nrrd");
  const patient::Volume b = patient::LoadVolume(ras + "/ct.nrrd");
  EXPECT_TRUE(test::CompareMatrices(a.index_to_P, b.index_to_P, 1e-15));
  EXPECT_TRUE(test::CompareMatrices(a.origin_P, b.origin_P, 1e-15));
  EXPECT_EQ(a.values, b.values);
  EXPECT_EQ(a.values, ph.ct.values);
  EXPECT_TRUE(a.hounsfield);
  // The markups are 3D Slicer curves in LPS millimetres.
  const auto lad = nlohmann::json::parse(ReadTextFile(lps + "/markups/LAD.mrk.json"));
  ASSERT_EQ(lad["markups"].size(), 1u);
  EXPECT_EQ(lad["markups"][0]["coordinateSystem"], "LPS");
  EXPECT_EQ(lad["markups"][0]["controlPoints"].size(), ph.truth.lad.size());
  const auto p0 = lad["markups"][0]["controlPoints"][0]["position"];
  EXPECT_NEAR(p0[0].get<double>(), ph.truth.lad[0].x() * 1e3, 1e-9);
  const auto spaces = nlohmann::json::parse(ReadTextFile(lps + "/markups/intercostal_left.mrk.json"));
  EXPECT_EQ(spaces["markups"].size(), 8u);
  EXPECT_TRUE(IsRegularFile(lps + "/patient.yaml"));
}

TEST(Phantom, SlicesAreShownInTheRadiologicalConvention) {
  // Axial slice through the heart: anterior (the sternum) at the top, the patient's left (the
  // heart) on the image's right.
  const Phantom ph = patient::GeneratePhantom(Coarse(5));
  const Eigen::Vector3d ijk = ph.ct.IndexOf(ph.truth.heart_centre);
  const auto slice = patient::RenderSlice(ph.ct, 2, int(std::lround(ijk.z())), 40, 1200);
  double blood_column = 0, bone_row = 0;
  int blood = 0, bone = 0;
  const unsigned char blood_grey = static_cast<unsigned char>(std::lround(255.0 * (PhantomHu::kBlood + 560) / 1200));
  for (int r = 0; r < slice.height; ++r) {
    for (int c = 0; c < slice.width; ++c) {
      const unsigned char g = slice.rgb[3 * (static_cast<std::size_t>(r) * slice.width + c)];
      if (g == blood_grey) { blood_column += c; ++blood; }
      if (g == 255 && std::abs(c - slice.width / 2) < 5) { bone_row += r; ++bone; }
    }
  }
  ASSERT_GT(blood, 50);
  ASSERT_GT(bone, 5);
  EXPECT_GT(blood_column / blood, slice.width / 2.0);  // heart on the image's right
  // Sternum above the vertebra along the midline: the first bone rows are near the top.
  EXPECT_LT(bone_row / bone, slice.height * 0.75);
  EXPECT_THROW(patient::RenderSlice(ph.ct, 3, 0, 0, 1), Error);
}

// A clinical grid (a square field of view, slices apart from the in-plane spacing) is written into
// the case's patient.yaml exactly enough that the CT regenerated from it has the same grid.
TEST(Phantom, ClinicalGridRoundTripsThroughTheCaseFile) {
  const std::string dir = testing::TempDir() + "/trocar-phantom-grid";
  std::filesystem::remove_all(dir);
  patient::PhantomParameters p;
  p.field_of_view = 0.41;
  p.voxel_size = p.field_of_view / 97;  // 4.2268... mm, not a short decimal
  p.slice_spacing = 0.0037;
  const patient::Phantom ph = patient::GeneratePhantom(p);
  EXPECT_EQ(ph.ct.size.x(), 97);
  EXPECT_EQ(ph.ct.size.y(), 97);
  EXPECT_NEAR(ph.ct.spacing().z(), 0.0037, 1e-12);
  patient::WritePhantomCase(ph, dir);
  const patient::Volume written = patient::LoadVolume(JoinPath(dir, "ct.nrrd"));
  std::filesystem::remove(JoinPath(dir, "ct.nrrd"));
  patient::ImportPatient(dir, {false, false});  // regenerates the CT from patient.yaml
  const patient::Volume again = patient::LoadVolume(JoinPath(dir, "ct.nrrd"));
  EXPECT_EQ(again.size, written.size);
  EXPECT_TRUE(again.index_to_P.isApprox(written.index_to_P, 1e-9));
  EXPECT_TRUE(again.origin_P.isApprox(written.origin_P, 1e-9));
  // A field of view that does not hold the body is refused, naming it.
  p.field_of_view = 0.2;
  EXPECT_THROW(patient::GeneratePhantom(p), Error);
}

// Every parameter away from its default is written into the case's patient.yaml and read back:
// the CT regenerated from the record is the phantom the user asked for, voxel for voxel (the
// record once left out the fat, so `trocar phantom --fat 0.06` regenerated a lean phantom).
TEST(Phantom, EveryParameterRoundTripsThroughTheCaseFile) {
  const std::string dir = testing::TempDir() + "/trocar-phantom-record";
  std::filesystem::remove_all(dir);
  patient::PhantomParameters p;
  p.seed = 5;
  p.body_width = 0.37;
  p.body_depth = 0.27;
  p.length = 0.31;
  p.fat_thickness = 0.031;
  p.wall_thickness = 0.021;
  p.ribs_per_side = 8;
  p.rib_spacing = 0.026;
  p.rib_radius = 0.0047;
  p.rib_drop = 0.043;
  p.heart_scale = 0.93;
  p.heart_offset = Eigen::Vector3d(0.004, -0.003, 0.006);
  p.voxel_size = 0.004;
  p.slice_spacing = 0.005;
  p.field_of_view = 0.56;
  p.ribs_reach_spine = true;
  p.shoulders = true;
  p.table_gap = 0.01;
  const patient::Phantom ph = patient::GeneratePhantom(p);
  patient::WritePhantomCase(ph, dir);
  const patient::CaseSpec c = patient::ReadCase(dir);
  ASSERT_TRUE(c.has_phantom);
  const patient::PhantomParameters& q = c.phantom;
  EXPECT_EQ(q.seed, p.seed);
  EXPECT_EQ(q.body_width, p.body_width);
  EXPECT_EQ(q.body_depth, p.body_depth);
  EXPECT_EQ(q.length, p.length);
  EXPECT_EQ(q.fat_thickness, p.fat_thickness);
  EXPECT_EQ(q.wall_thickness, p.wall_thickness);
  EXPECT_EQ(q.ribs_per_side, p.ribs_per_side);
  EXPECT_EQ(q.rib_spacing, p.rib_spacing);
  EXPECT_EQ(q.rib_radius, p.rib_radius);
  EXPECT_EQ(q.rib_drop, p.rib_drop);
  EXPECT_EQ(q.heart_scale, p.heart_scale);
  EXPECT_EQ(q.heart_offset, p.heart_offset);
  EXPECT_EQ(q.voxel_size, p.voxel_size);
  EXPECT_EQ(q.slice_spacing, p.slice_spacing);
  EXPECT_EQ(q.field_of_view, p.field_of_view);
  EXPECT_EQ(q.ribs_reach_spine, p.ribs_reach_spine);
  EXPECT_EQ(q.shoulders, p.shoulders);
  EXPECT_EQ(q.table_gap, p.table_gap);
  // And the CT made from the record is the one written.
  const patient::Phantom again = patient::GeneratePhantom(q);
  ASSERT_EQ(again.ct.size, ph.ct.size);
  long differ = 0;
  for (std::size_t v = 0; v < ph.ct.values.size(); ++v)
    differ += again.ct.values[v] != ph.ct.values[v];
  EXPECT_EQ(differ, 0) << "of " << ph.ct.values.size() << " voxels";
}

TEST(Phantom, RefusesParametersOutOfRange) {
  auto p = Coarse(1);
  p.body_width = 2.0;
  try {
    patient::GeneratePhantom(p);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(std::string(e.what()), "phantom: body_width = 2 is outside [0.2, 0.6]");
  }
  p = Coarse(1);
  p.ribs_per_side = 12;
  p.rib_spacing = 0.05;
  EXPECT_THROW(patient::GeneratePhantom(p), Error);
  p = Coarse(1);
  p.heart_offset = Eigen::Vector3d(NAN, 0, 0);
  EXPECT_THROW(patient::GeneratePhantom(p), Error);
}

}  // namespace
}  // namespace trocar
