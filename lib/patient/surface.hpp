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
  /// The mask is contoured on a grid coarsened by whole factors per axis (each coarse voxel holds
  /// the fraction of its fine voxels inside, so the 0.5 level stays where the boundary was) so
  /// that the contour has about this many times `max_triangles` before decimation: a clinical
  /// CT's skin at 0.7 mm gives millions of triangles that quadric decimation (the slow stage,
  /// 5-30 µs a triangle) would only throw away. The coarse spacing never exceeds
  /// `max_working_spacing` (m): thin structures (ribs) need a fine one, the skin does not.
  /// 0 = contour at full resolution.
  double contour_budget_factor = 2.0;
  double max_working_spacing = 0.002;
};

struct SurfaceReport {
  long contoured_triangles = 0;  ///< out of flying edges, before decimation
  Eigen::Vector3i coarsening = Eigen::Vector3i::Ones();  ///< whole factor per index axis
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
