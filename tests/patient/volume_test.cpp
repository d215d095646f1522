#include "patient/volume.hpp"

#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>

#include <gtest/gtest.h>
#include <zlib.h>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

using patient::LoadVolume;
using patient::Volume;
using test::CompareMatrices;

constexpr double kMm = 1e-3;

TEST(LoadVolume, Lidc2ChestNrrd) {
  const std::string path = test::SharedDataPath("ct/lidc2/ct.nhdr");
  TROCAR_REQUIRE_SHARED_FILE(path);
  const Volume v = LoadVolume(path);
  EXPECT_EQ(v.size, Eigen::Vector3i(256, 256, 133));
  EXPECT_TRUE(CompareMatrices(v.index_to_P,
                              Eigen::Vector3d(1.40625, -1.40625, -2.5).asDiagonal().toDenseMatrix() * kMm, 1e-15));
  EXPECT_TRUE(CompareMatrices(v.spacing(), Eigen::Vector3d(1.40625, 1.40625, 2.5) * kMm, 1e-15));
  EXPECT_FALSE(v.hounsfield);  // 8-bit windowed
  const auto [lo, hi] = std::minmax_element(v.values.begin(), v.values.end());
  EXPECT_GE(*lo, 0.0f);
  EXPECT_LE(*hi, 255.0f);
  EXPECT_GT(*hi, 200.0f);  // bone is bright
}

TEST(LoadVolume, TotalSegmentatorNiftiInHounsfieldUnits) {
  const std::string path = test::SharedDataPath("ct/totalseg-pulmonary/ct_cropped.nii.gz");
  TROCAR_REQUIRE_SHARED_FILE(path);
  const Volume v = LoadVolume(path);
  EXPECT_EQ(v.size, Eigen::Vector3i(122, 102, 112));
  // The file's RAS sform diag(-1.5, -1.5, 1.5) mm is LPS diag(1.5, 1.5, 1.5) mm.
  EXPECT_TRUE(CompareMatrices(v.index_to_P, Eigen::Matrix3d::Identity() * 1.5 * kMm, 1e-12));
  EXPECT_TRUE(CompareMatrices(v.origin_P, Eigen::Vector3d(-71.658203125, -255.658203125, 576.2000122070312) * kMm, 1e-9));
  EXPECT_TRUE(v.hounsfield);
  EXPECT_LE(*std::min_element(v.values.begin(), v.values.end()), -900.0f);  // air
}

TEST(LoadVolume, HeartMaskRegistersOntoItsCtThroughTheAffines) {
  const std::string ct_path = test::SharedDataPath("ct/totalseg-pulmonary/ct_cropped.nii.gz");
  const std::string mask_path = test::SharedDataPath("ct/totalseg-pulmonary/heart.nii.gz");
  TROCAR_REQUIRE_SHARED_FILE(mask_path);
  const Volume ct = LoadVolume(ct_path);
  const Volume mask = LoadVolume(mask_path);
  EXPECT_EQ(mask.size, Eigen::Vector3i(233, 167, 191));
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  long count = 0;
  for (int k = 0; k < mask.size.z(); ++k) {
    for (int j = 0; j < mask.size.y(); ++j) {
      for (int i = 0; i < mask.size.x(); ++i) {
        if (mask.at(i, j, k) > 0.5f) {
          centroid += mask.PatientPoint(i, j, k);
          ++count;
        }
      }
    }
  }
  ASSERT_GT(count, 1000);
  centroid /= static_cast<double>(count);
  // The heart's centre lies inside the cropped CT, in blood/myocardium (contrast CT: 0..500 HU).
  const Eigen::Vector3d ijk = ct.IndexOf(centroid);
  ASSERT_TRUE((ijk.array() >= 0).all() && (ijk.array() < ct.size.cast<double>().array()).all())
      << ijk.transpose();
  double mean = 0;
  int n = 0;
  for (int dk = -2; dk <= 2; ++dk) {
    for (int dj = -2; dj <= 2; ++dj) {
      for (int di = -2; di <= 2; ++di) {
        mean += ct.at(int(ijk.x()) + di, int(ijk.y()) + dj, int(ijk.z()) + dk);
        ++n;
      }
    }
  }
  mean /= n;
  EXPECT_GT(mean, 0.0);
  EXPECT_LT(mean, 500.0);
  // Heart volume of an adult: 300 .. 1500 ml.
  const double voxel_ml = mask.index_to_P.determinant() * 1e6;
  EXPECT_GT(count * std::abs(voxel_ml), 300.0);
  EXPECT_LT(count * std::abs(voxel_ml), 1500.0);
}

