#include <random>

#include <gtest/gtest.h>
#include "patient/patient_model.hpp"
#include <filesystem>

#include "common/error.hpp"
#include "patient/phantom.hpp"
#include "patient/segmentation.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

double Millilitres(const patient::Volume& ct, const patient::Mask& m) {
  return m.count() * std::abs(ct.index_to_P.determinant()) * 1e6;
}

double Dice(const patient::Mask& a, const patient::Mask& b) {
  long both = 0;
  for (std::size_t n = 0; n < a.inside.size(); ++n) both += a.inside[n] && b.inside[n];
  return 2.0 * both / double(a.count() + b.count());
}

Eigen::Vector3d Centroid(const patient::Volume& ct, const patient::Mask& m) {
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  long n = 0;
  for (int k = 0; k < ct.size.z(); ++k)
    for (int j = 0; j < ct.size.y(); ++j)
      for (int i = 0; i < ct.size.x(); ++i)
        if (m.inside[ct.Index(i, j, k)]) {
          sum += ct.PatientPoint(i, j, k);
          ++n;
        }
  return sum / double(n);
}

TEST(DistanceTransform, EqualsBruteForceOnRandomAnisotropicMasks) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < 20; ++trial) {
    patient::Volume grid;
    std::uniform_int_distribution<int> n(1, 12);
    grid.size = Eigen::Vector3i(n(rng), n(rng), n(rng));
    std::uniform_real_distribution<double> h(0.0005, 0.003);
    grid.index_to_P = Eigen::Vector3d(h(rng), h(rng), h(rng)).asDiagonal();
    patient::Mask mask;
    mask.size = grid.size;
    std::bernoulli_distribution on(trial % 3 == 0 ? 0.02 : 0.2);
    for (long v = 0; v < grid.voxel_count(); ++v) mask.inside.push_back(on(rng));
    const auto d2 = patient::SquaredDistanceToMask(grid, mask);
    for (int k = 0; k < grid.size.z(); ++k)
      for (int j = 0; j < grid.size.y(); ++j)
        for (int i = 0; i < grid.size.x(); ++i) {
          double best = HUGE_VAL;
          for (int c = 0; c < grid.size.z(); ++c)
            for (int b = 0; b < grid.size.y(); ++b)
              for (int a = 0; a < grid.size.x(); ++a)
                if (mask.inside[grid.Index(a, b, c)])
                  best = std::min(best, (grid.PatientPoint(i, j, k) - grid.PatientPoint(a, b, c)).squaredNorm());
          const float got = d2[grid.Index(i, j, k)];
          if (std::isinf(best)) {
            EXPECT_TRUE(std::isinf(got));
          } else {
            ASSERT_NEAR(got, best, 1e-6 * best + 1e-12) << "trial " << trial << " at " << i << "," << j << "," << k;
          }
        }
  }
}

TEST(Heart, FoundInThePhantomsContrastWhereItWasMade) {
  for (unsigned seed : {1u, 4u}) {
    SCOPED_TRACE(seed);
    patient::PhantomParameters p;
    p.seed = seed;
    p.voxel_size = 0.003;
    const patient::Phantom ph = patient::GeneratePhantom(p);
    const auto seg = patient::Segment(ph.ct);
    const patient::Mask heart = patient::SegmentHeartFromContrast(ph.ct, seg);
    patient::Mask truth;
    truth.size = ph.ct.size;
    truth.inside.assign(ph.ct.voxel_count(), 0);
    const Eigen::Vector3d c = ph.truth.heart_centre;
    for (int k = 0; k < ph.ct.size.z(); ++k)
      for (int j = 0; j < ph.ct.size.y(); ++j)
        for (int i = 0; i < ph.ct.size.x(); ++i)
          truth.inside[ph.ct.Index(i, j, k)] =
              ph.truth.HeartCoordinates(ph.ct.PatientPoint(i, j, k)).norm() <= 1.0;
    EXPECT_GT(Dice(heart, truth), 0.9);
    EXPECT_LT((Centroid(ph.ct, heart) - c).norm(), 0.005);
  }
}

TEST(Heart, TotalSegmentatorContrastCtAgreesWithItsHeartMask) {
  const std::string ct_path = test::SharedDataPath("ct/totalseg-pulmonary/ct_cropped.nii.gz");
  const std::string mask_path = test::SharedDataPath("ct/totalseg-pulmonary/heart.nii.gz");
  TROCAR_REQUIRE_SHARED_FILE(mask_path);
  const patient::Volume ct = patient::LoadVolume(ct_path);
  const patient::Mask reference = patient::ResampleMask(patient::LoadVolume(mask_path), ct);
  const patient::Mask heart = patient::SegmentHeartFromContrast(ct, patient::Segment(ct));
  std::cout << "totalseg heart " << Millilitres(ct, heart) << " ml vs mask " << Millilitres(ct, reference)
            << " ml, Dice " << Dice(heart, reference) << ", centroids "
            << (Centroid(ct, heart) - Centroid(ct, reference)).norm() * 1e3 << " mm apart\n";
  EXPECT_GT(Dice(heart, reference), 0.6);
}

