#pragma once
/// @file
/// Intercostal spaces found automatically from the segmented ribs: at each angle about the body
/// axis, the middle of the gap between each rib and the next one below it there, carried out to
/// the skin; the run of angles between the same two ribs gives a port candidate curve.

#include <cstdint>
#include <vector>

#include "patient/curve.hpp"
#include "patient/segmentation.hpp"

namespace trocar::patient {

struct IntercostalOptions {
  /// Angles about the body axis, from the back (0) to the front (π), where ports may go.
  double from_angle = 0.45 * M_PI;
  double to_angle = 0.85 * M_PI;
  double bin = 2.0 * M_PI / 180.0;  ///< angular sampling (rad)
  /// Shortest gap between rib edges that counts as a space (m).
  double min_gap = 0.004;
  /// Farthest the skin may lie beyond the ribs along a ray (m), at least: beyond it the ray runs
  /// into an arm against the chest, and the point is no port site. A side whose chest wall is
  /// thicker (obese patients: 5-8 cm of fat) gets its own bound, the lower quartile of its rays'
  /// walls plus `arm_margin` (an arm against the chest adds at least its own thickness, 7 cm or
  /// more); rays are followed out to `longest_ray` beyond the ribs.
  double max_wall_depth = 0.08;
  double arm_margin = 0.04;
  double longest_ray = 0.3;
  /// Fewest angular samples for a curve to be kept.
  int min_points = 5;
  bool left = true;
  bool right = false;
  /// Spaces on a side whose ribs the import cannot number (rib 1 not in view or not confirmed)
  /// are named in order from the top, the highest found being ICS-<count_from>, when the case
  /// file says so (`intercostal: {count_from: N}`: the user counted them); 0: they stay
  /// "gap-L1", "gap-L2", ... Ribs numbered by the import or by labels are never renumbered.
  int count_from = 0;
  /// The rib cage's layer (FindIntercostalSpacesInLayer, for windowed volumes): bone-bright
  /// voxels no deeper than `layer_depth` under the skin (m), the innermost of them along each ray
  /// (the ribs lie on the lungs; a shoulder blade or an arm lies outside them) smoothed over
  /// `layer_smooth_angle` (rad) and `layer_smooth_height` (m) either side, and the band from
  /// `layer_inside` inside that surface to `layer_outside` outside it (m).
  double layer_depth = 0.045;
  double layer_smooth_angle = 10.0 * M_PI / 180.0, layer_smooth_height = 0.02;
  double layer_inside = 0.004, layer_outside = 0.010;
  /// A rib in the layer is at least this bright (the volume's units); 0: `layer_floor_fraction`
  /// of the way from the chest wall's soft tissue (the median of the wall's voxels between the
  /// body and bone thresholds) to the bone threshold. A rib's cross-section partly filling a
  /// voxel reads there; 0.4 is where the plain-CT hysteresis floor lies in HU (130 HU, from
  /// muscle's 50 to the 250 HU bone threshold; AnatomyOptions::unenhanced_max_hu).
  double layer_floor = 0.0;
  double layer_floor_fraction = 0.4;
  /// A rib's run along a column of the chart is at most this tall, a space between two ribs at
  /// most `layer_max_gap` (m): taller bright runs are organs in the band (the liver below the rib
  /// cage, the heart against it), taller dark ones no space between neighbouring ribs.
  double layer_max_rib = 0.025, layer_max_gap = 0.035;
  /// A rib's run of bright voxels along a ray from the body's axis is at most this deep (m):
  /// the girdle's surface (LayerChart) is the innermost such run, not an organ under the ribs.
  double layer_max_rib_depth = 0.015;
  /// A space's points in the layer lie at least this share of the body's half-width (left to
  /// right) from its axis: the rib cage is round the lungs and the heart. On LIDC2 the spaces
  /// lie at 0.48-0.86 of it; dark runs at the neck's base and below the rib cage, where the band
  /// under the skin reaches the body's middle, at 0.04-0.21.
  double layer_min_cage_radius = 0.4;
};

struct IntercostalSpace {
  int side = +1;       ///< +1 left, −1 right
  int upper_rib = 0;   ///< index of the rib above (in the side's top-to-bottom order)
  int lower_rib = 1;   ///< index of the rib below
  Curve skin;          ///< on the skin, from the side of the chest toward the front
  Curve depth;         ///< the same points at the ribs' depth (the gap itself)
  std::vector<double> gap;  ///< width of the gap at each point (m)
};

/// How far the skin lies beyond the ribs on one side's rays over its spaces, and the points left
/// out as lying under an arm.
struct WallReach {
  int side = +1;
  double typical = 0.0;  ///< the lower quartile of the rays' walls, ribs to skin (m)
  double limit = 0.0;    ///< max(max_wall_depth, typical + arm_margin) (m)
  int kept = 0;          ///< rays whose skin lies within `limit`
  int dropped = 0;       ///< rays further: into an arm against the chest
};

/// Spaces of a side come top to bottom (by mean height). `reach`, when given, gets one entry per
/// side with rays.
/// @throws trocar::Error naming the volume when a side asked for has fewer than two ribs.
std::vector<IntercostalSpace> FindIntercostalSpaces(const Volume& ct, const Segmentation& seg,
                                                    const IntercostalOptions& options = {},
                                                    std::vector<WallReach>* reach = nullptr);

/// The chart of the rib cage's layer per side: rows are heights from `top_z` down by `dz`, columns
/// angles about the body's axis from the back (column c at (c + ½)·bin, to π at the front).
struct LayerChart {
  double floor = 0.0;  ///< the rib floor used (the volume's units)
  double top_z = 0.0, dz = 0.0, bin = 0.0;
  int rows = 0, cols = 0;
  std::vector<std::uint8_t> rib_left, rib_right;  ///< row * cols + col: 1 where the layer is rib
  /// row * cols + col: the ribs' surface, its distance from the body's axis (m; NaN where the
  /// wall holds no rib-bright run near): the lower quartile around of the innermost bright runs
  /// that end in the wall and are no deeper than a rib (`layer_max_rib_depth`, measured whole).
  /// Bone beyond it by more than `outside` lies outside the rib cage.
  std::vector<double> surface_left, surface_right;
  double outside = 0.0;  ///< `layer_outside` as used (m)
};

/// Spaces found in a chart of the rib cage's layer, not between rib components: for windowed
/// (8-bit) volumes, where most of a rib's cross-section lies below the bone threshold and the
/// components are fragments. At each height and angle about the body's axis the layer is rib
/// when any voxel in its band reaches the floor; at each angle the dark runs between two rib
/// runs are spaces, linked across neighbouring angles into curves. `upper_rib` and `lower_rib`
/// are −1 (no rib component bounds them). Spaces of a side come top to bottom.
/// @throws trocar::Error naming the volume when the body is empty.
std::vector<IntercostalSpace> FindIntercostalSpacesInLayer(const Volume& ct,
                                                           const Segmentation& seg,
                                                           const IntercostalOptions& options = {},
                                                           LayerChart* chart = nullptr,
                                                           std::vector<WallReach>* reach = nullptr);

}  // namespace trocar::patient