Volume RandomVolume(std::mt19937* rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  Volume v;
  v.size = Eigen::Vector3i(7, 5, 4);
  const Eigen::Matrix3d R = Eigen::Quaterniond(u(*rng), u(*rng), u(*rng), u(*rng)).normalized().toRotationMatrix();
  v.index_to_P = R * Eigen::Vector3d(0.8, 1.1, 2.5).asDiagonal() * kMm;
  v.origin_P = Eigen::Vector3d(u(*rng), u(*rng), u(*rng)) * 0.2;
  for (long i = 0; i < v.voxel_count(); ++i) v.values.push_back(static_cast<float>(1000 * u(*rng)));
  return v;
}

// A minimal NIfTI-1 writer (sform in RAS mm), independent of the readers under test.
void WriteNifti(const Volume& v, const std::string& path) {
  std::string h(352, '\0');
  auto put = [&](std::size_t at, const void* data, std::size_t n) { std::memcpy(&h[at], data, n); };
  const std::int32_t size = 348;
  put(0, &size, 4);
  const std::int16_t dims[8] = {3, std::int16_t(v.size.x()), std::int16_t(v.size.y()), std::int16_t(v.size.z()), 1, 1, 1, 1};
  put(40, dims, 16);
  const std::int16_t datatype = 16, bitpix = 32, sform = 1;
  put(70, &datatype, 2);
  put(72, &bitpix, 2);
  const float offset = 352;
  put(108, &offset, 4);
  put(254, &sform, 2);
  const Eigen::Vector3d to_ras(-1, -1, 1);
  const Eigen::Matrix3d A = to_ras.asDiagonal() * v.index_to_P / kMm;
  const Eigen::Vector3d o = to_ras.asDiagonal() * v.origin_P / kMm;
  for (int r = 0; r < 3; ++r) {
    const float row[4] = {float(A(r, 0)), float(A(r, 1)), float(A(r, 2)), float(o[r])};
    put(280 + 16 * r, row, 16);
  }
  put(344, "n+1", 4);
  std::string data(v.values.size() * 4, '\0');
  std::memcpy(&data[0], v.values.data(), data.size());
  std::ofstream(path, std::ios::binary) << h << data;
}

TEST(LoadVolume, LpsAndRasHeadersImportToTheSameGeometry) {
  const std::string dir = ::testing::TempDir() + "/trocar_volume_spaces";
  std::filesystem::create_directories(dir);
  std::mt19937 rng(3);
  for (int trial = 0; trial < 20; ++trial) {
    const Volume original = RandomVolume(&rng);
    patient::WriteNrrd(original, dir + "/lps.nrrd", false);
    patient::WriteNrrd(original, dir + "/ras.nrrd", true);
    WriteNifti(original, dir + "/ras.nii");
    for (const char* name : {"lps.nrrd", "ras.nrrd", "ras.nii"}) {
      SCOPED_TRACE(name);
      const Volume v = LoadVolume(dir + "/" + name);
      EXPECT_EQ(v.size, original.size);
      // float32 in the NIfTI header: ~1e-7 relative.
      EXPECT_TRUE(CompareMatrices(v.index_to_P, original.index_to_P, 1e-9));
      EXPECT_TRUE(CompareMatrices(v.origin_P, original.origin_P, 1e-7));
      EXPECT_EQ(v.values, original.values);
    }
  }
}

TEST(LoadVolume, MetaImageRawAndCompressed) {
  const std::string dir = ::testing::TempDir() + "/trocar_volume_mha";
  std::filesystem::create_directories(dir);
  std::vector<std::int16_t> data(4 * 3 * 2);
  for (std::size_t i = 0; i < data.size(); ++i) data[i] = static_cast<std::int16_t>(-1000 + 100 * i);
  std::string raw(data.size() * 2, '\0');
  std::memcpy(&raw[0], data.data(), raw.size());
  const std::string header =
      "ObjectType = Image\nNDims = 3\nDimSize = 4 3 2\nElementSpacing = 0.5 0.6 2\n"
      "Offset = 10 -20 30\nTransformMatrix = 0 1 0 -1 0 0 0 0 1\nElementType = MET_SHORT\n";
  std::ofstream(dir + "/a.mha", std::ios::binary) << header << "ElementDataFile = LOCAL\n" << raw;
  uLongf size = compressBound(raw.size());
  std::string packed(size, '\0');
  compress(reinterpret_cast<Bytef*>(&packed[0]), &size, reinterpret_cast<const Bytef*>(raw.data()), raw.size());
  packed.resize(size);
  std::ofstream(dir + "/b.raw", std::ios::binary) << packed;
  std::ofstream(dir + "/b.mhd") << header << "CompressedData = True\nElementDataFile = b.raw\n";
  for (const char* name : {"a.mha", "b.mhd"}) {
    SCOPED_TRACE(name);
    const Volume v = LoadVolume(dir + "/" + name);
    EXPECT_EQ(v.size, Eigen::Vector3i(4, 3, 2));
    EXPECT_TRUE(CompareMatrices(v.PatientPoint(1, 0, 0), Eigen::Vector3d(10, -19.5, 30) * kMm, 1e-15));
    EXPECT_TRUE(CompareMatrices(v.PatientPoint(0, 1, 1), Eigen::Vector3d(9.4, -20, 32) * kMm, 1e-15));
    EXPECT_EQ(v.at(3, 2, 1), -1000.0f + 100.0f * 23);
    EXPECT_TRUE(v.hounsfield);
  }
}

