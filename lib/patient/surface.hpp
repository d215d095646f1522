#pragma once
/// @file
/// Surfaces from masks, as the thesis did by hand in MeshLab and Blender (§2.9.1), automated:
/// contouring by flying edges, windowed-sinc smoothing, quadric decimation to a triangle budget.
/// VTK does the work and stays out of this header.

#include "common/mesh.hpp"
#include "patient/segmentation.hpp"

namespace trocar::patient {

struct SurfaceOptions {
  /// Gaussian blur of the binary mask before contouring (voxels; 0 = none): removes the
  /// staircase of thresholded masks without moving the surface by more than a fraction of a voxel.
  double blur_sigma_voxels = 0.8;
  int smoothing_iterations = 15;  ///< windowed-sinc iterations (0 = none)
  double smoothing_passband = 0.1;
  int max_triangles = 40000;      ///< decimation budget (0 = keep all)
};

struct SurfaceReport {
  long contoured_triangles = 0;  ///< out of flying edges, before decimation
  long triangles = 0;            ///< in the result
  double seconds = 0.0;
};

/// The boundary of `mask` (on `grid`'s geometry) as a closed triangle mesh in the patient frame
/// (m), triangles wound counter-clockwise seen from outside. The mask is padded by empty voxels,
/// so structures cut by the volume's edge come out closed there (a flat cap).
/// @throws trocar::Error naming `name` when the mask is empty or the surface degenerates.
TriangleMesh ExtractSurface(const Volume& grid, const Mask& mask, const std::string& name,
                            const SurfaceOptions& options = {}, SurfaceReport* report = nullptr);

}  // namespace trocar::patient
