#include "patient/surface.hpp"

#include <chrono>

#include <vtkCellArray.h>
#include <vtkFlyingEdges3D.h>
#include <vtkFloatArray.h>
#include <vtkImageData.h>
#include <vtkImageGaussianSmooth.h>
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
  TROCAR_THROW_UNLESS(mask.size == grid.size,
                      name << ": mask of " << mask.size.transpose() << " voxels on a grid of "
                           << grid.size.transpose());
  TROCAR_THROW_UNLESS(options.max_triangles >= 0 && options.smoothing_iterations >= 0 &&
                          options.blur_sigma_voxels >= 0.0,
                      name << ": surface options must not be negative");
  // Crop to the mask's bounding box, padded so the surface closes inside the image.
  Eigen::Vector3i lo = grid.size, hi = Eigen::Vector3i::Constant(-1);
  for (int k = 0; k < grid.size.z(); ++k) {
    for (int j = 0; j < grid.size.y(); ++j) {
      for (int i = 0; i < grid.size.x(); ++i) {
        if (mask.inside[grid.Index(i, j, k)] == 0) continue;
        lo = lo.cwiseMin(Eigen::Vector3i(i, j, k));
        hi = hi.cwiseMax(Eigen::Vector3i(i, j, k));
      }
    }
  }
  TROCAR_THROW_UNLESS((hi.array() >= 0).all(), name << ": the mask is empty, there is no surface");
  const int pad = 2 + static_cast<int>(std::ceil(3.0 * options.blur_sigma_voxels));
  const Eigen::Vector3i offset = lo - Eigen::Vector3i::Constant(pad);
  const Eigen::Vector3i dims = hi - lo + Eigen::Vector3i::Constant(1 + 2 * pad);
  const Eigen::Vector3d spacing = grid.spacing();

  auto image = vtkSmartPointer<vtkImageData>::New();
  image->SetDimensions(dims.x(), dims.y(), dims.z());
  image->SetSpacing(spacing.x(), spacing.y(), spacing.z());
  image->SetOrigin(0, 0, 0);
  auto scalars = vtkSmartPointer<vtkFloatArray>::New();
  scalars->SetNumberOfTuples(static_cast<vtkIdType>(dims.x()) * dims.y() * dims.z());
  float* data = scalars->GetPointer(0);
  for (int k = 0; k < dims.z(); ++k) {
    for (int j = 0; j < dims.y(); ++j) {
      for (int i = 0; i < dims.x(); ++i) {
        const int gi = i + offset.x(), gj = j + offset.y(), gk = k + offset.z();
        const bool in = gi >= 0 && gj >= 0 && gk >= 0 && gi < grid.size.x() &&
                        gj < grid.size.y() && gk < grid.size.z() &&
                        mask.inside[grid.Index(gi, gj, gk)] != 0;
        data[i + static_cast<long>(dims.x()) * (j + static_cast<long>(dims.y()) * k)] = in ? 1.f : 0.f;
      }
    }
  }
  image->GetPointData()->SetScalars(scalars);

  vtkSmartPointer<vtkAlgorithm> last;
  auto contour = vtkSmartPointer<vtkFlyingEdges3D>::New();
  if (options.blur_sigma_voxels > 0.0) {
    auto blur = vtkSmartPointer<vtkImageGaussianSmooth>::New();
    blur->SetInputData(image);
    blur->SetDimensionality(3);
    blur->SetStandardDeviations(options.blur_sigma_voxels, options.blur_sigma_voxels,
                                options.blur_sigma_voxels);
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
  vtkSmartPointer<vtkPolyData> poly = contour->GetOutput();
  const long contoured = poly->GetNumberOfPolys();
  TROCAR_THROW_UNLESS(contoured > 0, name << ": contouring the mask gave no triangles");

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
  if (options.max_triangles > 0 && poly->GetNumberOfPolys() > options.max_triangles) {
    auto decimate = vtkSmartPointer<vtkQuadricDecimation>::New();
    decimate->SetInputData(poly);
    decimate->SetTargetReduction(1.0 - static_cast<double>(options.max_triangles) /
                                           static_cast<double>(poly->GetNumberOfPolys()));
    decimate->VolumePreservationOn();
    decimate->Update();
    poly = decimate->GetOutput();
  }

  // Into the patient frame: crop-local millimetres → grid index → P.
  TriangleMesh mesh;
  mesh.source = name;
  vtkPoints* points = poly->GetPoints();
  mesh.vertices.reserve(points->GetNumberOfPoints());
  for (vtkIdType v = 0; v < points->GetNumberOfPoints(); ++v) {
    double x[3];
    points->GetPoint(v, x);
    const Eigen::Vector3d ijk = Eigen::Vector3d(x[0], x[1], x[2]).cwiseQuotient(spacing) +
                                offset.cast<double>();
    mesh.vertices.push_back(grid.PatientPoint(ijk.x(), ijk.y(), ijk.z()));
  }
  vtkCellArray* polys = poly->GetPolys();
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
  TROCAR_THROW_UNLESS(!mesh.triangles.empty(), name << ": the surface has no triangles");
  // Outward winding whatever the grid's handedness (LPS grids from RAS files are mirrored).
  if (MeshSignedVolume(mesh) < 0.0) {
    for (auto& t : mesh.triangles) std::swap(t[1], t[2]);
  }
  if (report != nullptr) {
    report->contoured_triangles = contoured;
    report->triangles = static_cast<long>(mesh.triangles.size());
    report->seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
  return mesh;
}

}  // namespace trocar::patient