class BadVolume : public ::testing::Test {
 protected:
  std::string Write(const std::string& name, const std::string& bytes) {
    const std::string dir = ::testing::TempDir() + "/trocar_bad_volume";
    std::filesystem::create_directories(dir);
    std::ofstream(dir + "/" + name, std::ios::binary) << bytes;
    return dir + "/" + name;
  }
  std::string Error(const std::string& path) {
    try {
      LoadVolume(path);
    } catch (const trocar::Error& e) {
      return e.what();
    }
    ADD_FAILURE() << path << " loaded";
    return "";
  }
};

#define EXPECT_CONTAINS(text, part) \
  EXPECT_NE(std::string(text).find(part), std::string::npos) << "message: " << (text)

const std::string kHeader =
    "NRRD0004\ntype: uint8\ndimension: 3\nspace: left-posterior-superior\nsizes: 4 4 4\n"
    "space directions: (1,0,0) (0,1,0) (0,0,1)\nspace origin: (0,0,0)\nencoding: raw\n\n";

TEST_F(BadVolume, TruncatedDataSaysHowShort) {
  const std::string path = Write("short.nrrd", kHeader + std::string(50, '\1'));
  EXPECT_EQ(Error(path), path + ": voxel data is truncated: 50 bytes, expected 64");
}

TEST_F(BadVolume, TruncatedGzipIsReported) {
  Volume v;
  v.index_to_P = 0.001 * Eigen::Matrix3d::Identity();
  v.size = Eigen::Vector3i(8, 8, 8);
  v.values.assign(512, 1.0f);
  const std::string good = ::testing::TempDir() + "/trocar_bad_volume_good.nrrd";
  patient::WriteNrrd(v, good);
  const std::string bytes = ReadTextFile(good);
  const std::string path = Write("cut.nrrd", bytes.substr(0, bytes.size() - 20));
  EXPECT_CONTAINS(Error(path), "compressed data is truncated");
}

TEST_F(BadVolume, GarbledHeadersNameTheField) {
  EXPECT_CONTAINS(Error(Write("magic.nrrd", "HELLO\n")), "not a NRRD file");
  std::string t = kHeader;
  t.replace(t.find("uint8"), 5, "complex");
  EXPECT_CONTAINS(Error(Write("type.nrrd", t + std::string(64, '\0'))), "field 'type': 'complex'");
  t = kHeader;
  t.replace(t.find("dimension: 3"), 12, "dimension: 4");
  EXPECT_CONTAINS(Error(Write("dim.nrrd", t)), "field 'dimension': 4");
  t = kHeader;
  t.replace(t.find("(0,1,0)"), 7, "(0,1)");
  EXPECT_CONTAINS(Error(Write("dir.nrrd", t)), "field 'space directions'");
  t = kHeader;
  t.replace(t.find("left-posterior-superior"), 23, "scanner-xyz");
  EXPECT_CONTAINS(Error(Write("space.nrrd", t)), "field 'space': 'scanner-xyz'");
  t = kHeader;
  t.replace(t.find("(0,0,1)"), 7, "(0,1,0)");
  EXPECT_CONTAINS(Error(Write("degenerate.nrrd", t + std::string(64, '\0'))), "degenerate");
  t = kHeader;
  t.replace(t.find("encoding: raw"), 13, "encoding: raw\ndata file: nowhere.raw");
  EXPECT_CONTAINS(Error(Write("detached.nrrd", t)), "field 'data file': 'nowhere.raw' not found");
}

TEST_F(BadVolume, NonFiniteVoxelsAreRefused) {
  Volume v;
  v.index_to_P = 0.001 * Eigen::Matrix3d::Identity();
  v.size = Eigen::Vector3i(2, 2, 2);
  v.values.assign(8, 1.0f);
  v.values[3] = NAN;
  const std::string path = ::testing::TempDir() + "/trocar_bad_volume_nan.nrrd";
  patient::WriteNrrd(v, path);
  EXPECT_CONTAINS(Error(path), "1 voxels are NaN or infinite");
}

TEST_F(BadVolume, NotANiftiAndUnknownExtensions) {
  EXPECT_CONTAINS(Error(Write("x.nii", std::string(400, 'x'))), "not a NIfTI-1 file");
  EXPECT_CONTAINS(Error(Write("x.vol", "data")), "unknown volume format");
  EXPECT_EQ(Error("/no/such/ct.nrrd"), "/no/such/ct.nrrd: CT volume not found");
}

}  // namespace
}  // namespace trocar
