#include "patient/surface.hpp"

#include <random>

#include <gtest/gtest.h>

#include "common/error.hpp"
#include "robot/mesh.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

// A grid with random orientation (possibly mirrored, as LPS grids from RAS files are) and
// anisotropic spacing, and a ball mask on it.
struct BallCase {
  patient::Volume grid;
  patient::Mask mask;
  Eigen::Vector3d centre_P;
  double radius = 0.0;
};

BallCase MakeBall(unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  BallCase c;
  const Eigen::Vector3d spacing(0.0008 + 0.0004 * (u(rng) + 1), 0.0008 + 0.0004 * (u(rng) + 1),
                                0.001 + 0.0005 * (u(rng) + 1));
  Eigen::Matrix3d R = Eigen::Quaterniond::UnitRandom().toRotationMatrix();
  if (seed % 2 == 1) R.col(0) *= -1.0;  // left-handed index axes
  c.grid.size = Eigen::Vector3i(64, 60, 50);
  c.grid.index_to_P = R * spacing.asDiagonal();
  c.grid.origin_P = Eigen::Vector3d(u(rng), u(rng), u(rng)) * 0.1;
  c.radius = 0.018 + 0.004 * u(rng);
  c.centre_P = c.grid.PatientPoint(31.3, 29.7, 24.6);
  c.mask.size = c.grid.size;
  c.mask.inside.assign(c.grid.voxel_count(), 0);
  for (int k = 0; k < c.grid.size.z(); ++k) {
    for (int j = 0; j < c.grid.size.y(); ++j) {
      for (int i = 0; i < c.grid.size.x(); ++i) {
        c.mask.inside[c.grid.Index(i, j, k)] =
            (c.grid.PatientPoint(i, j, k) - c.centre_P).norm() <= c.radius ? 1 : 0;
      }
    }
  }
  return c;
}

// A mask of scattered single voxels (a thin or broken structure, as a windowed scan's sternum
// that contrast swallowed) averages and blurs away below the contour level on a coarse grid, and
// even at full resolution under the blur: it is contoured all the same, small blobs about the
// voxels (decimated to the budget, not always closed), instead of failing the import.
TEST(Surface, ScatteredVoxelsAreContouredAtFullResolutionWithoutTheBlur) {
  for (unsigned seed = 1; seed <= 3; ++seed) {
    SCOPED_TRACE(seed);
    BallCase c = MakeBall(seed);
    std::fill(c.mask.inside.begin(), c.mask.inside.end(), 0);
    std::mt19937 rng(seed);
    std::vector<Eigen::Vector3i> voxels;
    for (int n = 0; n < 30; ++n) {
      const Eigen::Vector3i v(4 * (1 + static_cast<int>(rng() % 14)),
                              4 * (1 + static_cast<int>(rng() % 13)),
                              4 * (1 + static_cast<int>(rng() % 11)));
      c.mask.inside[c.grid.Index(v.x(), v.y(), v.z())] = 1;
      voxels.push_back(v);
    }
    patient::SurfaceOptions options;
    options.max_triangles = 200;  // coarsened first
    const TriangleMesh mesh = patient::ExtractSurface(c.grid, c.mask, "sternum", options);
    ASSERT_GT(mesh.triangles.size(), 0u);
    EXPECT_NO_THROW(ValidateMesh(mesh, "sternum"));
    const double h = c.grid.spacing().maxCoeff();
    for (const auto& p : mesh.vertices) {
      double nearest = HUGE_VAL;
      for (const auto& v : voxels)
        nearest = std::min(nearest, (c.grid.PatientPoint(v.x(), v.y(), v.z()) - p).norm());
      ASSERT_LT(nearest, h);
    }
  }
}

TEST(Surface, BallOnAnyGridIsAClosedOutwardSphereWithinTheBudget) {
  for (unsigned seed = 1; seed <= 6; ++seed) {
    SCOPED_TRACE(seed);
    const BallCase c = MakeBall(seed);
    patient::SurfaceOptions options;
    options.max_triangles = 3000;
    patient::SurfaceReport report;
    const TriangleMesh mesh = patient::ExtractSurface(c.grid, c.mask, "ball", options, &report);
    EXPECT_NO_THROW(ValidateMesh(mesh, "ball"));
    EXPECT_LE(report.triangles, 3000);
    EXPECT_GT(report.contoured_triangles, report.triangles);
    const EdgeCounts edges = CountEdges(mesh);
    EXPECT_EQ(edges.boundary, 0);
    EXPECT_EQ(edges.non_manifold, 0);
    // Outward winding and the ball's volume and radius, to a fraction of a voxel.
    const double volume = MeshSignedVolume(mesh);
    const double truth = 4.0 / 3.0 * M_PI * std::pow(c.radius, 3);
    EXPECT_NEAR(volume / truth, 1.0, 0.06);
    const double h = c.grid.spacing().maxCoeff();
    for (const auto& v : mesh.vertices) {
      ASSERT_NEAR((v - c.centre_P).norm(), c.radius, 0.6 * h);
    }
    for (const auto& t : mesh.triangles) {
      const Eigen::Vector3d a = mesh.vertices[t[0]], b = mesh.vertices[t[1]], d = mesh.vertices[t[2]];
      const Eigen::Vector3d n = (b - a).cross(d - a);
      EXPECT_GT(n.dot((a + b + d) / 3.0 - c.centre_P), 0.0);
    }
  }
}

