#pragma once
/// @file
/// Intercostal spaces found automatically from the segmented ribs: at each angle about the body
/// axis, the middle of the gap between each rib and the next one below it there, carried out to
/// the skin; the run of angles between the same two ribs gives a port candidate curve.

#include <vector>

#include "patient/phantom.hpp"
#include "patient/segmentation.hpp"

namespace trocar::patient {

struct IntercostalOptions {
  /// Angles about the body axis, from the back (0) to the front (π), where ports may go.
  double from_angle = 0.45 * M_PI;
  double to_angle = 0.85 * M_PI;
  double bin = 2.0 * M_PI / 180.0;  ///< angular sampling (rad)
  /// Shortest gap between rib edges that counts as a space (m).
  double min_gap = 0.004;
  /// Farthest the skin may lie beyond the ribs along a ray (m): beyond it the ray runs into an
  /// arm against the chest, and the point is no port site.
  double max_wall_depth = 0.08;
  /// Fewest angular samples for a curve to be kept.
  int min_points = 5;
  bool left = true;
  bool right = false;
};

struct IntercostalSpace {
  int side = +1;       ///< +1 left, −1 right
  int upper_rib = 0;   ///< index of the rib above (in the side's top-to-bottom order)
  int lower_rib = 1;   ///< index of the rib below
  Curve skin;          ///< on the skin, from the side of the chest toward the front
  Curve depth;         ///< the same points at the ribs' depth (the gap itself)
  std::vector<double> gap;  ///< width of the gap at each point (m)
};

/// Spaces of a side come top to bottom (by mean height).
/// @throws trocar::Error naming the volume when a side asked for has fewer than two ribs.
std::vector<IntercostalSpace> FindIntercostalSpaces(const Volume& ct, const Segmentation& seg,
                                                    const IntercostalOptions& options = {});

}  // namespace trocar::patient
