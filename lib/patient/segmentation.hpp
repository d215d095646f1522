#pragma once
/// @file
/// Segmentation with no manual work: body (skin) and bone (ribs, sternum, spine) from
/// thresholds and connected components, the heart from a mask volume. Thresholds are Hounsfield
/// units, or raw values for windowed volumes such as 8-bit CT.

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "patient/volume.hpp"

namespace trocar::patient {

/// A binary mask on a volume's grid (same size and geometry as the volume it came from).
struct Mask {
  Eigen::Vector3i size = Eigen::Vector3i::Zero();
  std::vector<std::uint8_t> inside;
  long count() const;
};

struct Component {
  int label = 0;           ///< 1-based label in the label image
  long voxels = 0;
  double volume = 0.0;     ///< m³
  Eigen::Vector3d centroid_P = Eigen::Vector3d::Zero();
  Eigen::Vector3d min_P = Eigen::Vector3d::Zero(), max_P = Eigen::Vector3d::Zero();  ///< bounds
};

/// 26-connected components of a mask, largest first; labels[i] is 0 outside, else the label.
std::vector<Component> ConnectedComponents(const Volume& grid, const Mask& mask,
                                           std::vector<int>* labels);

struct SegmentationOptions {
  /// Thresholds: in HU for Hounsfield volumes; the `raw_` ones for others (e.g. 8-bit windowed).
  double body_hu = -400.0;
  double bone_hu = 450.0;  // above contrast-filled blood (250-400 HU)
  double raw_body = 40.0;
  double raw_bone = 160.0;  // 8-bit windowed CT: cortical bone is 160-255
  /// Bone components smaller than this are noise (m³).
  double min_bone_volume = 0.3e-6;
};

struct BoneParts {
  std::vector<Component> ribs_left, ribs_right;  ///< top to bottom
  std::vector<Component> spine, sternum;         ///< midline pieces
  std::vector<int> labels;                       ///< component labels on the grid
};

struct Segmentation {
  Mask body;  ///< the patient, holes (lungs, airways) filled
  Eigen::Vector3d body_min_P = Eigen::Vector3d::Zero();  ///< the body's bounding box (m)
  Eigen::Vector3d body_max_P = Eigen::Vector3d::Zero();
  Mask bone;
  BoneParts bones;
  double body_threshold = 0.0, bone_threshold = 0.0;  ///< as used, in the volume's units
};

/// Segments body and bone. Bone components are sorted into ribs (left, right; by height),
/// sternum (anterior midline) and spine (posterior midline) by where they lie in the body.
/// @throws trocar::Error naming the volume when the body or the bone comes out empty.
Segmentation Segment(const Volume& ct, const SegmentationOptions& options = {});

/// A mask from another volume (e.g. TotalSegmentator's heart.nii.gz) resampled, nearest voxel,
/// onto `grid` through both volumes' patient geometry. @throws trocar::Error when the mask does
/// not overlap the grid at all.
Mask ResampleMask(const Volume& mask_volume, const Volume& grid, double threshold = 0.5);

}  // namespace trocar::patient