// A small budget on a fine grid: the mask is contoured on a coarsened grid (block fractions), and
// the surface stays where it was: centred (a coarse voxel's centre is its fine voxels' centre),
// the ball's radius and volume, closed and outward.
TEST(Surface, CoarsenedContourKeepsTheSurfaceInPlace) {
  for (unsigned seed = 1; seed <= 6; ++seed) {
    SCOPED_TRACE(seed);
    const BallCase c = MakeBall(seed);
    patient::SurfaceOptions options;
    options.max_triangles = 400;
    options.max_working_spacing = 0.004;
    patient::SurfaceReport report;
    const TriangleMesh mesh = patient::ExtractSurface(c.grid, c.mask, "ball", options, &report);
    EXPECT_GE(report.coarsening.maxCoeff(), 2) << report.coarsening.transpose();
    // About contour_budget_factor × the budget: far fewer than at full resolution.
    EXPECT_LE(report.contoured_triangles, 3 * options.contour_budget_factor * options.max_triangles);
    patient::SurfaceOptions full = options;
    full.contour_budget_factor = 0.0;
    patient::SurfaceReport full_report;
    patient::ExtractSurface(c.grid, c.mask, "ball", full, &full_report);
    EXPECT_EQ(full_report.coarsening, Eigen::Vector3i::Ones());
    EXPECT_GT(full_report.contoured_triangles, 2 * report.contoured_triangles);

    EXPECT_NO_THROW(ValidateMesh(mesh, "ball"));
    const EdgeCounts edges = CountEdges(mesh);
    EXPECT_EQ(edges.boundary, 0);
    EXPECT_EQ(edges.non_manifold, 0);
    const double truth = 4.0 / 3.0 * M_PI * std::pow(c.radius, 3);
    EXPECT_NEAR(MeshSignedVolume(mesh) / truth, 1.0, 0.06);
    const double fine = c.grid.spacing().maxCoeff();
    for (const auto& v : mesh.vertices) ASSERT_NEAR((v - c.centre_P).norm(), c.radius, 1.2 * fine);
    // The enclosed volume's centroid (tetrahedra from the true centre) is the ball's centre.
    Eigen::Vector3d moment = Eigen::Vector3d::Zero();
    double volume = 0.0;
    for (const auto& t : mesh.triangles) {
      const Eigen::Vector3d a = mesh.vertices[t[0]] - c.centre_P, b = mesh.vertices[t[1]] - c.centre_P,
                            d = mesh.vertices[t[2]] - c.centre_P;
      const double v = a.dot(b.cross(d)) / 6.0;
      volume += v;
      moment += v * (a + b + d) / 4.0;
    }
    EXPECT_LT((moment / volume).norm(), 0.1 * fine);
  }
}

TEST(Surface, EmptyOrMismatchedMasksAreErrorsNamingTheStructure) {
  BallCase c = MakeBall(2);
  patient::Mask empty = c.mask;
  std::fill(empty.inside.begin(), empty.inside.end(), 0);
  try {
    patient::ExtractSurface(c.grid, empty, "heart");
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("heart: the mask is empty"), std::string::npos) << e.what();
  }
  patient::Mask wrong = c.mask;
  wrong.size.x() -= 1;
  EXPECT_THROW(patient::ExtractSurface(c.grid, wrong, "skin"), Error);
}

TEST(Mesh, StlRoundTripsThroughAssimp) {
  const BallCase c = MakeBall(3);
  patient::SurfaceOptions options;
  options.max_triangles = 500;
  const TriangleMesh mesh = patient::ExtractSurface(c.grid, c.mask, "ball", options);
  const std::string path = testing::TempDir() + "/ball.stl";
  WriteStl(mesh, path, /*mm=*/false);
  const auto back = robot::LoadMesh(path);
  EXPECT_EQ(back->triangles.size() + back->degenerate_triangles_removed, mesh.triangles.size());
  EXPECT_NEAR(MeshSignedVolume(*back), MeshSignedVolume(mesh), 1e-3 * MeshSignedVolume(mesh));
}

}  // namespace
}  // namespace trocar
