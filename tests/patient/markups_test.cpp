#include "patient/markups.hpp"

#include <fstream>

#include <gtest/gtest.h>

#include "common/error.hpp"
#include "patient/phantom.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

TEST(Markups, ThePhantomsMarkupsReadBackOntoItsTruth) {
  patient::PhantomParameters p;
  p.voxel_size = 0.004;
  const patient::Phantom ph = patient::GeneratePhantom(p);
  const std::string dir = ::testing::TempDir() + "/trocar_markups_case";
  patient::WritePhantomCase(ph, dir);
  const auto lad = patient::LoadMarkups(dir + "/markups/LAD.mrk.json");
  ASSERT_EQ(lad.size(), 1u);
  EXPECT_EQ(lad[0].name, "LAD");
  EXPECT_EQ(lad[0].type, "Curve");
  ASSERT_EQ(lad[0].points.size(), ph.truth.lad.size());
  for (std::size_t i = 0; i < lad[0].points.size(); ++i) {
    EXPECT_TRUE(test::CompareMatrices(lad[0].points[i], ph.truth.lad[i], 1e-12));
  }
  EXPECT_EQ(patient::LoadMarkups(dir + "/markups/intercostal_left.mrk.json").size(), 8u);
}

class BadMarkups : public ::testing::Test {
 protected:
  std::string Write(const std::string& text) {
    const std::string path = ::testing::TempDir() + "/trocar_markups_" +
                             ::testing::UnitTest::GetInstance()->current_test_info()->name() + ".mrk.json";
    std::ofstream(path) << text;
    return path;
  }
  std::string Error(const std::string& path) {
    try {
      patient::LoadMarkups(path);
    } catch (const trocar::Error& e) {
      return e.what();
    }
    ADD_FAILURE() << "accepted " << path;
    return "";
  }
};

TEST_F(BadMarkups, RasFilesAreConvertedToLps) {
  const std::string path = Write(R"({"markups": [{"type": "Fiducial", "name": "port",
      "coordinateSystem": "RAS", "controlPoints": [{"position": [10, 20, 30]}]}]})");
  const auto m = patient::LoadMarkups(path);
  EXPECT_TRUE(test::CompareMatrices(m[0].points[0], Eigen::Vector3d(-0.01, -0.02, 0.03), 1e-15));
}

TEST_F(BadMarkups, ErrorsNameTheFileAndField) {
  std::string path = Write(R"({"markups": [{"coordinateSystem": "IJK", "controlPoints": []}]})");
  EXPECT_EQ(Error(path), path + ": markups[0].coordinateSystem: 'IJK' (expected LPS or RAS)");
  path = Write(R"({"markups": [{"controlPoints": [{"label": "a"}]}]})");
  EXPECT_EQ(Error(path), path + ": markups[0].controlPoints[0]: missing field 'position' (three numbers)");
  path = Write(R"({"markups": [{"controlPoints": [{"position": [1, "x", 3]}]}]})");
  EXPECT_EQ(Error(path), path + ": markups[0].controlPoints[0].position[1]: expected a number");
  path = Write(R"({"markups": [{"name": "LAD", "controlPoints": []}]})");
  EXPECT_EQ(Error(path), path + ": markups[0] ('LAD'): no control points");
  path = Write(R"({"points": []})");
  EXPECT_EQ(Error(path), path + ": missing field 'markups' (expected a 3D Slicer .mrk.json file)");
  path = Write(R"({"markups": [)");
  EXPECT_NE(Error(path).find(path + ": not valid JSON"), std::string::npos);
  path = Write(R"({"markups": [{"coordinateUnits": "inch", "controlPoints": []}]})");
  EXPECT_EQ(Error(path), path + ": markups[0].coordinateUnits: 'inch' (expected mm or m)");
}

}  // namespace
}  // namespace trocar
