#pragma once
/// @file
/// Sanity checks on an imported CT, from anatomy rather than from the header: is the spine behind
/// the sternum, do the ribs descend toward the front (head up), is the heart left of the midline?
/// A flipped or mirrored header otherwise imports silently with the spine taken for the sternum
/// and ports over the shoulder blade. And: where does the body meet the scan's edge (a crop face
/// is not skin)?

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "patient/segmentation.hpp"

namespace trocar::patient {

struct OrientationCheck {
  /// Per patient axis: +1 the anatomy agrees with the header, −1 it says the axis is flipped,
  /// 0 not decided (the cue is out of view or ambiguous).
  int anterior_posterior = 0;  ///< from the spine: midline bone behind vs in front of the centre
  int superior_inferior = 0;   ///< from the ribs: each rib's back end is higher than its front
  int left_right = 0;          ///< from the heart: left of the midline (LPS +x)
  /// What was measured, one line per axis ("spine behind the centre: 94% of midline bone").
  std::vector<std::string> findings;
  /// The heart lies behind the lungs' centre while the spine lies at the back as the header says:
  /// it is not where a heart lies (not used to judge the header; the import warns).
  bool heart_misplaced = false;
  bool flipped() const { return anterior_posterior < 0 || superior_inferior < 0 || left_right < 0; }
};

/// `heart` may be null (no heart in the model: left-right stays undecided unless labelled ribs
/// say it).
OrientationCheck CheckOrientation(const Volume& ct, const Segmentation& seg, const Mask* heart);

/// A face of the scan's box the body is cut by (the skin there is a crop face, not skin).
struct CutFace {
  std::string name;        ///< "superior", "inferior", "left", "right", "anterior", "posterior"
  int axis = 0;            ///< index axis
  bool high = false;       ///< at index size−1 (else 0)
  double body_fraction = 0.0;  ///< of the face's voxels inside the body
};

/// The faces of the volume the body touches over at least `min_fraction` of their voxels, in the
/// patient's order (right, left, anterior, posterior, superior, inferior) whichever index axes the
/// file stores them along.
std::vector<CutFace> FindCutFaces(const Volume& ct, const Mask& body, double min_fraction = 0.002);

/// Distance (m) from `p_P` to a cut face's plane, measured along its index axis (negative outside
/// the scan).
double DistanceToCutFace(const Volume& ct, const CutFace& face, const Eigen::Vector3d& p_P);

}  // namespace trocar::patient