TEST(Heart, Lidc2ContrastChestHasAnAdultHeartInTheLeftAnteriorChest) {
  const std::string path = test::SharedDataPath("ct/lidc2/ct.nhdr");
  TROCAR_REQUIRE_SHARED_FILE(path);
  const patient::Volume ct = patient::LoadVolume(path);
  const auto seg = patient::Segment(ct);
  const patient::Mask heart = patient::SegmentHeartFromContrast(ct, seg);
  const Eigen::Vector3d c = Centroid(ct, heart);
  const Eigen::Vector3d mid = 0.5 * (seg.body_min_P + seg.body_max_P);
  std::cout << "lidc2 heart " << Millilitres(ct, heart) << " ml, centroid " << c.transpose()
            << " body mid " << mid.transpose() << "\n";
  // The enhanced chambers (the right heart is brightest in this phase; the left ventricle is
  // barely enhanced and the descending aorta joins the pool, see docs/decisions.md).
  EXPECT_GT(Millilitres(ct, heart), 150.0);
  EXPECT_LT(Millilitres(ct, heart), 1500.0);
  EXPECT_GT(c.x(), mid.x() - 0.01);  // left of the midline (or on it)
  EXPECT_LT(c.y(), mid.y());         // anterior half
}

TEST(Heart, NoContrastIsAnErrorAskingForAMask) {
  patient::PhantomParameters p;
  p.voxel_size = 0.004;
  patient::Phantom ph = patient::GeneratePhantom(p);
  for (float& v : ph.ct.values) {
    if (v > 150.0f && v < 450.0f) v = 40.0f;  // blood as unenhanced as muscle
  }
  ph.ct.source = "plain.nrrd";
  const auto seg = patient::Segment(ph.ct);
  try {
    patient::SegmentHeartFromContrast(ph.ct, seg);
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("plain.nrrd: heart: no contrast-filled blood pool"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("heart.mask"), std::string::npos);
  }
}

// Without contrast (the phantom's blood made as dark as muscle), the heart is approximated from
// the mediastinum: it holds most of the true heart and is not the whole chest; on the contrast
// phantom detection still takes the blood pool, not the approximation.
TEST(Heart, WithoutContrastTheMediastinumApproximatesTheHeart) {
  for (unsigned seed : {1u, 3u, 5u}) {
    SCOPED_TRACE(seed);
    patient::PhantomParameters p;
    p.seed = seed;
    p.voxel_size = 0.003;
    patient::Phantom ph = patient::GeneratePhantom(p);
    EXPECT_TRUE(patient::TrySegmentHeartFromContrast(ph.ct, patient::Segment(ph.ct)).has_value());
    for (float& v : ph.ct.values) {
      if (v > 150.0f && v < 450.0f) v = 40.0f;
    }
    const auto seg = patient::Segment(ph.ct);
    EXPECT_FALSE(patient::TrySegmentHeartFromContrast(ph.ct, seg).has_value());
    const patient::Mask heart = patient::ApproximateHeartFromMediastinum(ph.ct, seg);
    patient::Mask truth;
    truth.size = ph.ct.size;
    truth.inside.assign(ph.ct.voxel_count(), 0);
    const Eigen::Vector3d c = ph.truth.heart_centre;
    long both = 0, in_truth = 0;
    for (int k = 0; k < ph.ct.size.z(); ++k)
      for (int j = 0; j < ph.ct.size.y(); ++j)
        for (int i = 0; i < ph.ct.size.x(); ++i) {
          const long n = ph.ct.Index(i, j, k);
          truth.inside[n] = ph.truth.HeartCoordinates(ph.ct.PatientPoint(i, j, k)).norm() <= 1.0;
          in_truth += truth.inside[n];
          both += truth.inside[n] && heart.inside[n];
        }
    const double recall = static_cast<double>(both) / in_truth;
    std::cout << "seed " << seed << ": approximation " << Millilitres(ph.ct, heart) << " ml, true heart "
              << Millilitres(ph.ct, truth) << " ml, recall " << recall << ", Dice " << Dice(heart, truth) << "\n";
    EXPECT_GT(recall, 0.7);
    EXPECT_LT(Millilitres(ph.ct, heart), 3.0 * Millilitres(ph.ct, truth));
    EXPECT_LT((Centroid(ph.ct, heart) - c).norm(), 0.03);
    if (seed != 1) continue;
    // Imported as a case that says nothing about contrast: detected, approximated, flagged.
    const std::string dir = ::testing::TempDir() + "/trocar_plain_heart";
    std::filesystem::remove_all(dir);
    p.voxel_size = 0.004;
    patient::Phantom plain = patient::GeneratePhantom(p);
    for (float& v : plain.ct.values) {
      if (v > 150.0f && v < 450.0f) v = 40.0f;
    }
    patient::WritePhantomCase(plain, dir);
    const patient::ImportedPatient m_imported = patient::ImportCase(dir, {false, false});
    const patient::PatientModel& m = *m_imported.model;
    const patient::ImportReport& m_report = m_imported.report;
    ASSERT_NE(m.Find("heart"), nullptr);
    bool flagged = false;
    for (const auto& w : m_report.warnings) flagged = flagged || w.find("APPROXIMATED from the mediastinum") != std::string::npos;
    EXPECT_TRUE(flagged);
  }
}

}  // namespace
}  // namespace trocar
