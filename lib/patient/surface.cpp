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

TriangleMesh ExtractSurface(const Volume& grid, const Mask& mask, const std::string& name,
                            const SurfaceOptions& options, SurfaceReport* report) {
  const auto start = std::chrono::steady_clock::now();
  // The import extracts surfaces on two threads, and VTK makes its object-factory registry on
  // the first New() without a lock: two threads both made one and one was lost (LeakSanitizer
  // caught it). A function-local static is made once, the other threads waiting for it.
  static vtkObjectFactoryCollection* const factories = vtkObjectFactory::GetRegisteredFactories();
  (void)factories;
  TROCAR_THROW_UNLESS(mask.size == grid.size,
                      name << ": mask of " << mask.size.transpose() << " voxels on a grid of "
                           << grid.size.transpose());
  TROCAR_THROW_UNLESS(options.max_triangles >= 0 && options.smoothing_iterations >= 0 &&
                          options.blur_sigma_voxels >= 0.0,
                      name << ": surface options must not be negative");
  // Crop to the mask's bounding box; count the mask's boundary faces per axis on the way (its
  // staircase area, which sets how many triangles a contour at a given spacing has).
  const Eigen::Vector3d spacing = grid.spacing();
  Eigen::Vector3i lo = grid.size, hi = Eigen::Vector3i::Constant(-1);
  Eigen::Vector3d faces = Eigen::Vector3d::Zero();
  const long sx = 1, sy = grid.size.x(), sz = static_cast<long>(grid.size.x()) * grid.size.y();
  for (int k = 0; k < grid.size.z(); ++k) {
    for (int j = 0; j < grid.size.y(); ++j) {
      for (int i = 0; i < grid.size.x(); ++i) {
        const long n = grid.Index(i, j, k);
        if (mask.inside[n] == 0) continue;
        lo = lo.cwiseMin(Eigen::Vector3i(i, j, k));
        hi = hi.cwiseMax(Eigen::Vector3i(i, j, k));
        faces.x() += (i == 0 || !mask.inside[n - sx]) + (i + 1 == grid.size.x() || !mask.inside[n + sx]);
        faces.y() += (j == 0 || !mask.inside[n - sy]) + (j + 1 == grid.size.y() || !mask.inside[n + sy]);
        faces.z() += (k == 0 || !mask.inside[n - sz]) + (k + 1 == grid.size.z() || !mask.inside[n + sz]);
      }
    }
  }
  TROCAR_THROW_UNLESS((hi.array() >= 0).all(), name << ": the mask is empty, there is no surface");

  // Coarsening: a contour at spacing h has about kPerArea · area / h² triangles (flying edges;
  // area = the staircase area counted above). The first guess is corrected by the count a contour
  // actually gave, at most twice.
  constexpr double kPerArea = 1.3;
  const double area = faces.x() * spacing.y() * spacing.z() + faces.y() * spacing.x() * spacing.z() +
                      faces.z() * spacing.x() * spacing.y();
  const bool coarsen = options.contour_budget_factor > 0.0 && options.max_triangles > 0;
  const double wanted = options.contour_budget_factor * options.max_triangles;
  auto factor_for = [&](double h) {
    h = std::min(h, options.max_working_spacing);
    Eigen::Vector3i f;
    for (int a = 0; a < 3; ++a) f[a] = std::max(1, static_cast<int>(std::floor(h / spacing[a] + 1e-9)));
    return f;
  };
  double h = std::sqrt(kPerArea * area / std::max(wanted, 1.0));
  Eigen::Vector3i factor = coarsen ? factor_for(h) : Eigen::Vector3i::Ones();
  const int pad = 2 + static_cast<int>(std::ceil(3.0 * options.blur_sigma_voxels));
  Eigen::Vector3i offset;
  Eigen::Vector3d coarse_spacing;
  vtkSmartPointer<vtkPolyData> poly;
  long contoured = 0;
  // A thin or scattered mask can average and blur away below the contour level on a coarse grid:
  // then it is contoured at full resolution, and at last without the blur.
  bool use_blur = options.blur_sigma_voxels > 0.0, fallback = false;
  for (int attempt = 0;; ++attempt) {
    // Coarse voxel (I, J, K) covers fine voxels offset + factor * (I, J, K) + [0, factor) and
    // holds the fraction of them inside the mask.
    offset = lo - factor * pad;
    const Eigen::Vector3i fine_extent = hi - lo + Eigen::Vector3i::Ones();
    Eigen::Vector3i dims;
    for (int a = 0; a < 3; ++a) dims[a] = (fine_extent[a] + factor[a] - 1) / factor[a] + 2 * pad;
    coarse_spacing = spacing.cwiseProduct(factor.cast<double>());
    auto image = vtkSmartPointer<vtkImageData>::New();
    image->SetDimensions(dims.x(), dims.y(), dims.z());
    image->SetSpacing(coarse_spacing.x(), coarse_spacing.y(), coarse_spacing.z());
    image->SetOrigin(0, 0, 0);
    auto scalars = vtkSmartPointer<vtkFloatArray>::New();
    scalars->SetNumberOfTuples(static_cast<vtkIdType>(dims.x()) * dims.y() * dims.z());
    float* data = scalars->GetPointer(0);
    std::fill(data, data + static_cast<long>(dims.x()) * dims.y() * dims.z(), 0.f);
    const float share = 1.f / static_cast<float>(factor.prod());
    for (int gk = lo.z(); gk <= hi.z(); ++gk) {
      const int k = (gk - offset.z()) / factor.z();
      for (int gj = lo.y(); gj <= hi.y(); ++gj) {
        const int j = (gj - offset.y()) / factor.y();
        float* row = data + static_cast<long>(dims.x()) * (j + static_cast<long>(dims.y()) * k);
        for (int gi = lo.x(); gi <= hi.x(); ++gi) {
          if (mask.inside[grid.Index(gi, gj, gk)] != 0) row[(gi - offset.x()) / factor.x()] += share;
        }
      }
    }
    image->GetPointData()->SetScalars(scalars);

    auto contour = vtkSmartPointer<vtkFlyingEdges3D>::New();
    if (use_blur) {
      auto blur = vtkSmartPointer<vtkImageGaussianSmooth>::New();
      blur->SetInputData(image);
      blur->SetDimensionality(3);
      // The same blur in metres as at full resolution (the block average blurs by itself too).
      blur->SetStandardDeviations(options.blur_sigma_voxels / factor.x(),
                                  options.blur_sigma_voxels / factor.y(),
                                  options.blur_sigma_voxels / factor.z());
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
    poly = contour->GetOutput();
    contoured = poly->GetNumberOfPolys();
    if (contoured == 0 && factor != Eigen::Vector3i::Ones()) {
      factor = Eigen::Vector3i::Ones();
      fallback = true;
      continue;
    }
    if (contoured == 0 && use_blur) {
      use_blur = false;
      fallback = true;
      continue;
    }
    TROCAR_THROW_UNLESS(contoured > 0, name << ": contouring the mask gave no triangles");
    if (!coarsen || fallback || attempt >= 2 || contoured <= 1.5 * wanted) break;
    h = coarse_spacing.maxCoeff() * std::sqrt(static_cast<double>(contoured) / wanted);
    const Eigen::Vector3i next = factor_for(h).cwiseMax(factor);
    if (next == factor) break;
    factor = next;
  }

  if (options.smoothing_iterations > 0) {
    auto smooth = vtkSmartPointer<vtkWindowedSincPolyDataFilter>::New();
    smooth->SetInputData(poly);
    smooth->SetNumberOfIterations(options.smoothing_iterations);
    smooth->SetPassBand(options.smoothing_passband);
    smooth->NormalizeCoordinatesOn();
    smooth->BoundarySmoothingOff();
    smooth->FeatureEdgeSmoothingOff();
    smooth->NonManifoldSmoothingOn();
    smooth->Update();
    poly = smooth->GetOutput();
  }
  // Into the patient frame: crop-local millimetres → grid index → P.
  auto to_mesh = [&](vtkPolyData* data) {
    TriangleMesh mesh;
    mesh.source = name;
    vtkPoints* points = data->GetPoints();
    mesh.vertices.reserve(points->GetNumberOfPoints());
    for (vtkIdType v = 0; v < points->GetNumberOfPoints(); ++v) {
      double x[3];
      points->GetPoint(v, x);
      // A coarse voxel's centre is the centre of the fine voxels it covers.
      const Eigen::Vector3d ijk =
          Eigen::Vector3d(x[0], x[1], x[2]).cwiseQuotient(coarse_spacing).cwiseProduct(factor.cast<double>()) +
          offset.cast<double>() + 0.5 * (factor - Eigen::Vector3i::Ones()).cast<double>();
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
  };
  TriangleMesh mesh;
  if (options.max_triangles > 0 && poly->GetNumberOfPolys() > options.max_triangles) {
    // Quadric decimation (the better shape for its count) does not keep the topology: on thin
    // parts (a vertebra's arch at 4 mm voxels) it can leave open and non-manifold edges. Then
    // the topology-preserving decimation is used instead, and the result with the fewest open or
    // non-manifold edges is kept.
    const double reduction =
        1.0 - static_cast<double>(options.max_triangles) / static_cast<double>(poly->GetNumberOfPolys());
    auto quadric = vtkSmartPointer<vtkQuadricDecimation>::New();
    quadric->SetInputData(poly);
    quadric->SetTargetReduction(reduction);
    quadric->VolumePreservationOn();
    quadric->Update();
    mesh = to_mesh(quadric->GetOutput());
    EdgeCounts edges = CountEdges(mesh);
    if (edges.boundary + edges.non_manifold > 0) {
      auto pro = vtkSmartPointer<vtkDecimatePro>::New();
      pro->SetInputData(poly);
      pro->SetTargetReduction(reduction);
      pro->PreserveTopologyOn();
      pro->SplittingOff();
      pro->BoundaryVertexDeletionOff();
      pro->Update();
      TriangleMesh kept = to_mesh(pro->GetOutput());
      const EdgeCounts kept_edges = CountEdges(kept);
      if (kept_edges.boundary + kept_edges.non_manifold < edges.boundary + edges.non_manifold &&
          static_cast<long>(kept.triangles.size()) <= options.max_triangles) {
        mesh = std::move(kept);
      }
    }
  } else {
    mesh = to_mesh(poly);
  }
  TROCAR_THROW_UNLESS(!mesh.triangles.empty(), name << ": the surface has no triangles");
  // Outward winding whatever the grid's handedness (LPS grids from RAS files are mirrored).
  if (MeshSignedVolume(mesh) < 0.0) {
    for (auto& t : mesh.triangles) std::swap(t[1], t[2]);
  }
  if (report != nullptr) {
    report->contoured_triangles = contoured;
    report->coarsening = factor;
    report->triangles = static_cast<long>(mesh.triangles.size());
    report->seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
  return mesh;
}

}  // namespace trocar::patient
