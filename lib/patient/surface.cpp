#include "patient/surface.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>

#include <vtkCellArray.h>
#include <vtkDecimatePro.h>
#include <vtkFlyingEdges3D.h>
#include <vtkFloatArray.h>
#include <vtkImageData.h>
#include <vtkImageGaussianSmooth.h>
#include <vtkObjectFactory.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkQuadricDecimation.h>
#include <vtkSmartPointer.h>
#include <vtkWindowedSincPolyDataFilter.h>

#include "common/error.hpp"

namespace trocar::patient {

namespace {

// The mask's bounding box (voxels) and its boundary faces counted per axis (its staircase area,
// which sets how many triangles a contour at a given spacing has).
struct MaskExtent {
  Eigen::Vector3i lo, hi;
  Eigen::Vector3d faces = Eigen::Vector3d::Zero();
};

MaskExtent MeasureMask(const Volume& grid, const Mask& mask, const std::string& name) {
  MaskExtent e;
  e.lo = grid.size;
  e.hi = Eigen::Vector3i::Constant(-1);
  const long sx = 1, sy = grid.size.x(), sz = static_cast<long>(grid.size.x()) * grid.size.y();
  for (int k = 0; k < grid.size.z(); ++k) {
    for (int j = 0; j < grid.size.y(); ++j) {
      for (int i = 0; i < grid.size.x(); ++i) {
        const long n = grid.Index(i, j, k);
        if (mask.inside[n] == 0) continue;
        e.lo = e.lo.cwiseMin(Eigen::Vector3i(i, j, k));
        e.hi = e.hi.cwiseMax(Eigen::Vector3i(i, j, k));
        e.faces.x() +=
            (i == 0 || !mask.inside[n - sx]) + (i + 1 == grid.size.x() || !mask.inside[n + sx]);
        e.faces.y() +=
            (j == 0 || !mask.inside[n - sy]) + (j + 1 == grid.size.y() || !mask.inside[n + sy]);
        e.faces.z() +=
            (k == 0 || !mask.inside[n - sz]) + (k + 1 == grid.size.z() || !mask.inside[n + sz]);
      }
    }
  }
  TROCAR_THROW_UNLESS((e.hi.array() >= 0).all(),
                      name << ": the mask is empty, there is no surface");
  return e;
}

// A contour of the mask on a grid coarsened by `factor` (fine voxel offset + factor * (I, J, K)
// + [0, factor) in coarse voxel (I, J, K)).
struct Contour {
  vtkSmartPointer<vtkPolyData> poly;
  Eigen::Vector3i factor = Eigen::Vector3i::Ones(), offset = Eigen::Vector3i::Zero();
  Eigen::Vector3d coarse_spacing = Eigen::Vector3d::Zero();
  long contoured = 0;
};

// The coarse grid's image: each coarse voxel holds the fraction of its fine voxels inside the
// mask.
vtkSmartPointer<vtkImageData> BlockAverage(const Volume& grid, const Mask& mask,
                                           const MaskExtent& e, int pad, Contour* c) {
  c->offset = e.lo - c->factor * pad;
  const Eigen::Vector3i fine_extent = e.hi - e.lo + Eigen::Vector3i::Ones();
  Eigen::Vector3i dims;
  for (int a = 0; a < 3; ++a)
    dims[a] = (fine_extent[a] + c->factor[a] - 1) / c->factor[a] + 2 * pad;
  c->coarse_spacing = grid.spacing().cwiseProduct(c->factor.cast<double>());
  auto image = vtkSmartPointer<vtkImageData>::New();
  image->SetDimensions(dims.x(), dims.y(), dims.z());
  image->SetSpacing(c->coarse_spacing.x(), c->coarse_spacing.y(), c->coarse_spacing.z());
  image->SetOrigin(0, 0, 0);
  auto scalars = vtkSmartPointer<vtkFloatArray>::New();
  scalars->SetNumberOfTuples(static_cast<vtkIdType>(dims.x()) * dims.y() * dims.z());
  float* data = scalars->GetPointer(0);
  std::fill(data, data + static_cast<long>(dims.x()) * dims.y() * dims.z(), 0.f);
  const float share = 1.f / static_cast<float>(c->factor.prod());
  const Eigen::Vector3i& factor = c->factor;
  const Eigen::Vector3i& offset = c->offset;
  for (int gk = e.lo.z(); gk <= e.hi.z(); ++gk) {
    const int k = (gk - offset.z()) / factor.z();
    for (int gj = e.lo.y(); gj <= e.hi.y(); ++gj) {
      const int j = (gj - offset.y()) / factor.y();
      float* row = data + static_cast<long>(dims.x()) * (j + static_cast<long>(dims.y()) * k);
      for (int gi = e.lo.x(); gi <= e.hi.x(); ++gi) {
        if (mask.inside[grid.Index(gi, gj, gk)] != 0) row[(gi - offset.x()) / factor.x()] += share;
      }
    }
  }
  image->GetPointData()->SetScalars(scalars);
  return image;
}

// Flying edges at the half level, after a blur of `sigma_voxels` fine voxels (none at 0).
vtkSmartPointer<vtkPolyData> ContourImage(vtkImageData* image, double sigma_voxels,
                                          const Eigen::Vector3i& factor) {
  auto contour = vtkSmartPointer<vtkFlyingEdges3D>::New();
  if (sigma_voxels > 0.0) {
    auto blur = vtkSmartPointer<vtkImageGaussianSmooth>::New();
    blur->SetInputData(image);
    blur->SetDimensionality(3);
    // The same blur in metres as at full resolution (the block average blurs by itself too).
    blur->SetStandardDeviations(sigma_voxels / factor.x(), sigma_voxels / factor.y(),
                                sigma_voxels / factor.z());
    blur->SetRadiusFactors(3, 3, 3);
    contour->SetInputConnection(blur->GetOutputPort());
  } else {
    contour->SetInputData(image);
  }
  contour->SetValue(0, 0.5);
  contour->ComputeNormalsOff();
  contour->ComputeGradientsOff();
  contour->ComputeScalarsOff();
  contour->Update();
  return contour->GetOutput();
}

// Coarsening: a contour at spacing h has about kPerArea · area / h² triangles (flying edges;
// area = the staircase area counted above). The first guess is corrected by the count a contour
// actually gave, at most twice. A thin or scattered mask can average and blur away below the
// contour level on a coarse grid: then it is contoured at full resolution, and at last without
// the blur.
Contour ContourMask(const Volume& grid, const Mask& mask, const MaskExtent& e,
                    const SurfaceOptions& options, const std::string& name) {
  constexpr double kPerArea = 1.3;
  const Eigen::Vector3d spacing = grid.spacing();
  const double area = e.faces.x() * spacing.y() * spacing.z() +
                      e.faces.y() * spacing.x() * spacing.z() +
                      e.faces.z() * spacing.x() * spacing.y();
  const bool coarsen = options.contour_budget_factor > 0.0 && options.max_triangles > 0;
  const double wanted = options.contour_budget_factor * options.max_triangles;
  auto factor_for = [&](double h) {
    h = std::min(h, options.max_working_spacing);
    Eigen::Vector3i f;
    for (int a = 0; a < 3; ++a) f[a] = std::max(1, static_cast<int>(std::floor(h / spacing[a] + 1e-9)));
    return f;
  };
  double h = std::sqrt(kPerArea * area / std::max(wanted, 1.0));
  Contour c;
  c.factor = coarsen ? factor_for(h) : Eigen::Vector3i::Ones();
  const int pad = 2 + static_cast<int>(std::ceil(3.0 * options.blur_sigma_voxels));
  bool use_blur = options.blur_sigma_voxels > 0.0, fallback = false;
  for (int attempt = 0;; ++attempt) {
    const vtkSmartPointer<vtkImageData> image = BlockAverage(grid, mask, e, pad, &c);
    c.poly = ContourImage(image, use_blur ? options.blur_sigma_voxels : 0.0, c.factor);
    c.contoured = c.poly->GetNumberOfPolys();
    if (c.contoured == 0 && c.factor != Eigen::Vector3i::Ones()) {
      c.factor = Eigen::Vector3i::Ones();
      fallback = true;
      continue;
    }
    if (c.contoured == 0 && use_blur) {
      use_blur = false;
      fallback = true;
      continue;
    }
    TROCAR_THROW_UNLESS(c.contoured > 0, name << ": contouring the mask gave no triangles");
    if (!coarsen || fallback || attempt >= 2 || c.contoured <= 1.5 * wanted) break;
    h = c.coarse_spacing.maxCoeff() * std::sqrt(static_cast<double>(c.contoured) / wanted);
    const Eigen::Vector3i next = factor_for(h).cwiseMax(c.factor);
    if (next == c.factor) break;
    c.factor = next;
  }
  return c;
}

vtkSmartPointer<vtkPolyData> Smooth(vtkPolyData* poly, const SurfaceOptions& options) {
  auto smooth = vtkSmartPointer<vtkWindowedSincPolyDataFilter>::New();
  smooth->SetInputData(poly);
  smooth->SetNumberOfIterations(options.smoothing_iterations);
  smooth->SetPassBand(options.smoothing_passband);
  smooth->NormalizeCoordinatesOn();
  smooth->BoundarySmoothingOff();
  smooth->FeatureEdgeSmoothingOff();
  smooth->NonManifoldSmoothingOn();
  smooth->Update();
  return smooth->GetOutput();
}

// Into the patient frame: crop-local millimetres → grid index → P; degenerate triangles left out
// (counted).
TriangleMesh ToMesh(vtkPolyData* data, const Volume& grid, const Contour& c,
                    const std::string& name) {
  TriangleMesh mesh;
  mesh.source = name;
  vtkPoints* points = data->GetPoints();
  mesh.vertices.reserve(points->GetNumberOfPoints());
  for (vtkIdType v = 0; v < points->GetNumberOfPoints(); ++v) {
    double x[3];
    points->GetPoint(v, x);
    // A coarse voxel's centre is the centre of the fine voxels it covers.
    const Eigen::Vector3d ijk = Eigen::Vector3d(x[0], x[1], x[2])
                                    .cwiseQuotient(c.coarse_spacing)
                                    .cwiseProduct(c.factor.cast<double>()) +
                                c.offset.cast<double>() +
                                0.5 * (c.factor - Eigen::Vector3i::Ones()).cast<double>();
    mesh.vertices.push_back(grid.PatientPoint(ijk.x(), ijk.y(), ijk.z()));
  }
  vtkCellArray* polys = data->GetPolys();
  mesh.triangles.reserve(polys->GetNumberOfCells());
  auto ids = vtkSmartPointer<vtkIdList>::New();
  for (polys->InitTraversal(); polys->GetNextCell(ids);) {
    if (ids->GetNumberOfIds() != 3) continue;
    const Eigen::Vector3i t(static_cast<int>(ids->GetId(0)), static_cast<int>(ids->GetId(1)),
                            static_cast<int>(ids->GetId(2)));
    if (TriangleArea(mesh, t) > 0.0) {
      mesh.triangles.push_back(t);
    } else {
      ++mesh.degenerate_triangles_removed;
    }
  }
  return mesh;
}

// Quadric decimation (the better shape for its count) does not keep the topology: on thin parts
// (a vertebra's arch at 4 mm voxels) it can leave open and non-manifold edges. Then the
// topology-preserving decimation is used instead, and the result with the fewest open or
// non-manifold edges is kept.
TriangleMesh Decimate(vtkPolyData* poly, const Volume& grid, const Contour& c,
                      const SurfaceOptions& options, const std::string& name) {
  const double reduction = 1.0 - static_cast<double>(options.max_triangles) /
                                     static_cast<double>(poly->GetNumberOfPolys());
  auto quadric = vtkSmartPointer<vtkQuadricDecimation>::New();
  quadric->SetInputData(poly);
  quadric->SetTargetReduction(reduction);
  quadric->VolumePreservationOn();
  quadric->Update();
  TriangleMesh mesh = ToMesh(quadric->GetOutput(), grid, c, name);
  EdgeCounts edges = CountEdges(mesh);
  if (edges.boundary + edges.non_manifold > 0) {
    auto pro = vtkSmartPointer<vtkDecimatePro>::New();
    pro->SetInputData(poly);
    pro->SetTargetReduction(reduction);
    pro->PreserveTopologyOn();
    pro->SplittingOff();
    pro->BoundaryVertexDeletionOff();
    pro->Update();
    TriangleMesh kept = ToMesh(pro->GetOutput(), grid, c, name);
    const EdgeCounts kept_edges = CountEdges(kept);
    if (kept_edges.boundary + kept_edges.non_manifold < edges.boundary + edges.non_manifold &&
        static_cast<long>(kept.triangles.size()) <= options.max_triangles) {
      mesh = std::move(kept);
    }
  }
  return mesh;
}

}  // namespace

TriangleMesh ExtractSurface(const Volume& grid, const Mask& mask, const std::string& name,
                            const SurfaceOptions& options, SurfaceReport* report) {
  const auto start = std::chrono::steady_clock::now();
  // The import extracts surfaces on two threads, and VTK makes its object-factory registry on
  // the first New() without a lock: two threads both made one and one was lost (LeakSanitizer
  // caught it). A function-local static is made once, the other threads waiting for it.
  static vtkObjectFactoryCollection* const factories = vtkObjectFactory::GetRegisteredFactories();
  (void)factories;
  TROCAR_THROW_UNLESS(mask.size == grid.size, name << ": mask of " << mask.size.transpose()
                                                   << " voxels on a grid of "
                                                   << grid.size.transpose());
  TROCAR_THROW_UNLESS(options.max_triangles >= 0 && options.smoothing_iterations >= 0 &&
                          options.blur_sigma_voxels >= 0.0,
                      name << ": surface options must not be negative");
  const MaskExtent extent = MeasureMask(grid, mask, name);
  const Contour contour = ContourMask(grid, mask, extent, options, name);
  vtkSmartPointer<vtkPolyData> poly = contour.poly;
  if (options.smoothing_iterations > 0) poly = Smooth(poly, options);
  TriangleMesh mesh = options.max_triangles > 0 && poly->GetNumberOfPolys() > options.max_triangles
                          ? Decimate(poly, grid, contour, options, name)
                          : ToMesh(poly, grid, contour, name);
  TROCAR_THROW_UNLESS(!mesh.triangles.empty(), name << ": the surface has no triangles");
  // Outward winding whatever the grid's handedness (LPS grids from RAS files are mirrored).
  if (MeshSignedVolume(mesh) < 0.0) {
    for (auto& t : mesh.triangles) std::swap(t[1], t[2]);
  }
  if (report != nullptr) {
    report->contoured_triangles = contour.contoured;
    report->coarsening = contour.factor;
    report->triangles = static_cast<long>(mesh.triangles.size());
    report->seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
  return mesh;
}

}  // namespace trocar::patient
